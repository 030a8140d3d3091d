"""Bicubic B-spline surfaces fitted to the denoised mesh, one per patch, meeting exactly along shared borders.

Entry point: `cam.fit.patches.fit_patches` (quad-grid patches + triangle mesh + `cam.params.FitParams`
-> surfaces and errors). Modules, one concept each:

- `grid`: a patch's quads as a vertex grid;
- `param`: mesh samples, the patch and seed parameters each falls in, the grid's anchors;
- `foot`: foot points on a surface and the surface's frame there, distances without a guess;
- `system`: the least-squares terms of one squared-distance step and their normal equations;
- `solve`: the squared-distance iteration for one surface;
- `measure`: a surface's distances from the mesh, on a fixed lattice and at its worst points searched for;
- `refine`: knot insertion where the error stays high;
- `boundary`: shared segments and the curves carrying them;
- `curve`: fitting one boundary curve;
- `crease`: moving sharp borders onto the mesh's creases;
- `borders`: the boundary curves fitted from the free fits and the creases, and the border rows they give;
- `report`: the records the fit returns, measured afresh on every sample;
- `patches`: the whole fit.

B-spline basics come from `cam.spline`, distances to the mesh from `cam.mesh.closest`.

What a user can act on is raised as a `cam.GeometryError`: `PatchGridError` (a patch that is no
rectangular grid of quads), `PatchLayoutError` (patches that overlap along an edge).
"""

from cam.fit.boundary import PatchLayoutError
from cam.fit.grid import PatchGridError, orient_grid, patch_grid
from cam.fit.patches import FitResult, PatchFit, fit_patches

__all__ = ["FitResult", "PatchFit", "PatchGridError", "PatchLayoutError", "fit_patches", "orient_grid",
           "patch_grid"]
