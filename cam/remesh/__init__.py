"""The `remesh` stage: a checked quad mesh of the denoised triangle mesh.

`quadriflow` runs QuadriFlow (in the child process of `child`, with a timeout) and keeps the best
checked candidate; `check` inspects and repairs a quad mesh; `creases` measures how much of the
input's creases the quad edges follow.
"""

from cam.remesh.quadriflow import (
    QuadriflowFailed,
    RemeshFailed,
    RemeshResult,
    boundary_loop_count,
    remesh_quads,
    run_quadriflow,
)

__all__ = ["QuadriflowFailed", "RemeshFailed", "RemeshResult", "boundary_loop_count", "remesh_quads",
           "run_quadriflow"]
