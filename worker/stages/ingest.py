"""The `ingest` stage: read the upload, clean it, write `cloud.ply` or `mesh_raw.ply` and `ingest.json`."""

from __future__ import annotations

from pathlib import Path

from cam.ingest.clean import clean_cloud, clean_mesh
from cam.io import ReadError, read_input, write_ply_mesh, write_ply_points
from worker.context import StageContext, StageError, write_json

MM_PER_UNIT = {"mm": 1.0, "inch": 25.4}


def run_ingest(ctx: StageContext) -> dict[str, Path]:
    units = ctx.params["ingest"]["units"]
    scale = MM_PER_UNIT[units]
    ctx.progress(0.05, "reading")
    try:
        data = read_input(ctx.inputs["input"])
    except ReadError as exc:
        raise StageError(f"could not read the upload: {exc}") from exc
    ctx.check_cancel()
    ctx.progress(0.6, "cleaning")
    try:
        if data.faces is not None:
            clean = clean_mesh(data.points, data.faces, scale_to_mm=scale, max_points=ctx.settings["max_points"],
                               format=data.format, units=units, notes=data.notes)
            out = {"mesh_raw.ply": write_ply_mesh(ctx.output("mesh_raw.ply"), clean.vertices, clean.faces)}
        else:
            clean = clean_cloud(data.points, data.normals, scale_to_mm=scale, min_points=ctx.settings["min_points"],
                                max_points=ctx.settings["max_points"], format=data.format, units=units,
                                notes=data.notes)
            out = {"cloud.ply": write_ply_points(ctx.output("cloud.ply"), clean.points, clean.normals)}
    except ValueError as exc:
        raise StageError(str(exc)) from exc
    out["ingest.json"] = write_json(ctx.output("ingest.json"), clean.report)
    ctx.progress(1.0, None)
    return out
