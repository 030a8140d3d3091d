"""cloud2cnc geometry core: arrays in, arrays or small frozen records out.

One package per stage, in pipeline order (`ingest`, `reconstruct`, `denoise`, `remesh`, `segment`,
`fit`, `plan`, `verify`), and shared packages (`mesh`, `spline`, `gcode`, `io`, `params`). A stage's
entry point takes its own parameter group from `cam.params` and two optional callbacks, the one
convention every long computation here follows:

- ``progress(fraction, message=None)`` reports how far it got, fraction in [0, 1];
- ``check_cancel()`` is called from long loops and raises the caller's own exception to stop it
  (cam never catches it).

Independent pieces of a stage (the patches of `fit` and of `plan`) run in forked processes through `map_forked`; its
results are those of the same calls made one after another, bit for bit.

What a user can act on (a cloud too small, a patch that is no quad grid, a file that is not a mesh)
is raised as a `GeometryError` whose message says what was found and what to change; any other
exception is a bug.
"""

from __future__ import annotations

import os
import pickle
import selectors
import signal
import struct
from collections.abc import Callable
from typing import Any

__all__ = ["CheckCancel", "GeometryError", "Progress", "map_forked", "progress_between"]

#: progress(fraction in [0, 1], message or None)
Progress = Callable[..., None]
#: check_cancel() raises to stop the computation, returns otherwise
CheckCancel = Callable[[], None]


class GeometryError(ValueError):
    """The input or the parameters do not allow the result, for a reason the user can act on; the message
    names what was found and what to change, and reaches the user as it is."""


def progress_between(progress: Progress | None, start: float, end: float) -> Progress:
    """A progress callback for a sub-step: its 0..1 is reported as start..end of `progress`."""

    def report(fraction: float, message: str | None = None) -> None:
        if progress is not None:
            progress(start + (end - start) * min(max(float(fraction), 0.0), 1.0), message)

    return report


def map_forked(fn: Callable[[int, CheckCancel], Any], n: int, *, processes: int = 1,
               check_cancel: CheckCancel | None = None, progress: Progress | None = None,
               poll_s: float = 0.5) -> list[Any]:
    """[fn(0, cc), …, fn(n − 1, cc)], computed in up to `processes` forked child processes.

    The children are forks of this process: `fn` and everything it reads are inherited, not pickled; only
    each result comes back, pickled. Each child is handed the next index as it finishes one, so a long
    call does not hold the others up. With processes <= 1 (or n <= 1) the calls run here, in order, with
    the caller's `check_cancel` — the reference the forked run matches bit for bit. In a child, `fn` gets
    a no-op check_cancel: this process calls the real one every `poll_s` while it waits and, when it
    raises, kills the children. An exception in `fn` is raised here, children killed.

    Plain `os.fork` rather than `multiprocessing`: a Celery prefork child is a daemon process, which
    multiprocessing does not let start children. A child whose parent is gone stops at its next index.

    Parameters
    ----------
    fn : callable
        fn(index, check_cancel) -> a picklable result.
    n : int
        Number of calls.
    processes : int
        Child processes at most.
    check_cancel, progress : callable, optional
        The convention of this package; progress gets the share of calls done.

    Returns
    -------
    list
        The results in index order.
    """
    cancel = check_cancel or (lambda: None)
    report = progress or (lambda fraction, message=None: None)
    if processes <= 1 or n <= 1:
        out = []
        for k in range(n):
            cancel()
            out.append(fn(k, cancel))
            report((k + 1) / n)
        return out
    return _map_in_children(fn, n, min(processes, n), cancel, report, poll_s)


def _map_in_children(fn, n: int, processes: int, cancel: CheckCancel, report: Progress, poll_s: float) -> list[Any]:
    children, results, todo, done = [], [None] * n, iter(range(n)), 0
    selector = selectors.DefaultSelector()
    try:
        for _ in range(processes):
            child = _fork_child(fn, [fd for c in children for fd in c[1:]])
            children.append(child)
            selector.register(child[2], selectors.EVENT_READ, child)
            _send(child[1], next(todo, -1))
        while done < n:
            cancel()
            for key, _ in selector.select(poll_s):
                child = key.data
                index, ok, value = pickle.loads(_read_message(child[2]))
                if not ok:
                    raise value
                results[index] = value
                done += 1
                report(done / n)
                following = next(todo, -1)
                if following < 0:  # the child ends: its pipe's end of file is no result
                    selector.unregister(child[2])
                _send(child[1], following)
    finally:
        selector.close()
        for pid, task_w, result_r in children:
            for fd in (task_w, result_r):
                os.close(fd)
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
    return results


def _fork_child(fn, siblings: list[int]) -> tuple[int, int, int]:
    """A child that reads indices from a pipe and writes (index, ok, result) back; (pid, task fd, result fd).
    `siblings`: this process's ends of the earlier children's pipes, closed in the new child."""
    task_r, task_w = os.pipe()
    result_r, result_w = os.pipe()
    pid = os.fork()
    if pid:
        os.close(task_r)
        os.close(result_w)
        return pid, task_w, result_r
    # The child keeps only its own two pipes (so that a sibling sees end of file when the parent is gone) and
    # leaves by os._exit, so that none of the parent's exit handlers run here.
    for fd in (task_w, result_r, *siblings):
        os.close(fd)
    status = 0
    try:
        with os.fdopen(task_r, "rb") as tasks, os.fdopen(result_w, "wb") as out:
            while (raw := tasks.read(8)) and len(raw) == 8 and (k := struct.unpack("<q", raw)[0]) >= 0:
                try:
                    message = (k, True, fn(k, lambda: None))
                except BaseException as exc:  # noqa: BLE001 — handed to the parent, which raises it
                    message = (k, False, exc)
                try:
                    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
                except Exception as exc:  # noqa: BLE001 — an exception that does not pickle still says what it was
                    failure = message[2] if not message[1] else exc
                    data = pickle.dumps((k, False, RuntimeError(f"in call {k}: {failure!r}")))
                out.write(struct.pack("<q", len(data)) + data)
                out.flush()
    except BaseException:  # noqa: BLE001 — a broken pipe: the parent is gone
        status = 1
    finally:
        os._exit(status)


def _send(fd: int, index: int) -> None:
    os.write(fd, struct.pack("<q", index))


def _read_message(fd: int) -> bytes:
    size = struct.unpack("<q", _read_exactly(fd, 8))[0]
    return _read_exactly(fd, size)


def _read_exactly(fd: int, size: int) -> bytes:
    chunks, left = [], size
    while left:
        chunk = os.read(fd, min(left, 1 << 20))
        if not chunk:
            raise ChildProcessError("a child process of map_forked ended without its result")
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)
