"""The `verify` stage: measure every program against the surfaces, independently of the planner."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cam.gcode import GCodeError, parse_program
from cam.io.atomic import atomic_write
from cam.plan.access import machine_patches
from cam.spline.geometry import Patch
from cam.plan.region import sub_surface
from cam.plan.scallop import flat_spacing
from cam.verify import heat_colors, measure_program
from worker.context import StageContext, StageError, write_json
from worker.stages.plan import load_setups, load_surfaces, outward_signs

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
    r = float(ctx.params["tool"]["radius_mm"])
    tp = ctx.params["toolpath"]
    target = float(tp["scallop_height_mm"])
    ids, surfaces = load_surfaces(ctx.inputs["surfaces.json"])
    doc, setups = load_setups(ctx.inputs["setup.json"])
    signs = outward_signs(ctx, surfaces, setups[0])
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
        machined = [p for p in part if p.id in set(entry["patches"])]
        # A patch the planner finishes only in part is held to its claims, on those rectangles alone.
        try:
            claims: dict[int, list] = {}
            for q in entry.get("partial") or []:
                claims.setdefault(int(q["patch"]), []).append(tuple(float(x) for x in q["region"]))
            machined = [q for p in machined for q in
                        ([Patch(p.id, sub_surface(p.surface, box), p.sign) for box in claims[p.id]]
                         if p.id in claims else [p])]
        except (KeyError, TypeError, ValueError) as exc:
            raise StageError(f"setup {setup.id} in setup.json has a 'partial' entry that is not a parameter "
                             f"rectangle inside its patch: {exc}") from exc
        ctx.progress(0.05 + 0.9 * k / len(setups), f"measuring {name}")
        m = measure_program(program, machined, part, tool_radius_mm=r, target_mm=target,
                            interval_mm=float(flat_spacing(target, r)),
                            samples_per_interval=tp["verify_samples_per_interval"],
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
