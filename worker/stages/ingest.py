"""The `ingest` stage: read the upload, clean it, write `cloud.ply` or `mesh_raw.ply` and `ingest.json`."""

from __future__ import annotations

from pathlib import Path

from cam.ingest import clean_cloud, clean_mesh
from cam.io import ReadError, read_input, write_json, write_ply_mesh, write_ply_points
from worker.context import StageContext, StageError


def run_ingest(ctx: StageContext) -> dict[str, Path]:
    params = ctx.params.ingest
    ctx.progress(0.05, "reading")
    try:
        data = read_input(ctx.inputs["input"], max_points=ctx.settings["max_points"])
    except ReadError as exc:
        raise StageError(f"could not read the upload: {exc}") from exc
    if data.in_mm:  # the file stated its unit and the reader converted to mm (its notes say so)
        params = params.model_copy(update={"units": "mm"})
    ctx.check_cancel()
    ctx.progress(0.6, "cleaning")
    # IngestError (a GeometryError) propagates: its message is what the user sees.
    if data.faces is not None:
        clean = clean_mesh(data.points, data.faces, params, max_points=ctx.settings["max_points"],
                           format=data.format, notes=data.notes)
        out = {"mesh_raw.ply": write_ply_mesh(ctx.output("mesh_raw.ply"), clean.vertices, clean.faces)}
    else:
        clean = clean_cloud(data.points, data.normals, params, min_points=ctx.settings["min_points"],
                            max_points=ctx.settings["max_points"], format=data.format, notes=data.notes)
        out = {"cloud.ply": write_ply_points(ctx.output("cloud.ply"), clean.points, clean.normals)}
    out["ingest.json"] = write_json(ctx.output("ingest.json"), clean.report)
    ctx.progress(1.0, None)
    return out
