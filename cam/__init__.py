"""cloud2cnc geometry core: arrays in, arrays or small frozen records out.

One package per stage, in pipeline order (`ingest`, `reconstruct`, `denoise`, `remesh`, `segment`,
`fit`, `plan`, `verify`), and shared packages (`mesh`, `spline`, `gcode`, `io`, `params`). A stage's
entry point takes its own parameter group from `cam.params` and two optional callbacks, the one
convention every long computation here follows:

- ``progress(fraction, message=None)`` reports how far it got, fraction in [0, 1];
- ``check_cancel()`` is called from long loops and raises the caller's own exception to stop it
  (cam never catches it).

Independent pieces of a stage (the patches of `fit` and of `plan`) run in forked processes through `map_forked`; its
results are those of the same calls made one after another, bit for bit, and each piece's own progress reaches
the caller while it runs.

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
import time
from collections.abc import Callable
from typing import Any

__all__ = ["REPORT_INTERVAL_S", "CheckCancel", "GeometryError", "Progress", "map_forked", "progress_between", "progress_labelled"]

#: progress(fraction in [0, 1], message or None)
Progress = Callable[..., None]
#: check_cancel() raises to stop the computation, returns otherwise
CheckCancel = Callable[[], None]
#: Seconds between two progress reports of one call of `map_forked`, at least (the others are dropped)
REPORT_INTERVAL_S = 0.2


class GeometryError(ValueError):
    """The input or the parameters do not allow the result, for a reason the user can act on; the message
    names what was found and what to change, and reaches the user as it is."""


def progress_between(progress: Progress | None, start: float, end: float) -> Progress:
    """A progress callback for a sub-step: its 0..1 is reported as start..end of `progress`."""

    def report(fraction: float, message: str | None = None) -> None:
        if progress is not None:
            progress(start + (end - start) * min(max(float(fraction), 0.0), 1.0), message)

    return report


def progress_labelled(progress: Progress | None, start: float, end: float, label: str, *,
                      sep: str = ": ") -> Progress:
    """`progress_between` for a sub-step whose messages follow `label` (label, `sep`, message)."""

    def report(fraction: float, message: str | None = None) -> None:
        if progress is not None:
            progress(start + (end - start) * min(max(float(fraction), 0.0), 1.0),
                     f"{label}{sep}{message}" if message else label)

    return report


def map_forked(fn: Callable[..., Any], n: int, *, processes: int = 1, check_cancel: CheckCancel | None = None,
               progress: Progress | None = None, poll_s: float = 0.5, item_progress: bool = False,
               report_s: float | None = None) -> list[Any]:
    """[fn(0, cc), …, fn(n − 1, cc)], computed in up to `processes` forked child processes.

    The children are forks of this process: `fn` and everything it reads are inherited, not pickled; only
    each result comes back, pickled. Each child is handed the next index as it finishes one, so a long
    call does not hold the others up. With processes <= 1 (or n <= 1) the calls run here, in order, with
    the caller's `check_cancel` — the reference the forked run matches bit for bit. In a child, `fn` gets
    a no-op check_cancel: this process calls the real one every `poll_s` while it waits and, when it
    raises, kills the children. An exception in `fn` is raised here, children killed.

    With `item_progress`, `fn` is called fn(index, check_cancel, progress) and reports how far that one
    call got with progress(fraction, message=None), fraction in [0, 1] of the call. A child sends those
    reports to this process beside its results (at most one per `report_s`, the others dropped), which
    reads them as they come while it waits; so does the serial run. Reports change no result.

    Plain `os.fork` rather than `multiprocessing`: a Celery prefork child is a daemon process, which
    multiprocessing does not let start children. A child whose parent is gone stops at its next index.

    Parameters
    ----------
    fn : callable
        fn(index, check_cancel) -> a picklable result; fn(index, check_cancel, progress) with
        `item_progress`.
    n : int
        Number of calls.
    processes : int
        Child processes at most.
    check_cancel, progress : callable, optional
        The convention of this package. progress gets the share of the calls done, each running call
        counted with its own last fraction (never less than before), and a message "k of n done", with
        the latest running call's own message after a semicolon.
    poll_s : float
        Seconds between two calls of `check_cancel` while the children work, at most.
    item_progress : bool
        Hand `fn` a progress callback of its own (see above).
    report_s : float or None
        Seconds between two reports of one call, at least (0: every one); None: `REPORT_INTERVAL_S`.

    Returns
    -------
    list
        The results in index order.
    """
    cancel = check_cancel or (lambda: None)
    report_s = REPORT_INTERVAL_S if report_s is None else float(report_s)
    tally = _Tally(n, progress or (lambda fraction, message=None: None))
    if processes <= 1 or n <= 1:
        out = []
        for k in range(n):
            cancel()
            if item_progress:
                out.append(fn(k, cancel, _Throttled(lambda f, m=None, k=k: tally.running(k, f, m), report_s)))
            else:
                out.append(fn(k, cancel))
            tally.finished(k)
        return out
    return _map_in_children(fn, n, min(processes, n), cancel, tally, poll_s, item_progress, report_s)


class _Tally:
    """How far n calls got: the calls done plus each running call's own fraction, reported as a share of n
    that never goes back."""

    def __init__(self, n: int, report: Progress) -> None:
        self.n, self.report = n, report
        self.done, self.shown = 0, 0.0
        self.fractions: dict[int, float] = {}

    def running(self, index: int, fraction: float, message: str | None) -> None:
        """Call `index` reports `fraction` of itself done, doing `message`."""
        fraction = min(max(float(fraction), 0.0), 1.0)
        self.fractions[index] = max(self.fractions.get(index, 0.0), fraction)
        self._report(message)

    def finished(self, index: int) -> None:
        """Call `index` returned."""
        self.fractions.pop(index, None)
        self.done += 1
        self._report(None)

    def _report(self, message: str | None) -> None:
        # Each call's fraction only grows and a call that returns counts 1, so the share falls by a
        # rounding at most (sums in another order): what was shown stays.
        self.shown = max(self.shown, min((self.done + sum(self.fractions.values())) / self.n, 1.0))
        done = f"{self.done} of {self.n} done"
        self.report(self.shown, f"{done}; {message}" if message else done)


class _Throttled:
    """A progress callback that passes on at most one report per `interval_s`, the first at once."""

    def __init__(self, report: Progress, interval_s: float) -> None:
        self.report, self.interval_s, self.last = report, interval_s, None

    def __call__(self, fraction: float, message: str | None = None) -> None:
        now = time.monotonic()
        if self.last is None or now - self.last >= self.interval_s:
            self.last = now
            self.report(fraction, message)


def _map_in_children(fn, n: int, processes: int, cancel: CheckCancel, tally: _Tally, poll_s: float,
                     item_progress: bool, report_s: float) -> list[Any]:
    children, results, todo = [], [None] * n, iter(range(n))
    selector = selectors.DefaultSelector()
    try:
        for _ in range(processes):
            child = _fork_child(fn, [fd for c in children for fd in c[1:]], item_progress, report_s)
            children.append(child)
            selector.register(child[2], selectors.EVENT_READ, child)
            _send(child[1], next(todo, -1))
        # One message per ready child per turn, whatever its kind: a child that reports often is read as
        # often as it writes (it blocks on a full pipe, never on us), and cancel is polled between turns.
        while tally.done < n:
            cancel()
            for key, _ in selector.select(poll_s):
                child = key.data
                kind, index, payload = pickle.loads(_read_message(child[2]))
                if kind == _PROGRESS:
                    tally.running(index, *payload)
                    continue
                ok, value = payload
                if not ok:
                    raise value
                results[index] = value
                tally.finished(index)
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


#: The kinds of a child's messages: (kind, index, (fraction, message)) or (kind, index, (ok, result)).
_PROGRESS, _RESULT = 0, 1


def _fork_child(fn, siblings: list[int], item_progress: bool, report_s: float) -> tuple[int, int, int]:
    """A child that reads indices from a pipe and writes its messages back; (pid, task fd, result fd).
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
            def write(data: bytes) -> None:
                out.write(struct.pack("<q", len(data)) + data)
                out.flush()

            def report(k: int, fraction: float, message: str | None = None) -> None:
                write(pickle.dumps((_PROGRESS, k, (float(fraction), message)), protocol=pickle.HIGHEST_PROTOCOL))

            while (raw := tasks.read(8)) and len(raw) == 8 and (k := struct.unpack("<q", raw)[0]) >= 0:
                try:
                    if item_progress:
                        value = fn(k, lambda: None, _Throttled(lambda f, m=None, k=k: report(k, f, m), report_s))
                    else:
                        value = fn(k, lambda: None)
                    message = (_RESULT, k, (True, value))
                except BaseException as exc:  # noqa: BLE001 — handed to the parent, which raises it
                    message = (_RESULT, k, (False, exc))
                try:
                    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
                except Exception as exc:  # noqa: BLE001 — an exception that does not pickle still says what it was
                    ok, value = message[2]
                    failure = value if not ok else exc
                    data = pickle.dumps((_RESULT, k, (False, RuntimeError(f"in call {k}: {failure!r}"))))
                write(data)
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
