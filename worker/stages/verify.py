"""The `verify` stage: measure every program on the part (mesh.ply), independently of the planner."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cam.gcode import GCodeError, parse_program
from cam.io import read_ply, read_setups, write_json
from cam.io.atomic import atomic_write
from cam.verify import heat_colors, pass_width_mm
from cam.verify.part import PartMeasurement, ProgramIn, measure_part, vertex_values
from cam.verify.report import ProgramStats, classify_faces, measure_moves, render_report
from worker.context import StageContext, StageError


def write_heat_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray, scallop: np.ndarray) -> Path:
    """Binary little-endian PLY with per-vertex colour and a float `scallop` (mm; NaN unreachable)."""
    vertex = np.empty(len(vertices), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"),
                                            ("green", "u1"), ("blue", "u1"), ("scallop", "<f4")])
    vertex["x"], vertex["y"], vertex["z"] = vertices.T
    vertex["red"], vertex["green"], vertex["blue"] = colors.T
    vertex["scallop"] = np.where(np.isposinf(scallop), -1.0, scallop)
    face = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, faces
    head = ("ply\nformat binary_little_endian 1.0\ncomment scallop height in mm left on the part (mesh.ply); "
            "NaN where the ball cannot reach, -1 where nothing cut\n"
            f"element vertex {len(vertex)}\nproperty float x\nproperty float y\nproperty float z\n"
            "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty float scallop\n"
            f"element face {len(face)}\nproperty list uchar int vertex_indices\nend_header\n")
    return atomic_write(path, [head.encode(), vertex.tobytes(), face.tobytes()])


def _programs(ctx: StageContext, doc: dict, setups: list) -> list[ProgramIn]:
    """Every program setup.json names, parsed; a program the job lacks or verify cannot read fails the stage."""
    tool = ctx.params.tool
    out = []
    for entry, setup in zip(doc.get("setups", []), setups):
        for key, role, radius in (("program", "main", tool.radius_mm), ("rest_program", "rest", tool.rest_radius_mm)):
            name = entry.get(key)
            if not name:
                continue
            if name not in ctx.inputs or radius is None:
                raise StageError(f"setup {setup.id} names {name}, which this job does not have")
            try:
                program = parse_program(ctx.inputs[name].read_text())
            except (GCodeError, UnicodeDecodeError) as exc:
                raise StageError(f"{name} cannot be verified: {exc}") from exc
            out.append(ProgramIn(setup=setup, program=program, tool_radius_mm=float(radius), role=role, name=name))
    return out


def _problems(report: dict, tp) -> list[str]:
    problems = []
    if report["finished_share_of_reachable"] < tp.min_finished_share:
        problems.append(f"the programs finish {report['finished_share_of_reachable']:.1%} of what the ball can reach, "
                        f"below toolpath.min_finished_share = {tp.min_finished_share:.1%}")
    for p in report["programs"]:
        if p["max_gouge_mm"] > tp.gouge_tolerance_mm:
            problems.append(f"{p['program']}: a cutting move cuts {p['max_gouge_mm']:.4f} mm into the part "
                            f"(toolpath.gouge_tolerance_mm = {tp.gouge_tolerance_mm})")
        if p["max_rapid_gouge_mm"] > tp.gouge_tolerance_mm:
            problems.append(f"{p['program']}: a rapid move cuts {p['max_rapid_gouge_mm']:.4f} mm into the part")
        elif p["rapid_margin_violation_mm"] > tp.gouge_tolerance_mm:
            problems.append(f"{p['program']}: a rapid move comes {p['rapid_margin_violation_mm']:.4f} mm inside the "
                            f"rapid margin of {tp.rapid_margin_mm} mm")
    return problems


def write_report(ctx: StageContext, mesh, doc: dict, setups: list, programs: list[ProgramIn],
                 m: PartMeasurement, result: dict) -> Path:
    """report.html: the setup sheet, from this measurement (coverage per face from its samples)."""
    stats = []
    for item in programs:
        cutting, rapid, cutting_min, rapid_min = measure_moves(item.program)
        stats.append(ProgramStats(name=item.name, setup=item.setup.id, role=item.role,
                                  tool_radius_mm=item.tool_radius_mm, cutting_mm=cutting, rapid_mm=rapid,
                                  cutting_min=cutting_min, rapid_min=rapid_min, moves=len(item.program.rapid)))
    classes = classify_faces(m.samples.face, m.left, m.reach, len(mesh.faces),
                             target_mm=ctx.params.toolpath.scallop_height_mm)
    html = render_report(title=f"job {ctx.job_id}", verify=result, setup_doc=doc, setups=setups, programs=stats,
                         vertices=mesh.points, faces=mesh.faces, face_class=classes,
                         tool=ctx.params.tool.model_dump(mode="json"),
                         toolpath=ctx.params.toolpath.model_dump(mode="json"))
    return atomic_write(ctx.output("report.html"), [html.encode()])


def run_verify(ctx: StageContext) -> dict[str, Path]:
    tool, tp = ctx.params.tool, ctx.params.toolpath
    if "mesh.ply" not in ctx.inputs:
        raise StageError("this job has no mesh.ply to measure the programs on")
    mesh = ctx.read("mesh.ply", read_ply)
    doc, setups = ctx.read("setup.json", read_setups)
    programs = _programs(ctx, doc, setups)
    if not programs:
        raise StageError("setup.json names no program to verify")
    width = pass_width_mm(tool.radius_mm, tp.scallop_height_mm)
    ctx.progress(0.05, "measuring the programs on the part")
    m = measure_part(mesh.points, mesh.faces, programs, setups, tool_radius_mm=tool.radius_mm,
                     rest_radius_mm=tool.rest_radius_mm, target_mm=tp.scallop_height_mm,
                     spacing_mm=2.0 * width / tp.verify_samples_per_interval, rapid_margin_mm=tp.rapid_margin_mm,
                     check_cancel=ctx.check_cancel)
    problems = _problems(m.report, tp)
    result = {**m.report, "min_finished_share": tp.min_finished_share, "gouge_tolerance_mm": tp.gouge_tolerance_mm,
              "passed": not problems, "problems": problems}
    out = {"verify.json": write_json(ctx.output("verify.json"), result)}
    values = vertex_values(m, len(mesh.points), mesh.faces)
    out["scallop.ply"] = write_heat_ply(ctx.output("scallop.ply"), mesh.points, mesh.faces,
                                        heat_colors(values, tp.scallop_height_mm), values)
    out["report.html"] = write_report(ctx, mesh, doc, setups, programs, m, result)
    if problems:
        raise StageError("; ".join(problems), outputs=out)
    ctx.progress(1.0, m.report["summary"])
    return out
