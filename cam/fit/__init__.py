"""Bicubic B-spline surfaces fitted to the denoised mesh, one per patch, meeting exactly along shared borders.

Entry point: `cam.fit.patches.fit_patches` (quad-grid patches + triangle mesh -> surfaces and
errors). Modules, one concept each: `basis` (basis functions, design and bending matrices),
`knots` (exact knot insertion, splitting, joining), `grid` (a patch's quads as a vertex
grid), `param` (samples, seed parameters, foot points, anchors), `solve` (the squared-distance iteration), `boundary` (shared segments and
the curves carrying them), `curve` (fitting one boundary curve), `crease` (moving sharp
borders onto the mesh's creases), `measure` (a surface's worst distances from the mesh, searched for),
`refine` (knot insertion where the error stays high),
`patches` (the whole fit). Distances to the mesh come from `cam.mesh.closest`.
"""

from cam.fit.grid import orient_grid, patch_grid
from cam.fit.patches import FitResult, PatchFit, fit_patches

__all__ = ["FitResult", "PatchFit", "fit_patches", "orient_grid", "patch_grid"]
