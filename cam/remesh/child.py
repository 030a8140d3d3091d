"""Child-process entry that runs QuadriFlow once: arrays in on stdin, arrays out on stdout (npz).

QuadriFlow runs in its own process because it can, on rare inputs, loop
forever or crash inside C++; the parent (:mod:`cam.remesh.quadriflow`) kills it on a
timeout. Run as ``python -P cam/remesh/child.py`` (it imports nothing of the project). Exit status 0 = result
written, 3 = QuadriFlow reported an error (message on stderr).
"""

from __future__ import annotations

import io
import math
import os
import signal
import sys

import numpy as np


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _die_with_parent(limit_s: float) -> None:
    """Never outlive the parent or the time limit, even if the parent is killed (SIGKILL cannot be caught)."""
    if hasattr(signal, "alarm") and limit_s > 0:
        signal.alarm(math.ceil(limit_s))  # default SIGALRM action ends the process
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG (Linux): die when the parent dies
    except (OSError, AttributeError):
        pass


def main() -> int:
    request = np.load(io.BytesIO(sys.stdin.buffer.read()))
    _die_with_parent(float(request["limit_s"]))
    # Anything the C++ library prints must not corrupt the npz on stdout: point fd 1 at stderr.
    result_fd = os.dup(1)
    os.dup2(2, 1)
    from pyQuadriFlow.pyQuadriFlow import pyquadriflow

    try:
        mesh = pyquadriflow(
            int(request["target_faces"]),
            int(request["seed"]),
            request["vertices"].tolist(),
            request["faces"].tolist(),
            bool(request["preserve_sharp"]),
            bool(request["preserve_boundary"]),
            False,  # adaptive scale: ignored by this build
            False,  # aggressive SAT: ignored by this build
            bool(request["min_cost_flow"]),
        )
    except Exception as exc:  # noqa: BLE001 — the library raises a bare Exception with its message
        print(f"{exc}", file=sys.stderr)
        return 3
    buf = io.BytesIO()
    np.savez(buf, vertices=np.asarray(mesh["vertices"], dtype=np.float64).reshape(-1, 3),
             faces=np.asarray(mesh["faces"], dtype=np.int64).reshape(-1, 4))
    _write_all(result_fd, buf.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
