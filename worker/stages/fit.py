"""The `fit` stage: one bicubic B-spline surface per patch, C0 across patches, as `surfaces.json`, `surfaces.igs`
and `surfaces.step`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cam import GeometryError
from cam.fit.grid import PatchGridError, orient_grid, patch_grid
from cam.fit.patches import FitResult, fit_patches
from cam.io import read_json, read_ply, write_json
from cam.io.iges import write_iges
from cam.io.quads import read_quad_obj
from cam.io.step import write_step
from core.config import stage_processes
from worker.context import StageContext, StageError, StageSkipped


def run_fit(ctx: StageContext) -> dict[str, Path]:
    params = ctx.params.effective("fit")  # tolerance_mm resolved from the scallop height when unset
    if "patches.json" not in ctx.inputs or "quads.obj" not in ctx.inputs:
        raise StageSkipped("segment made no patches: nothing to fit; plan finishes the part from mesh.ply alone")
    ctx.progress(0.02, "reading the quad mesh, patches and mesh")
    vertices, quads = ctx.read("quads.obj", read_quad_obj)
    patches, sharp_edges = _patches(ctx.read("patches.json", read_json))
    mesh = ctx.read("mesh.ply", read_ply)
    if mesh.faces is None or not len(mesh.faces):
        raise StageError("mesh.ply has no triangles to fit the surfaces to")
    grids, ids, skipped = [], [], []
    in_patch = np.zeros(len(quads), dtype=bool)
    for p in patches:
        if p.get("valid") is False:
            # Segment says this patch is no height-field grid; its quads are left out, not forced.
            skipped.append({"patch": int(p["id"]), "reason": "; ".join(p.get("problems") or ["not a quad grid"])})
            continue
        try:
            if p.get("grid") is not None:
                grid = orient_grid(quads, p["grid"])
            else:
                grid = patch_grid(quads, p["faces"], corner=(p.get("corners") or [None])[0], rows=p.get("rows"),
                                  cols=p.get("cols"))
        except PatchGridError as exc:
            # Left out like an invalid patch: plan finishes its area from the mesh.
            skipped.append({"patch": int(p["id"]), "reason": f"not a rectangular grid of quads ({exc})"})
            continue
        grids.append(grid)
        ids.append(int(p["id"]))
        in_patch[np.asarray(p["faces"], dtype=np.int64)] = True
    if not grids:
        raise StageSkipped("segment left no patch that is a grid of quads: nothing to fit; plan finishes the part "
                           "from mesh.ply alone")
    ctx.check_cancel()
    try:
        result = fit_patches(vertices, grids, mesh.points, mesh.faces, params, other_quads=quads[~in_patch],
                             sharp_edges=sharp_edges, processes=stage_processes(ctx.settings.get("stage_processes")),
                             progress=ctx.progress_between(0.05, 0.9),
                             check_cancel=ctx.check_cancel)
    except GeometryError as exc:
        raise StageSkipped(f"the patches cannot be fitted ({exc}); plan finishes the part from mesh.ply without "
                           "patch passes") from exc
    ctx.progress(0.92, "writing surfaces.json, surfaces.igs and surfaces.step")
    shapes = [(g.shape[0] - 1, g.shape[1] - 1) for g in grids]
    document = surfaces_document(result, ids, skipped, shapes)
    surfaces = [p.surface for p in result.patches]
    out = {"surfaces.json": write_json(ctx.output("surfaces.json"), document),
           "surfaces.igs": write_iges(ctx.output("surfaces.igs"), surfaces, labels=ids),
           "surfaces.step": write_step(ctx.output("surfaces.step"), surfaces, labels=ids)}
    over = [ids[k] for k in result.over_tolerance]
    # Where the worst point is next to a crease of the mesh, the layout is what to change, not the fit.
    at_crease = [ids[k] for k in result.at_crease]
    if over and params.require_tolerance:
        worst = max(result.patches, key=lambda p: p.max_error_mm)
        layout = (f"; {len(at_crease)} of them ({at_crease}) have it at a crease of the mesh that their patch "
                  "layout does not follow, which remesh's or segment's parameters change, not the fit's"
                  ) if at_crease else ""
        raise StageError(f"{len(over)} of {len(ids)} patches deviate from the mesh by more than "
                         f"fit.tolerance_mm = {result.tolerance_mm} mm (worst: patch {ids[worst.index]}, "
                         f"{worst.max_error_mm:.4f} mm){layout}; raise fit.tolerance_mm or fit.max_refinements, or "
                         "set fit.require_tolerance to false to accept them", outputs=out)
    folded = [ids[k] for k in result.folded]
    notes = ([f"{len(over)} patches over tolerance: {over}"
              + (f" ({len(at_crease)} at a crease of the mesh their layout does not follow: {at_crease})"
                 if at_crease else "")] if over else []) + (
        [f"{len(folded)} surfaces fold over themselves: {folded}"] if folded else [])
    ctx.progress(1.0, "; ".join(notes) or None)
    return out


def surfaces_document(result: FitResult, ids: list[int], skipped: list[dict] | None = None,
                      shapes: list[tuple[int, int]] | None = None) -> dict[str, Any]:
    """`surfaces.json`: DESIGN's fields per surface plus its quad grid (rows x cols), errors, neighbours,
    and the largest C0 gap."""
    surfaces = []
    for p in result.patches:
        rows, cols = shapes[p.index] if shapes else (None, None)
        entry = {"patch": ids[p.index], **p.surface.to_json(), "rows": rows, "cols": cols,
                 "max_error_mm": p.max_error_mm,
                 "mean_error_mm": p.mean_error_mm, "surface_to_mesh_mm": p.surface_to_mesh_mm,
                 "boundary_error_mm": p.boundary_error_mm, "within_tolerance": p.within_tolerance,
                 "folded_fraction": p.folded_fraction,
                 "worst_point_mm": [float(x) for x in p.worst_point_mm],
                 "worst_crease_mm": p.worst_crease_mm if np.isfinite(p.worst_crease_mm) else None,
                 "samples": p.samples, "refinements": p.refinements,
                 "neighbours": [ids[k] for k in p.neighbours],
                 "sides": {name: [ids[k] for k in nb] for name, nb in p.side_neighbours.items()}}
        surfaces.append(entry)
    return {"units": "mm", "tolerance_mm": result.tolerance_mm, "max_c0_gap_mm": result.max_gap_mm,
            "boundary_curves": result.curves, "over_tolerance": [ids[k] for k in result.over_tolerance],
            "folded": [ids[k] for k in result.folded], "at_crease": [ids[k] for k in result.at_crease],
            "skipped": list(skipped or []), "surfaces": surfaces}


def _patches(doc: Any) -> tuple[list[dict[str, Any]], np.ndarray]:
    """The patches of the `patches.json` document and its sharp edges (int (k, 2) quad-mesh vertex pairs)."""
    try:
        patches = list(doc["patches"])
        for p in patches:
            p["id"], p["faces"] = int(p["id"]), [int(f) for f in p["faces"]]
            if p.get("grid") is not None:
                p["grid"] = np.asarray(p["grid"], dtype=np.int64)
        sharp = np.asarray(doc.get("sharp_edges") or [], dtype=np.int64).reshape(-1, 2)
    except (ValueError, KeyError, TypeError) as exc:
        # The document as segment wrote it has these fields; anything else is a file the user can replace.
        raise StageError(f"patches.json is not what segment writes: {exc}") from exc
    if not patches:
        raise StageError("segment found no patches to fit")
    return patches, sharp
