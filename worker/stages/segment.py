"""The `segment` stage: `quads.obj` → `patches.json`, `segments.ply`, `setup.json` (the paper's MST segmentation)."""

from __future__ import annotations

import colorsys
from pathlib import Path

import numpy as np

from cam import GeometryError
from cam.io import write_json
from cam.io.quads import read_quad_obj, write_ply_quads_colored
from cam.mesh.quads import face_normals
from cam.params import SegmentParams
from cam.segment import Segmentation, segment_quads
from worker.context import StageContext, StageSkipped

BASE_COLOR = (90, 90, 90)
INVALID_COLOR = (255, 0, 0)


def patch_colors(labels: np.ndarray, invalid: set[int]) -> np.ndarray:
    """uint8 (m, 3): a distinct colour per patch (golden-ratio hues), grey for the base, red for invalid patches."""
    ids = np.arange(labels.max() + 1 if labels.size and labels.max() >= 0 else 0)
    table = np.array([colorsys.hsv_to_rgb((0.13 + 0.618034 * i) % 1.0, 0.45 + 0.3 * ((i * 7) % 3) / 2,
                                          0.95 - 0.15 * ((i * 5) % 2)) for i in ids]).reshape(-1, 3)
    table = (table * 255).round().astype(np.uint8)
    for i in invalid:
        table[i] = INVALID_COLOR
    colors = np.empty((len(labels), 3), dtype=np.uint8)
    colors[labels < 0] = BASE_COLOR
    colors[labels >= 0] = table[labels[labels >= 0]]
    return colors


def patches_document(seg: Segmentation, params: SegmentParams) -> dict:
    """The `patches.json` body: DESIGN's fields plus grids, neighbours, boundary polylines and diagnostics,
    and the segment parameters used."""
    patches = []
    for p in seg.patches:
        patches.append({
            "id": p.id, "faces": p.faces.tolist(), "rows": p.rows, "cols": p.cols, "corners": list(p.corners),
            "sharp_boundary": bool(any(p.sharp_sides)), "sharp_sides": list(p.sharp_sides),
            "neighbors": list(p.neighbors), "boundary": p.sides(), "grid": p.grid.tolist(),
            "face_grid": p.face_grid.tolist(), "valid": p.valid, "problems": list(p.problems),
        })
    return {
        "patches": patches, "base_faces": seg.base_faces.tolist(), "sharp_edges": seg.sharp_edges.tolist(),
        "clipping_edges": seg.cut_edges.tolist(), "extraordinary_points": seg.extraordinary.tolist(),
        "stats": seg.stats, "params": params.model_dump(mode="json"),
    }


def setup_document(seg: Segmentation, vertices: np.ndarray, faces: np.ndarray) -> dict:
    """The `setup.json` body: one setup from the base (the plan stage refines it)."""
    axis = seg.base.tool_axis
    normals = face_normals(vertices, faces)
    unmachined = []
    for p in seg.patches:
        if (normals[p.faces] @ axis).max() < 0:
            unmachined.append({"patch": p.id, "reason": "faces away from the tool axis (an undercut for this setup)"})
    base = seg.base
    return {
        "setups": [{
            "id": 1, "rotation": base.rotation.tolist(), "translation": base.translation.tolist(),
            "program": "program.nc", "tool_axis": axis.tolist(), "patches": [p.id for p in seg.patches],
            "unmachined": unmachined,
        }],
        "base": {"faces": len(seg.base_faces), "clusters": list(base.clusters), "chosen": base.chosen},
    }


def _failure_message(seg: Segmentation) -> str:
    bad = seg.invalid
    parts = []
    for p in bad[:5]:
        sample = ", ".join(str(f) for f in p.faces[:4].tolist()) + (", …" if len(p.faces) > 4 else "")
        parts.append(f"patch {p.id} ({len(p.faces)} quads: {sample}): {p.problems[0]}")
    more = f"; and {len(bad) - 5} more" if len(bad) > 5 else ""
    missing = seg.stats["sharp_in_domain"] - seg.stats["sharp_on_boundary"]
    sharp = f"{missing} sharp edges are not on a patch boundary; " if missing else ""
    return (f"{sharp}{len(bad)} of {len(seg.patches)} patches are not sharp height fields: " + "; ".join(parts)
            + more + ". segments.ply shows them in red; try another remesh.target_faces or segment.sharp_angle_deg")


def run_segment(ctx: StageContext) -> dict[str, Path]:
    params = ctx.params.segment
    if "quads.obj" not in ctx.inputs:
        raise StageSkipped("remesh made no quad mesh: no patches; plan finishes the part from mesh.ply alone")
    ctx.progress(0.02, "reading quads.obj")
    vertices, faces = ctx.read("quads.obj", read_quad_obj)
    try:
        seg = segment_quads(vertices, faces, params, progress=ctx.progress_between(0.05, 0.9),
                            check_cancel=ctx.check_cancel)
    except GeometryError as exc:  # the message names the mesh's defect; the user also needs to know which file
        raise StageSkipped(f"cannot segment quads.obj ({exc}); plan finishes the part from mesh.ply without "
                           "patch passes") from exc
    ctx.progress(0.92, "writing")
    invalid = {p.id for p in seg.invalid}
    out = {
        "segments.ply": write_ply_quads_colored(
            ctx.output("segments.ply"), vertices, faces, patch_colors(seg.labels, invalid), labels=seg.labels,
            comments=[f"cloud2cnc segment: {len(seg.patches)} patches, base faces in grey, invalid in red"],
        ),
        "patches.json": write_json(ctx.output("patches.json"), patches_document(seg, params)),
    }
    if len(seg.invalid) == len(seg.patches):
        # Nothing to fit: kept for inspection, and plan finishes the part from the mesh.
        raise StageSkipped(_failure_message(seg) + "; plan finishes the part from mesh.ply without patch passes",
                           outputs=out)
    out["setup.json"] = write_json(ctx.output("setup.json"), setup_document(seg, vertices, faces))
    # Invalid patches are listed in patches.json (valid: false); fit leaves them out and plan finishes
    # their area from the mesh.
    ctx.progress(1.0, None if seg.ok else _failure_message(seg) + "; fit leaves them out")
    return out
