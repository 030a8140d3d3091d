"""Bicubic B-spline surfaces fitted to the denoised mesh, one per patch, meeting exactly along shared borders.

Entry point: `cam.fit.patches.fit_patches` (quad-grid patches + triangle mesh + `cam.params.FitParams`
-> surfaces and errors). Modules, one concept each: `grid` (a patch's quads as a vertex grid), `param`
(samples, seed parameters, foot points, anchors), `solve` (the squared-distance iteration), `boundary`
(shared segments and the curves carrying them), `curve` (fitting one boundary curve), `crease` (moving
sharp borders onto the mesh's creases), `measure` (a surface's worst distances from the mesh, searched
for), `refine` (knot insertion where the error stays high), `patches` (the whole fit). B-spline basics
come from `cam.spline`, distances to the mesh from `cam.mesh.closest`.

What a user can act on is raised as a `cam.GeometryError`: `PatchGridError` (a patch that is no
rectangular grid of quads), `PatchLayoutError` (patches that overlap along an edge).
"""

from cam.fit.boundary import PatchLayoutError
from cam.fit.grid import PatchGridError, orient_grid, patch_grid
from cam.fit.patches import FitResult, PatchFit, fit_patches

__all__ = ["FitResult", "PatchFit", "PatchGridError", "PatchLayoutError", "fit_patches", "orient_grid",
           "patch_grid"]
