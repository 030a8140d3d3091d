"""Run QuadriFlow in child processes with a time limit and cancellation: once, or several runs at once.

QuadriFlow (through ``pyQuadriFlow``) can, on rare inputs, loop forever or
crash inside C++, so it runs in :mod:`cam.remesh.child`: the request goes in on
stdin and the result comes back on stdout, both as npz. The parent waits in
short steps so that it can kill the child at the deadline or when the caller
cancels. `QuadriflowRuns` keeps several such children going on one mesh, so that
the runs a remesh will want next are already running when it wants them.
"""

from __future__ import annotations

import io
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from cam import CheckCancel

__all__ = ["QuadriflowFailed", "QuadriflowRuns", "run_quadriflow"]

# How often, s, the wait on the child wakes to check the deadline and cancellation.
_CHECK_EVERY_S = 0.25
# The child's own alarm, s beyond the parent's limit: it ends the child should the parent die without killing it.
_CHILD_GRACE_S = 30.0
# Once a run on a mesh has given a mesh, a later run on it that takes this many times as long is taken to hang (QuadriFlow
# loops forever on rare inputs; its time for one mesh and target varies by a factor of about two between seeds and
# two children sharing two cores), but never before _HANG_FLOOR_S.
_HANG_FACTOR = 4.0
_HANG_FLOOR_S = 15.0
# While no run on a mesh has given a mesh, every run going has run this long (s) and a spare run is named, the spare
# starts beside them. A whole remesh of three runs takes 8-78 s on bench/remesh.py's parts (one thin plate, abc5,
# 316 s) and about 20 s on 50k-point clouds' meshes; two seeds once hung side by side on a cloud's mesh and the
# remesh waited out its 300 s limit while a third seed then gave a mesh in 6 s. A spare that gives a mesh sets the
# pace, and the hung runs stop; a spare beside runs that are merely slow only costs a core for a while.
_STALL_S = 60.0


class QuadriflowFailed(RuntimeError):
    """One QuadriFlow run gave no result (timeout, crash, error); the message says which.

    :func:`cam.remesh.quadriflow.remesh_quads` catches it and tries the next seed; it reaches the user only
    as part of a :class:`cam.remesh.quadriflow.RemeshFailed`.
    """


def run_quadriflow(
    vertices: np.ndarray,
    triangles: np.ndarray,
    *,
    target_faces: int,
    seed: int,
    preserve_sharp: bool = True,
    preserve_boundary: bool = False,
    min_cost_flow: bool = False,
    timeout_s: float = 600.0,
    check_cancel: CheckCancel | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run QuadriFlow once in a child process.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    triangles
        int (m, 3) vertex indices.
    target_faces
        Quads QuadriFlow aims for (it lands within a few tens of percent).
    seed
        QuadriFlow's random seed.
    preserve_sharp, preserve_boundary, min_cost_flow
        QuadriFlow's ``-sharp``, ``-boundary`` and ``-mcf`` switches.
    timeout_s
        Wall-clock limit, s; the child is killed after it.
    check_cancel
        Called about four times a second while the child runs; whatever it
        raises (the caller's cancellation) kills the child and propagates.

    Returns
    -------
    vertices : ndarray
        float64 (n', 3), mm, holding single-precision values.
    faces : ndarray
        int64 (m', 4) vertex indices.

    Raises
    ------
    QuadriflowFailed
        On timeout, a crash, an error reported by QuadriFlow or unreadable output.
    """
    runs = QuadriflowRuns(vertices, triangles, preserve_sharp=preserve_sharp, preserve_boundary=preserve_boundary,
                          min_cost_flow=min_cost_flow, timeout_s=timeout_s, processes=1)
    try:
        out_vertices, out_faces, _, _ = runs.result((target_faces, seed), check_cancel=check_cancel)
    finally:
        runs.close()
    return out_vertices, out_faces


class QuadriflowRuns:
    """QuadriFlow runs on one mesh, up to `processes` children at once, each keyed by (target_faces, seed).

    `plan(keys, spare)` says which runs are wanted next, in order: children running for any other key (or the
    spare) are killed, and children are started for the first keys while fewer than `processes` run. The
    spare (the run wanted should the first key fail) starts beside them, over `processes`, once every run
    going has run `_STALL_S` with no run on the mesh having given a mesh yet. `result(key)` waits for
    that run (starting it if need be), checking every child's time limit and the caller's cancellation
    four times a second, and returns its vertices and faces, its seconds and its start on
    `time.monotonic`, or raises its `QuadriflowFailed`. `close()` kills what still runs. A run's result
    does not depend on what runs beside it: QuadriFlow is deterministic for a mesh, a target and a seed.

    A run's limit is `timeout_s`, or, once some run on the mesh has given a mesh in t seconds (the awaited
    runs, and those beside them as soon as they end), the smaller of that and max(15 s, 4 t): a run that takes
    four times as long as one that gave a mesh hangs, and waiting the full limit for it made a 3,000-point
    example wait five minutes.

    Parameters
    ----------
    vertices, triangles
        float (n, 3), mm, and int (m, 3): the mesh.
    preserve_sharp, preserve_boundary, min_cost_flow, timeout_s
        As for `run_quadriflow`; the limit holds for each run from its start.
    processes
        Most children at once (at least 1).
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, *, preserve_sharp: bool, preserve_boundary: bool,
                 min_cost_flow: bool, timeout_s: float, processes: int) -> None:
        self._mesh = (vertices, triangles)
        self._switches = {"preserve_sharp": preserve_sharp, "preserve_boundary": preserve_boundary,
                          "min_cost_flow": min_cost_flow}
        self._timeout_s = float(timeout_s)
        self._processes = max(1, int(processes))
        self._running: dict[tuple[int, int], tuple[subprocess.Popen, threading.Thread, dict, float]] = {}
        self._quickest_s: float | None = None  # the shortest run that gave a mesh
        self._spare: tuple[int, int] | None = None

    def _limit_s(self) -> float:
        if self._quickest_s is None:
            return self._timeout_s
        return min(self._timeout_s, max(_HANG_FLOOR_S, _HANG_FACTOR * self._quickest_s))

    def plan(self, keys: list[tuple[int, int]], spare: tuple[int, int] | None = None) -> None:
        """Keep the runs of `keys` and `spare` only, and start the first keys while fewer than `processes` run."""
        self._spare = spare
        for key in [k for k in self._running if k not in keys and k != spare]:
            self._stop(key)
        for key in keys:
            if len(self._running) >= self._processes:
                break
            if key not in self._running:
                self._start(key)

    def result(self, key: tuple[int, int], *, check_cancel: CheckCancel | None = None
               ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """The run of `key`: (vertices, faces, seconds, start), or its QuadriflowFailed raised."""
        if key not in self._running:
            self._start(key)
        proc, talker, out, started = self._running[key]
        try:
            while talker.is_alive():
                self._pace_from_finished()
                self._start_spare_if_stalled()
                limit = self._limit_s()
                talker.join(max(0.0, min(_CHECK_EVERY_S, started + limit - time.monotonic())))
                if not talker.is_alive():
                    break
                if time.monotonic() > started + limit:
                    quick = "" if limit == self._timeout_s else f", {_HANG_FACTOR:g} times the quickest run's"
                    raise QuadriflowFailed(f"timed out after {limit:.0f} s{quick}")
                if check_cancel is not None:
                    check_cancel()
        finally:
            self._stop(key)
        seconds = out["ended"] - started
        vertices, faces = _decode_result(proc.returncode, out.get("out", b""), out.get("err", b""))
        # Only a run that gave a mesh sets the pace: a crash ends in no time and says nothing of how long a run takes.
        self._note_pace(seconds)
        return vertices, faces, seconds, started

    def _pace_from_finished(self) -> None:
        # A run beside the awaited one that has given a mesh sets the pace at once: on a 50k-point Fandisk the
        # first seed hung while the second, beside it, gave a mesh in 14 s, and the first still ran its full 300 s.
        for proc, talker, out, started in self._running.values():
            if not talker.is_alive() and proc.returncode == 0 and out.get("out"):
                self._note_pace(out["ended"] - started)

    def _start_spare_if_stalled(self) -> None:
        if self._quickest_s is not None or self._spare is None or self._spare in self._running:
            return
        now = time.monotonic()
        if all(now - started >= _STALL_S for _, _, _, started in self._running.values()):
            self._start(self._spare)

    def _note_pace(self, seconds: float) -> None:
        self._quickest_s = seconds if self._quickest_s is None else min(self._quickest_s, seconds)

    def close(self) -> None:
        """Kill every child still running."""
        for key in list(self._running):
            self._stop(key)

    def _start(self, key: tuple[int, int]) -> None:
        target, seed = key
        request = _encode_request(*self._mesh, target_faces=target, seed=seed, timeout_s=self._timeout_s,
                                  **self._switches)
        proc = _start_child()
        out: dict = {}

        def talk() -> None:
            # communicate() in a thread: polling communicate(timeout=...) cannot resume sending stdin.
            out["out"], out["err"] = proc.communicate(input=request)
            out["ended"] = time.monotonic()

        talker = threading.Thread(target=talk, daemon=True)
        talker.start()
        self._running[key] = (proc, talker, out, time.monotonic())

    def _stop(self, key: tuple[int, int]) -> None:
        proc, talker, _, _ = self._running.pop(key)
        if proc.poll() is None:
            proc.kill()
        talker.join()


def _encode_request(vertices: np.ndarray, triangles: np.ndarray, *, target_faces: int, seed: int,
                    preserve_sharp: bool, preserve_boundary: bool, min_cost_flow: bool, timeout_s: float) -> bytes:
    """The npz the child reads on stdin (see :mod:`cam.remesh.child`)."""
    buf = io.BytesIO()
    np.savez(buf, vertices=np.asarray(vertices, dtype=np.float64), faces=np.asarray(triangles, dtype=np.int64),
             target_faces=int(target_faces), seed=int(seed), preserve_sharp=bool(preserve_sharp),
             preserve_boundary=bool(preserve_boundary), min_cost_flow=bool(min_cost_flow),
             limit_s=float(timeout_s) + _CHILD_GRACE_S)
    return buf.getvalue()


def _start_child() -> subprocess.Popen:
    """``python -P cam/remesh/child.py`` with pipes on stdin, stdout and stderr.

    The file, not the module: ``-m`` would import the packages above it first (``cam.remesh`` brings scipy,
    numba and trimesh: 0.75 s of every run's start), and the child needs numpy and QuadriFlow alone. ``-P``:
    its folder is not put on the path, where its neighbours' names could shadow a library's modules.
    """
    return subprocess.Popen([sys.executable, "-P", str(Path(__file__).resolve().with_name("child.py"))],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _decode_result(returncode: int | None, out: bytes, err: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The child's vertices and faces, or QuadriflowFailed naming its exit status and last line of stderr."""
    message = err.decode("utf-8", errors="replace").strip().splitlines()
    tail = message[-1] if message else ""
    if returncode == 3:
        raise QuadriflowFailed(f"QuadriFlow reported an error: {tail}")
    if returncode != 0:
        raise QuadriflowFailed(f"QuadriFlow crashed (exit status {returncode}){': ' + tail if tail else ''}")
    try:
        data = np.load(io.BytesIO(out))
        return data["vertices"], data["faces"]
    except Exception as exc:
        raise QuadriflowFailed(f"unreadable output from the QuadriFlow process ({exc})") from exc
