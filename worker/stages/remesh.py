"""The `remesh` stage: the quad layout of `mesh.ply` (crease-first, or QuadriFlow's), checked, written as `quads.obj`."""

from __future__ import annotations

from pathlib import Path

from cam import GeometryError
from cam.io import read_ply, write_json
from cam.io.quads import write_quad_obj
from cam.remesh.quadriflow import remesh_quads
from core.config import stage_processes
from worker.context import StageContext, StageError, StageSkipped


def run_remesh(ctx: StageContext) -> dict[str, Path]:
    ctx.progress(0.02, "reading the mesh")
    mesh = ctx.read("mesh.ply", read_ply)
    if mesh.faces is None or len(mesh.faces) == 0:
        raise StageError("mesh.ply has no faces; the remesh stage needs a triangle mesh")
    try:
        # Crease recall and straddling quads in remesh.json are measured at segment's default θ, not at
        # segment.sharp_angle_deg: this stage's cache key holds the remesh group only.
        result = remesh_quads(mesh.points, mesh.faces, ctx.params.remesh, progress=ctx.progress_between(0.05, 0.9),
                              check_cancel=ctx.check_cancel,
                              processes=stage_processes(ctx.settings.get("stage_processes")))
    except GeometryError as exc:
        # No quad layout, no patches: the job goes on, and plan finishes the part from mesh.ply alone.
        raise StageSkipped(f"no usable quad layout ({exc}); plan finishes the part from mesh.ply without "
                           "patch passes") from exc
    ctx.check_cancel()
    ctx.progress(0.95, "writing quads.obj")
    report = result.report
    out = {
        "quads.obj": write_quad_obj(
            ctx.output("quads.obj"), result.vertices, result.faces,
            comments=[(f"cloud2cnc remesh: {_made_by(report)}, {report['faces']} quads, "
                      f"Hausdorff {report['hausdorff_mm']:.4g} mm, {report['missed_crease_mm']:.4g} of "
                      f"{report['crease_length_mm']:.4g} mm of creases not followed")],
        ),
        "remesh.json": write_json(ctx.output("remesh.json"), report),
    }
    ctx.progress(1.0, None)
    return out


def _made_by(report: dict) -> str:
    if report["layout"] == "creases":
        return f"crease-first layout, coarse edges of {report['coarse_edge_quads']:g} quads"
    return f"QuadriFlow seed {report['seed']}"
