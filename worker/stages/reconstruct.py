"""The `reconstruct` stage: `cloud.ply` -> IGR -> `mesh_raw.ply` (a watertight triangle mesh, mm)."""

from __future__ import annotations

from pathlib import Path

from cam.io import read_ply, write_ply_mesh
from cam.reconstruct import ReconstructionCanceled, reconstruct_surface
from worker.context import StageCanceled, StageContext, StageError, StageSkipped

# JobParams.reconstruct fields passed to the core under the same names.
_CORE_OPTIONS = ("preset", "iterations", "batch_size", "grid_cells", "width", "depth", "resolution",
                 "learning_rate", "eikonal_weight", "normal_weight", "normals_k", "max_faces", "sharpen", "seed")


def run_reconstruct(ctx: StageContext) -> dict[str, Path]:
    if "cloud.ply" not in ctx.inputs:
        raise StageSkipped("the upload is a mesh: it is passed on as mesh_raw.ply without reconstruction")
    params = ctx.params.get("reconstruct", {})
    options = {k: params[k] for k in _CORE_OPTIONS if k in params}
    ctx.progress(0.0, "reading the cloud")
    cloud = ctx.read("cloud.ply", read_ply)
    if cloud.faces is not None:
        raise StageError("cloud.ply holds a mesh, not a point cloud; mesh uploads skip reconstruct")
    threads = ctx.settings.get("blas_threads") or 1

    def should_cancel() -> bool:
        ctx.check_cancel()  # raises StageCanceled, which passes through the core untouched
        return False

    try:
        result = reconstruct_surface(cloud.points, cloud.normals, threads=int(threads),
                                     progress=ctx.progress, should_cancel=should_cancel, **options)
    except ReconstructionCanceled as exc:
        raise StageCanceled(str(exc)) from exc
    except ValueError as exc:
        raise StageError(str(exc)) from exc
    ctx.check_cancel()
    report = result.report
    comments = [
        f"cloud2cnc reconstruct (IGR, preset {report['preset']})",
        f"watertight {str(report['mesh']['watertight']).lower()}, normals {report['normals']['source']}",
    ]
    path = write_ply_mesh(ctx.output("mesh_raw.ply"), result.vertices, result.faces, comments=comments)
    ctx.progress(1.0, None)
    return {"mesh_raw.ply": path}
