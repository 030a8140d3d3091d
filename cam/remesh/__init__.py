"""The `remesh` stage: a checked quad mesh of the denoised triangle mesh.

`quadriflow` holds the entry point: it runs QuadriFlow several times (`process`, in the child process
of `child`, with a timeout), brings each result onto the input and checks it (`accept`), and keeps the
one whose edges follow the most of the input's creases (`creases`); with `remesh.snap_creases` each is first
moved so that its edges run along them (`snap`, along the crease chains of `chains`). `check` inspects a quad mesh,
`repair` fixes what is small and safe, and `holes` closes the odd holes QuadriFlow leaves.
"""

from cam.remesh.process import QuadriflowFailed, run_quadriflow
from cam.remesh.quadriflow import (
    RemeshFailed,
    RemeshResult,
    boundary_loop_count,
    remesh_quads,
)

__all__ = ["QuadriflowFailed", "RemeshFailed", "RemeshResult", "boundary_loop_count", "remesh_quads",
           "run_quadriflow"]
