"""The `plan` stage: mesh.ply (+ surfaces.json and setup.json when the job has them) → programs per setup and
ball, toolpath.json, toolpath.csv and setup.json."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from cam.gcode import write_program
from cam.io import read_json, read_ply, read_setups, read_surfaces, write_json
from cam.io.atomic import atomic_write
from cam.plan import SurfacesIn, plan_job
from cam.plan.documents import (
    program_header,
    setup_document,
    toolpath_document,
    toolpath_rows,
)
from cam.spline.geometry import orientation_signs
from core.config import stage_processes
from worker.context import StageContext, StageError


def _surfaces(ctx: StageContext, mesh) -> SurfacesIn | None:
    """The fitted patches, when fit made them; only those within the fit tolerance get patch passes."""
    if "surfaces.json" not in ctx.inputs:
        return None
    ids, surfaces = ctx.read("surfaces.json", read_surfaces)
    if not surfaces:
        return None
    doc = ctx.read("surfaces.json", read_json)
    over = set(doc.get("over_tolerance") or []) | set(doc.get("folded") or [])
    signs = orientation_signs(surfaces, mesh_vertices=mesh.points, mesh_faces=mesh.faces)
    return SurfacesIn(ids=ids, surfaces=surfaces, signs=signs, good=np.array([i not in over for i in ids]))


def run_plan(ctx: StageContext) -> dict[str, Path]:
    tool, tp = ctx.params.tool, ctx.params.toolpath
    if "mesh.ply" not in ctx.inputs:
        raise StageError("this job has no mesh.ply to plan on (denoise made none)")
    mesh = ctx.read("mesh.ply", read_ply)
    if mesh.faces is None or not len(mesh.faces):
        raise StageError("mesh.ply has no triangles to plan on")
    base, given = ctx.read("setup.json", read_setups) if "setup.json" in ctx.inputs else ({}, [])
    plan = plan_job(mesh.points, mesh.faces, tool, tp, surfaces=_surfaces(ctx, mesh), given_setups=given,
                    processes=stage_processes(ctx.settings.get("stage_processes")),
                    progress=ctx.progress_between(0.0, 0.95), check_cancel=ctx.check_cancel)
    out: dict[str, Path] = {}
    for k, program in enumerate(plan.programs):
        number = tool.rest_tool_number if program.role == "rest" else tool.tool_number
        text = write_program(program.moves, dialect=tp.dialect,
                             header=program_header(plan, program, job_id=ctx.job_id, tool_number=number,
                                                   dialect=tp.dialect),
                             tool_number=number, spindle_rpm=tool.spindle_rpm, feed_mm_min=tool.feed_mm_min,
                             plunge_mm_min=tool.plunge_mm_min, program_number=k + 1)
        out[program.name] = atomic_write(ctx.output(program.name), [text.encode()])
    rows = io.StringIO()
    csv.writer(rows).writerows(toolpath_rows(plan))
    out["toolpath.json"] = write_json(ctx.output("toolpath.json"), toolpath_document(plan, tool, tp))
    out["toolpath.csv"] = atomic_write(ctx.output("toolpath.csv"), [rows.getvalue().encode()])
    out["setup.json"] = write_json(ctx.output("setup.json"), setup_document(plan, base))
    if not plan.programs:
        raise StageError(f"no surface of the part can be reached with a ball of radius {tool.radius_mm} mm from "
                         f"{len(plan.setups)} setup(s)", outputs=out)
    ctx.progress(1.0, None)
    return out
