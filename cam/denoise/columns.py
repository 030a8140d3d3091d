"""The filter's linear solves on two processors: the last column of each right-hand side in a forked child.

Every iteration of the MeshTGV filter solves two fixed factorisations for the three components of the
normals (and of the auxiliary field), and those solves are most of its time. SuperLU's solve holds the GIL,
so a thread does not help; a child forked once the factorisations are made shares them (copy-on-write, and
nothing writes them) and solves the last column while this process solves the others. One process splits
the columns the same way (the others in one call, then the last): SuperLU's answer for a column can depend on
the columns solved beside it (SciPy 1.17's solves them in pairs, so the first of two columns solved together
differs in its last bits from the same column solved alone), and the filter's result is that of one process
only when both make the same calls. (Two calls cost one process about a quarter more per three-column solve
than one call, 39 against 31 ms on a 90,000-row grid Laplacian; the same bits for any process count are worth it.)

The child reads a factor's number from a pipe and its column from memory shared with this process, writes
the answer back there and one byte of reply; it ends when the pipe closes (this process left the block, or
died). Where the child cannot be forked, or fails, the solves run here.
"""

from __future__ import annotations

import contextlib
import functools
import mmap
import os
import signal
from collections.abc import Callable, Iterator, Sequence
from typing import Protocol

import numpy as np

__all__ = ["Factor", "solves_in_two", "split_solve"]


class Factor(Protocol):
    """A factorisation of an n x n matrix that solves for (n,) or (n, k) right-hand sides (`scipy.sparse.linalg.splu`'s)."""

    shape: tuple[int, int]

    def solve(self, rhs: np.ndarray) -> np.ndarray: ...


_OK = b"k"


@contextlib.contextmanager
def solves_in_two(factors: Sequence[Factor], *, processes: int) -> Iterator[list[Callable[[np.ndarray], np.ndarray]]]:
    """One solve function per factor, solving (n, k ≥ 2) right-hand sides with the last column in a child.

    Parameters
    ----------
    factors : sequence of Factor
        The factorisations, made before the block (the child inherits them).
    processes : int
        Processors the caller may use: below 2, every solve runs in this process.

    Yields
    ------
    list of callable
        solve(rhs (n, k) float64) -> (n, k) float64: `split_solve` of the factor, bit for bit, wherever its
        last column was solved.
    """
    if processes < 2 or not factors:
        yield [functools.partial(split_solve, f) for f in factors]
        return
    sizes = [int(f.shape[0]) for f in factors]
    shared = [mmap.mmap(-1, 16 * n) for n in sizes]  # anonymous and shared: the child sees the same pages
    columns = [np.frombuffer(m, dtype=np.float64, count=n) for m, n in zip(shared, sizes, strict=True)]
    answers = [np.frombuffer(m, dtype=np.float64, count=n, offset=8 * n) for m, n in zip(shared, sizes, strict=True)]
    task_r, task_w = os.pipe()
    reply_r, reply_w = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        for fd in (task_r, task_w, reply_r, reply_w):
            os.close(fd)
        yield [functools.partial(split_solve, f) for f in factors]
        return
    if pid == 0:
        os.close(task_w)
        os.close(reply_r)
        _serve(factors, columns, answers, task_r, reply_w)
    os.close(task_r)
    os.close(reply_w)
    state = {"child": True}

    def solver(k: int) -> Callable[[np.ndarray], np.ndarray]:
        factor = factors[k]

        def solve(rhs: np.ndarray) -> np.ndarray:
            rhs = np.asarray(rhs, dtype=np.float64)
            if not state["child"] or rhs.ndim != 2 or rhs.shape[1] < 2:
                return split_solve(factor, rhs)
            columns[k][:] = rhs[:, -1]
            os.write(task_w, bytes([k]))
            head = factor.solve(np.ascontiguousarray(rhs[:, :-1]))
            if os.read(reply_r, 1) != _OK:
                state["child"] = False  # it failed or is gone: every solve runs here from now on
                return split_solve(factor, rhs)
            return _joined(head, answers[k])

        return solve

    try:
        yield [solver(k) for k in range(len(factors))]
    finally:
        os.close(task_w)
        os.close(reply_r)
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)


def split_solve(factor: Factor, rhs: np.ndarray) -> np.ndarray:
    """`factor.solve(rhs)` made as `solves_in_two` makes it: all columns but the last in one call, the last alone.

    Parameters
    ----------
    factor : Factor
        The factorisation, n x n.
    rhs : ndarray, shape (n,) or (n, k), float64
        Right-hand sides; (n,) and (n, 1) are solved in one call.

    Returns
    -------
    ndarray, the shape of `rhs`, float64
    """
    rhs = np.asarray(rhs, dtype=np.float64)
    if rhs.ndim != 2 or rhs.shape[1] < 2:
        return factor.solve(rhs)
    return _joined(factor.solve(np.ascontiguousarray(rhs[:, :-1])), factor.solve(np.ascontiguousarray(rhs[:, -1])))


def _joined(head: np.ndarray, last: np.ndarray) -> np.ndarray:
    """(n, k): the solved columns `head` (n, k - 1) and `last` (n,), in the layout SuperLU's solve returns."""
    out = np.empty((head.shape[0], head.shape[1] + 1), order="F")
    out[:, :-1], out[:, -1] = head, last
    return out


def _serve(factors, columns, answers, task_r: int, reply_w: int) -> None:
    """The child: solve the columns asked for until the pipe closes; leaves by os._exit (none of the
    parent's exit handlers run here)."""
    status = 0
    try:
        while (task := os.read(task_r, 1)) and task[0] < len(factors):
            k = task[0]
            try:
                answers[k][:] = factors[k].solve(columns[k].copy())
                reply = _OK
            except Exception:  # noqa: BLE001 — the parent solves the column itself
                reply = b"e"
            os.write(reply_w, reply)
    except BaseException:  # noqa: BLE001 — a broken pipe: the parent is gone
        status = 1
    finally:
        os._exit(status)
