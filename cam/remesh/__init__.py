"""The `remesh` stage: a checked quad mesh of the denoised triangle mesh.

`quadriflow` holds the entry point, `remesh_quads`. With ``remesh.layout = "creases"`` it makes the crease-first
layout of `layout`: the creases as chains (`features`), a coarse triangle mesh that keeps them as edge paths
(`coarse`, its collapses compiled in `_collapsekernel`), its triangles paired into quads (`pairing`), split into
coarse quads and rotated towards valence four (`coarsequads`), edge counts per strip (`quantize`) and grids on the
part (`subdivide`). Otherwise, or where that layout fails, it runs QuadriFlow several times (`process`, in the child
process of `child`, with a timeout), brings each result onto the input and checks it (`accept`), and keeps the
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
