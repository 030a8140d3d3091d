"""The embedded worker's lifeline to `cloud2cnc serve`: it never outlives the serve that started it.

`serve` starts its worker in a session of its own (so a terminal's Ctrl-C reaches the worker only through
serve, which stops it warmly). That also means nothing ends the worker when serve dies hard (kill -9, the
OOM killer): it would keep running its stage as an orphan and keep taking jobs from the queue a restarted
serve uses. Two independent guards end it, and with it every process of its stage:

- a parent-death signal (Linux `prctl(PR_SET_PDEATHSIG)`), set between fork and exec of the worker by
  `prepare_embedded_worker`: the kernel sends `PARENT_GONE_SIGNAL` when the thread that forked the worker
  exits, so serve must start it from its main thread, which lives as long as serve;
- a watch in the worker's main process (`follow_parent`): a thread that compares `os.getppid()` with
  serve's pid every `poll_s` (a process whose parent dies is re-parented), for systems without prctl and as
  a second line if the signal is lost.

Either one kills the worker's whole process group with SIGKILL: the Celery main process, its prefork pool
children and the processes a stage forks (`cam.map_forked`, QuadriFlow's child) all stay in the group the
worker leads. SIGKILL because a warm shutdown would let the stage run to its end, and no work is lost: the
stage's lease lapses and the reconciler of the next serve re-queues it, to be finished once.

Only the standard library: `serve` imports this module without the geometry or queue stack.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Callable

#: What the kernel sends the worker when serve is gone; Celery leaves SIGUSR2 alone (unless CELERY_RDBSIG).
PARENT_GONE_SIGNAL = signal.SIGUSR2
_PR_SET_PDEATHSIG = 1


def prepare_embedded_worker(parent_pid: int, *, nice: int) -> Callable[[], None]:
    """The `preexec_fn` for serve's worker: lower its CPU priority by `nice` and ask for `PARENT_GONE_SIGNAL`
    when serve (`parent_pid`, the caller's pid) is gone.

    Runs in the child between fork and exec, so it only makes system calls; a child whose parent died
    before the request took effect exits at once instead of running unwatched.
    """
    if nice < 0:
        raise ValueError(f"nice must be >= 0 (a lower priority than serve's), got {nice}")

    def preexec() -> None:
        if nice:
            os.nice(nice)
        _set_parent_death_signal(PARENT_GONE_SIGNAL)
        if os.getppid() != parent_pid:
            os._exit(1)

    return preexec


def _set_parent_death_signal(signum: int) -> bool:
    """prctl(PR_SET_PDEATHSIG, signum) where Linux offers it; False elsewhere (the watch still guards)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signum), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def follow_parent(parent_pid: int, *, poll_s: float = 0.5,
                  on_gone: Callable[[str], None] | None = None) -> threading.Thread:
    """End this process and its process group as soon as `parent_pid` is no longer this process's parent.

    Call it in the worker's main process before Celery starts its pool. It makes this process the leader of
    its own process group (if it is not already), so the group holds exactly the worker and what it starts;
    then it handles `PARENT_GONE_SIGNAL` and starts the watching thread (returned, a daemon). `on_gone`
    (default: `end_process_group`) gets the reason.
    """
    if parent_pid <= 1:
        raise ValueError(f"parent_pid must be a real process id, got {parent_pid}")
    if poll_s <= 0:
        raise ValueError(f"poll_s must be > 0, got {poll_s}")
    act = on_gone or end_process_group
    if os.getpgrp() != os.getpid():
        os.setpgid(0, 0)  # a session leader (serve's start_new_session) already leads its group
    signal.signal(PARENT_GONE_SIGNAL, lambda signum, frame: act(f"parent-death signal: pid {parent_pid} is gone"))

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        act(f"pid {parent_pid} is gone (parent is now pid {os.getppid()})")

    thread = threading.Thread(target=watch, name="cloud2cnc-lifeline", daemon=True)
    thread.start()
    return thread


def end_process_group(reason: str) -> None:
    """SIGKILL this process's group (itself included): the worker, its pool and its stages' processes."""
    try:
        os.write(2, f"cloud2cnc worker {os.getpid()}: {reason}; ending the worker and its stage processes\n"
                 .encode())
    except OSError:
        pass
    group = os.getpgrp()
    if group == os.getpid():
        os.killpg(group, signal.SIGKILL)
    os.kill(os.getpid(), signal.SIGKILL)  # not a group leader: never kill a group that is not ours
