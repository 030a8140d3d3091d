"""The `verify` stage: measure every program against the surfaces, independently of the planner."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cam.gcode import GCodeError, parse_program
from cam.io import ReadError, read_ply, read_setups, read_surfaces, write_json
from cam.io.atomic import atomic_write
from cam.spline.geometry import machine_patches, orientation_signs
from cam.verify import claimed_patches, heat_colors, measure_program
from worker.context import StageContext, StageError

GOUGE_LIMIT_MM = 1e-3


def write_heat_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray, scallop: np.ndarray) -> Path:
    """Binary little-endian PLY with per-vertex colour and a float `scallop` (mm; NaN unreachable)."""
    vertex = np.empty(len(vertices), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"),
                                            ("green", "u1"), ("blue", "u1"), ("scallop", "<f4")])
    vertex["x"], vertex["y"], vertex["z"] = vertices.T
    vertex["red"], vertex["green"], vertex["blue"] = colors.T
    vertex["scallop"] = np.where(np.isposinf(scallop), -1.0, scallop)
    face = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, faces
    head = ("ply\nformat binary_little_endian 1.0\ncomment scallop height in mm; NaN unreachable, -1 never reached\n"
            f"element vertex {len(vertex)}\nproperty float x\nproperty float y\nproperty float z\n"
            "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty float scallop\n"
            f"element face {len(face)}\nproperty list uchar int vertex_indices\nend_header\n")
    return atomic_write(path, [head.encode(), vertex.tobytes(), face.tobytes()])


def run_verify(ctx: StageContext) -> dict[str, Path]:
    r = float(ctx.params.tool.radius_mm)
    tp = ctx.params.toolpath
    target = float(tp.scallop_height_mm)
    ids, surfaces = ctx.read("surfaces.json", read_surfaces)
    doc, setups = ctx.read("setup.json", read_setups)
    if not surfaces or not setups:
        raise StageError("surfaces.json holds no surfaces or setup.json no setup: nothing to verify")
    mesh = ctx.read("mesh.ply", read_ply) if "mesh.ply" in ctx.inputs else None
    signs = orientation_signs(surfaces, mesh_vertices=None if mesh is None else mesh.points,
                              mesh_faces=None if mesh is None else mesh.faces,
                              up=setups[0].tool_axis_part)
    reports, verts, faces, values = [], [], [], []
    for k, (entry, setup) in enumerate(zip(doc["setups"], setups)):
        name = entry.get("program")
        if not name or not entry.get("patches"):
            continue
        if name not in ctx.inputs:
            raise StageError(f"setup {setup.id} names {name}, which this job does not have")
        try:
            program = parse_program(ctx.inputs[name].read_text())
        except (GCodeError, UnicodeDecodeError) as exc:
            raise StageError(f"{name} cannot be verified: {exc}") from exc
        certified = program.header_value("certified scallop bound")
        certified = float(certified.split()[0]) if certified else None
        part = machine_patches(ids, surfaces, signs, setup)
        try:
            machined = claimed_patches(entry, part)
        except ReadError as exc:
            raise StageError(str(exc)) from exc
        ctx.progress(0.05 + 0.9 * k / len(setups), f"measuring {name}")
        m = measure_program(program, machined, part, tool_radius_mm=r, target_mm=target,
                            samples_per_interval=tp.verify_samples_per_interval,
                            check_cancel=ctx.check_cancel)
        reports.append({"setup": setup.id, "program": name, "certified_scallop_mm": certified, **m.report})
        verts.append((m.vertices - setup.translation) @ setup.rotation)  # back to the part frame
        faces.append(m.faces + sum(len(v) for v in verts[:-1]))
        values.append(m.scallop)
    if not reports:
        raise StageError("no program to verify: setup.json lists no machined patch")
    top = lambda key: max((x[key] for x in reports if x[key] is not None), default=None)
    result = {
        "target_scallop_mm": target, "tool_radius_mm": r,
        "certified_scallop_mm": top("certified_scallop_mm"),
        "max_scallop_mm": top("max_scallop_mm"), "p99_scallop_mm": top("p99_scallop_mm"),
        "max_gouge_mm": top("max_gouge_mm"), "max_rapid_gouge_mm": top("max_rapid_gouge_mm"),
        "fraction_over_target": top("fraction_over_target"),
        "uncut_area_mm2": sum(x["uncut_area_mm2"] for x in reports),
        "time_s": sum(x["time_s"] for x in reports), "setups": reports,
    }
    problems = []
    for x in reports:
        bound = x["certified_scallop_mm"] if x["certified_scallop_mm"] is not None else target
        if x["max_scallop_mm"] is not None and x["max_scallop_mm"] > bound * (1 + 1e-6) + 1e-9:
            problems.append(f"{x['program']} leaves {x['max_scallop_mm']:.4f} mm of scallop, more than its certified "
                            f"bound {bound:.4f} mm (at {x['max_at']})")
        for key, what in (("max_gouge_mm", "cutting"), ("max_rapid_gouge_mm", "rapid")):
            if x[key] > GOUGE_LIMIT_MM:
                problems.append(f"{x['program']}: a {what} move cuts {x[key]:.4f} mm into the part")
    result["passed"] = not problems
    result["problems"] = problems
    out = {"verify.json": write_json(ctx.output("verify.json"), result)}
    v = np.concatenate(verts)
    s = np.concatenate(values)
    out["scallop.ply"] = write_heat_ply(ctx.output("scallop.ply"), v, np.concatenate(faces), heat_colors(s, target), s)
    if problems:
        raise StageError("; ".join(problems), outputs=out)
    ctx.progress(1.0, None)
    return out
