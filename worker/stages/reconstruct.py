"""The `reconstruct` stage: `cloud.ply` -> IGR -> `mesh_raw.ply` (a watertight triangle mesh, mm)."""

from __future__ import annotations

from pathlib import Path

from cam.io import read_ply, write_ply_mesh
from cam.reconstruct import reconstruct_surface
from core.config import stage_processes
from worker.context import StageContext, StageError, StageSkipped


def run_reconstruct(ctx: StageContext) -> dict[str, Path]:
    if "cloud.ply" not in ctx.inputs:
        raise StageSkipped("the upload is a mesh: it is passed on as mesh_raw.ply without reconstruction")
    ctx.progress(0.0, "reading the cloud")
    cloud = ctx.read("cloud.ply", read_ply)
    if cloud.faces is not None:
        raise StageError("cloud.ply holds a mesh, not a point cloud; mesh uploads skip reconstruct")
    threads = ctx.settings.get("blas_threads") or 1
    # Torch keeps the BLAS thread count (its sums would split along more threads); the k-NN queries,
    # each answered alike by any thread, use the stage's processors.
    workers = stage_processes(ctx.settings.get("stage_processes"))
    # The core reports its own fractions of the stage (training 0.05..0.9, extraction after);
    # a GeometryError (too few points, a flat cloud, a mesh that strays from its cloud, ...) reaches
    # the user as it is: a wrong part must not go on to be machined.
    result = reconstruct_surface(cloud.points, cloud.normals, ctx.params.reconstruct, threads=int(threads),
                                 workers=workers, progress=ctx.progress, check_cancel=ctx.check_cancel)
    ctx.check_cancel()
    report = result.report
    comments = [
        f"cloud2cnc reconstruct (IGR, preset {report['preset']})",
        f"watertight {str(report['mesh']['watertight']).lower()}, {_normals_comment(report['normals'])}",
        _fidelity_comment(report["fidelity"]),
    ]
    path = write_ply_mesh(ctx.output("mesh_raw.ply"), result.vertices, result.faces, comments=comments)
    ctx.progress(1.0, None)
    return {"mesh_raw.ply": path}


def _normals_comment(normals: dict) -> str:
    """Where the normals came from and, for estimated ones, how their side was told, for the PLY header."""
    if normals["source"] != "estimated":
        return f"normals {normals['source']}"
    if normals["orientation"] == "outside":
        how = f"turned outward by the space around the cloud ({normals['outside_voted_share']:.0%} of points voted)"
    else:
        how = "turned outward along the surface (the space around the cloud could not tell)"
    return f"normals estimated (k {normals['k']}), {how}"


def _fidelity_comment(fid: dict) -> str:
    """The self-check's measurement, for the PLY header (the stage writes no JSON report)."""
    bridged = ""
    if fid.get("bridged_vertices"):
        near = ", ".join(f"{c:.1f}" for c in fid["bridged_at"])
        bridged = (f"; {fid['bridged_vertices']} vertices bridge a gap in the scan, up to "
                   f"{fid['bridge_distance']:.3g} mm from it near ({near}): surface guessed, not scanned")
    return (f"fidelity: every vertex within {fid['mesh_to_cloud']:.3g} mm of the cloud, the cloud within "
            f"{fid['cloud_to_mesh']:.3g} mm of the surface ({fid['outliers']} isolated outliers apart), "
            f"allowed {fid['tolerance']:.3g} mm = {fid['rule']}{bridged}")
