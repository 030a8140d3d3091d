"""The `plan` stage: surfaces.json + setup.json (+ mesh.ply for orientation) → toolpath.json, programs, CSV, setup.json."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from cam.gcode import GENERATOR, write_program
from cam.io import read_ply, read_setups, read_surfaces, write_json
from cam.io.atomic import atomic_write
from cam.plan import Plan, plan_job
from cam.spline.geometry import orientation_signs
from worker.context import StageContext, StageError


def _r(x, d=5):
    return np.round(np.asarray(x, dtype=np.float64), d).tolist()


def header(ctx: StageContext, plan: Plan, setup_id: int, patches: list[int], dialect: str) -> dict[str, str]:
    tool = ctx.params.tool
    return {
        "cloud2cnc finishing program": f"job {ctx.job_id}, setup {setup_id}, patches {' '.join(map(str, patches))}",
        "tool": f"ball end mill radius {plan.tool_radius_mm:.4f} mm, T{tool.tool_number}",
        "target scallop": f"{plan.scallop_height_mm:.4f} mm",
        "certified scallop bound": f"{plan.certified_scallop_mm:.6f} mm",
        "budget split": f"scallop {plan.scallop_share_mm:.4f} mm + chord {plan.chord_tolerance_mm:.4f} mm",
        "chord tolerance": f"{plan.chord_tolerance_mm:.4f} mm",
        "units": "mm, absolute, tool tip in the machine frame (ball centre = tip + r Z)",
        "dialect": dialect,
        "generator": GENERATOR,
    }


def run_plan(ctx: StageContext) -> dict[str, Path]:
    tool, tp = ctx.params.tool, ctx.params.toolpath
    ids, surfaces = ctx.read("surfaces.json", read_surfaces)
    if not surfaces:
        raise StageError("surfaces.json holds no surfaces: nothing to machine")
    setup_doc, setups = ctx.read("setup.json", read_setups)
    if not setups:
        raise StageError("setup.json holds no setup")
    mesh = ctx.read("mesh.ply", read_ply) if "mesh.ply" in ctx.inputs else None
    signs = orientation_signs(surfaces, mesh_vertices=None if mesh is None else mesh.points,
                              mesh_faces=None if mesh is None else mesh.faces, up=setups[0].tool_axis_part)
    plan = plan_job(ids, surfaces, setups, tool, tp, signs=signs, progress=ctx.progress,
                    check_cancel=ctx.check_cancel)
    dialect = tp.dialect
    out: dict[str, Path] = {}
    rows = io.StringIO()
    writer = csv.writer(rows)
    writer.writerow(["setup", "patch", "pass", "x", "y", "z"])
    setups_json, unmachined = [], list(plan.unmachined)
    for k, sp in enumerate(plan.setups):
        patch_ids = list(dict.fromkeys(pp.patch for pp in sp.patches))  # a patch on several rectangles once
        text = write_program(sp.moves, dialect=dialect, header=header(ctx, plan, sp.setup.id, patch_ids, dialect),
                             tool_number=tool.tool_number, spindle_rpm=tool.spindle_rpm,
                             feed_mm_min=tool.feed_mm_min, plunge_mm_min=tool.plunge_mm_min,
                             program_number=k + 1)
        out[sp.program] = atomic_write(ctx.output(sp.program), [text.encode()])
        for pp in sp.patches:
            for j, tips in enumerate(pp.passes):
                for x, y, z in tips:
                    writer.writerow([sp.setup.id, pp.patch, j, f"{x:.4f}", f"{y:.4f}", f"{z:.4f}"])
        setups_json.append({"id": sp.setup.id, "rotation": sp.setup.rotation.tolist(),
                            "translation": sp.setup.translation.tolist(), "program": sp.program,
                            "patches": patch_ids, "unmachined": unmachined if k == 0 else [],
                            # Patches finished only on a parameter rectangle (u0, u1, v0, v1): the claim
                            # verify holds the program to; the rest is left, with the reason.
                            "partial": [q for q in plan.partial if q["patch"] in patch_ids]})
    toolpath = {
        "tool": {"shape": "ball", "radius_mm": plan.tool_radius_mm, "number": tool.tool_number},
        "scallop_height_mm": plan.scallop_height_mm, "scallop_share_mm": plan.scallop_share_mm,
        "chord_tolerance_mm": plan.chord_tolerance_mm, "strategy": plan.strategy,
        "certified_scallop_mm": plan.certified_scallop_mm, "unmachined": unmachined, "partial": plan.partial,
        "setups": [{
            "id": sp.setup.id, "program": sp.program, "stats": sp.moves.stats(),
            "patches": [{
                "patch": pp.patch, "passes": [_r(t, 4) for t in pp.passes], "region": list(pp.region),
                "certified_scallop_mm": pp.certified_scallop_mm,
                "bound": {"relation": "exact circle intersection in the normal section",
                          "side_gaps_mm": pp.side_scallop_mm, "corner_pockets_mm": pp.corner_scallop_mm,
                          "chord_mm": pp.chord_error_mm, "lift_mm": pp.lift_mm},
                "spacing_mm": {"min": pp.spacing_mm[0], "max": pp.spacing_mm[1]},
                "path_length_mm": pp.path_length_mm, "rings": pp.rings, "corner_excursions": pp.excursions,
                "reach_fraction": pp.reach_fraction, "replans": pp.replans,
                "excluded_points": pp.excluded_points, "time_s": pp.time_s,
            } for pp in sp.patches],
        } for sp in plan.setups],
    }
    out["toolpath.json"] = write_json(ctx.output("toolpath.json"), toolpath)
    out["toolpath.csv"] = atomic_write(ctx.output("toolpath.csv"), [rows.getvalue().encode()])
    out["setup.json"] = write_json(ctx.output("setup.json"), {**setup_doc, "setups": setups_json,
                                                              "unmachined": unmachined})
    if not any(sp.patches for sp in plan.setups):
        reasons = "; ".join(f"patch {u['patch']}: {u['reason']}" for u in unmachined) or "no patch reachable"
        raise StageError(f"no patch can be machined with this tool and setup ({reasons})", outputs=out)
    if plan.certified_scallop_mm > plan.scallop_height_mm * (1 + 1e-9):
        raise StageError(f"the planner could only certify {plan.certified_scallop_mm:.4f} mm, above the target "
                         f"{plan.scallop_height_mm:.4f} mm", outputs=out)
    ctx.progress(1.0, None)
    return out
