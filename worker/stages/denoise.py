"""The `denoise` stage: MeshTGV on `mesh_raw.ply`, written as `mesh.ply` with its report in `denoise.json`."""

from __future__ import annotations

import shutil
from pathlib import Path

from cam import GeometryError
from cam.denoise import denoise_mesh, measure_shift
from cam.io import read_ply, write_json, write_ply_mesh
from core.config import stage_processes
from worker.context import StageContext, StageError, StageSkipped


def run_denoise(ctx: StageContext) -> dict[str, Path]:
    params = ctx.params.denoise
    if "mesh_raw.ply" not in ctx.inputs:
        raise StageError("this job has no mesh_raw.ply to denoise (reconstruct produced none)")
    if not params.enabled:
        # A copy, not a link: the store takes ownership of what the stage leaves in its output folder.
        passed = ctx.output("mesh.ply")
        shutil.copyfile(ctx.inputs["mesh_raw.ply"], passed)
        raise StageSkipped("denoise.enabled is false: mesh_raw.ply is passed on as mesh.ply",
                           outputs={"mesh.ply": passed})
    ctx.progress(0.0, "reading mesh_raw.ply")
    mesh = ctx.read("mesh_raw.ply", read_ply)
    if mesh.faces is None or not len(mesh.faces):
        raise StageError("mesh_raw.ply has no faces; denoise needs a triangle mesh")
    try:
        result = denoise_mesh(mesh.points, mesh.faces, params, progress=ctx.progress, check_cancel=ctx.check_cancel,
                              processes=stage_processes(ctx.settings.get("stage_processes")))
    except GeometryError as exc:
        # The core's message describes the mesh; the user needs to know which file it means.
        raise StageError(f"cannot denoise mesh_raw.ply: {exc}") from exc
    ctx.check_cancel()
    shift = measure_shift(mesh.points, result.vertices, mesh.faces)
    report = {"iterations": result.iterations, **result.report,
              "shift": {"max_mm": shift.max_mm, "diagonal_mm": shift.diagonal_mm, "volume_ratio": shift.volume_ratio,
                        "kept": not shift.too_far}}
    if shift.too_far:
        # Another shape, not the part without its noise: plan must not machine it. The input goes on.
        passed = ctx.output("mesh.ply")
        shutil.copyfile(ctx.inputs["mesh_raw.ply"], passed)
        raise StageSkipped(f"MeshTGV would change the part, not only its noise ({shift.describe()}): mesh_raw.ply is "
                           "passed on as mesh.ply (see denoise.json)",
                           outputs={"mesh.ply": passed, "denoise.json": write_json(ctx.output("denoise.json"), report)})
    out = {
        "mesh.ply": write_ply_mesh(ctx.output("mesh.ply"), result.vertices, mesh.faces,
                                   comments=[f"cloud2cnc denoise: MeshTGV, {result.iterations} iterations"]),
        "denoise.json": write_json(ctx.output("denoise.json"), report),
    }
    ctx.progress(1.0, None)
    return out
