"""Tool-path benchmark: our adaptive rings vs the paper's Algorithm 1 (one global minimum interval per
direction, corner-shrunk steps) and vs an OpenCAMLib drop-cutter raster (bench/raster.py), all verified
independently from their G-code, at r = 3 mm and h = 0.16 and 0.02 mm.

Writes bench/results/toolpath.md and toolpath-*.png. Parts: the analytic surfaces; Fandisk ×10 and Block
×10 (when ../shared/data is there) as our own stages fit them from the clean meshes. The patch passes
alone: what the whole pipeline finishes of a part, against the part itself, is bench/part_coverage.py's.
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine_info import describe_machine  # bench/ is on the path when a script runs  # noqa: I001

from cam.params import ToolParams, ToolpathParams
from cam.gcode import parse_program, write_program
from cam.spline import analytic
from cam.gcode.setup import Setup
from cam.spline.geometry import Patch, orientation_signs
from cam.plan.patch_job import plan_patches
from cam.spline.geometry import area_share, machine_patches, surface_area
from cam.spline.knots import sub_surface
from cam.verify import measure_program
from raster import matched_raster

R = 3.0
PARTS = {
    "plane 20×16": [analytic.plane(20, 16)],
    "convex cylinder R20": [analytic.cylinder(20.0, 16.0, 60.0)],
    "concave cylinder R20": [analytic.cylinder(20.0, 16.0, 60.0, concave=True)],
    "saddle R40": [analytic.saddle(40.0, 16.0)],
    "dome R15": [analytic.paraboloid(15.0, 16.0)],
    "bowl R30": [analytic.paraboloid(30.0, 16.0, concave=True)],
    "V-groove (2 patches)": analytic.v_groove(),
}


def run_part(ids, surfaces, signs, setups, h, strategy, *, raster=False, raster_tries=3):
    """Plan with `strategy`, then verify every setup's program on exactly what it claims; with raster=True
    also the OpenCAMLib raster on the same claimed rectangles. Sums over setups."""
    t0 = time.perf_counter()
    plan = plan_patches(ids, surfaces, setups, ToolParams(radius_mm=R), ToolpathParams(scallop_height_mm=h, strategy=strategy), signs=signs)
    t_plan = time.perf_counter() - t0
    claims: dict[int, list] = {}  # a patch finished in part may be claimed on several rectangles
    for q in plan.partial:
        claims.setdefault(q["patch"], []).append(tuple(q["region"]))
    area = {i: surface_area(s) for i, s in zip(ids, surfaces)}
    row = {"certified": plan.certified_scallop_mm, "max": 0.0, "gouge": 0.0, "length": 0.0, "air": 0.0, "retracts": 0,
           "t_plan": t_plan, "t_verify": 0.0, "never": 0.0, "unreach": 0.0, "samples": 0, "covered": 0.0,
           "total_area": sum(area.values()), "machined": 0, "raster": None, "measure": [], "passes": []}
    rast = []
    for sp in plan.setups:
        part = machine_patches(ids, surfaces, signs, sp.setup)
        mine = {q.patch for q in sp.patches}
        machined = [q for p in part if p.id in mine for q in
                    ([Patch(p.id, sub_surface(p.surface, box), p.sign) for box in claims[p.id]] if p.id in claims
                     else [p])]
        if not machined:
            continue
        prog = parse_program(write_program(sp.moves, header={}))
        m = measure_program(prog, machined, part, tool_radius_mm=R, target_mm=h)
        rep, st = m.report, sp.moves.stats()
        row["max"] = max(row["max"], rep["max_scallop_mm"] or 0.0)
        row["gouge"] = max(row["gouge"], rep["max_gouge_mm"], rep["max_rapid_gouge_mm"])
        row["length"] += st["cut_length_mm"]
        row["air"] += st["air_length_mm"]
        row["retracts"] += st["retracts"]
        row["t_verify"] += rep["time_s"]
        row["never"] += rep["uncut_area_mm2"]
        row["machined"] += len(mine)
        row["covered"] += sum(area[i] * (sum(area_share(surfaces[ids.index(i)], box) for box in claims[i])
                                         if i in claims else 1.0) for i in mine)
        row["measure"].append((sp.setup, m))
        row["passes"].append((sp.setup, [q for pp in sp.patches for q in pp.passes]))
        if raster:
            top = max(float(np.max(q.surface.control_points[..., 2])) for q in part) + 5.0
            rast.append(matched_raster(machined, part, r=R, h=h, clearance_z=top, tries=raster_tries))
    if raster and rast:
        row["raster"] = {"length": sum(x["length"] for x in rast), "air": sum(x["air"] for x in rast),
                         "max": max(x["max"] for x in rast), "gouge": max(x["gouge"] for x in rast),
                         "stepover": min(x["stepover"] for x in rast), "met": all(x["met"] for x in rast),
                         "t_plan": sum(x["t_plan"] for x in rast), "retracts": sum(x["retracts"] for x in rast),
                         "uncut": sum(x["uncut"] for x in rast)}
    return row


def run(surfaces, h, strategy, *, raster=False):
    ids = list(range(1, len(surfaces) + 1))
    return run_part(ids, surfaces, np.ones(len(surfaces)), [Setup(1, np.eye(3), np.zeros(3))], h, strategy,
                    raster=raster)


DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CLOUD_POINTS = 50_000
# On the fitted parts one raster try at h = 0.16 takes minutes on 2 cores (this OpenCAMLib build tests every
# triangle near a line against every drop) and steep walls keep a raster over the target at any stepover
# tried: the parts section runs one try at the flat stepover, at h = 0.16 only; `parts-fine` (h = 0.02,
# three times the lines) runs ours and the paper's without it.
PART_RASTER_TRIES = 1


def fitted_part(name: str, tmp: Path):
    """Our stages from the clean mesh ×10 up to `fit`: (ids, surfaces, signs, setups, fit seconds) or None."""
    import trimesh

    from cam.io import read_input, read_setups, read_surfaces
    from core.config import Settings
    from worker.local import run_local

    src = DATA / f"{name}_gt.obj"
    if not src.exists():
        return None
    mesh = trimesh.load(src, process=False)
    mesh.apply_scale(10.0)
    path = tmp / f"{name}10.obj"
    mesh.export(path)
    out = tmp / name
    with open(os.devnull, "w") as quiet:
        reports = run_local(path, out, params={"tool": {"radius_mm": R}}, settings=Settings(), until="fit", stream=quiet)
    if reports[-1].status != "succeeded":
        raise RuntimeError(f"{name}: {reports[-1].name} failed: {reports[-1].error}")
    ids, surfaces = read_surfaces(out / "surfaces.json")
    _, setups = read_setups(out / "setup.json")
    m = read_input(out / "mesh.ply")
    signs = orientation_signs(surfaces, mesh_vertices=m.points, mesh_faces=m.faces)
    return ids, surfaces, signs, setups


def picture(name: str, row: dict, h: float) -> str:
    """Tool paths over the scallop heat map of the first setup, seen from the tool; returns the file name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    setup, m = row["measure"][0]
    _, passes = row["passes"][0]
    fig, axes = plt.subplots(1, 2, figsize=(13, 6))
    for ax in axes:
        ax.set_aspect("equal")
        ax.set_xlabel("x mm (machine frame)")
    ok = np.isfinite(m.scallop)
    axes[0].scatter(m.vertices[~ok, 0], m.vertices[~ok, 1], s=0.2, c="0.85")
    for q in passes:
        axes[0].plot(q[:, 0], q[:, 1], lw=0.4, c="tab:blue")
    axes[0].set_title(f"{name}: tool paths, setup {setup.id} (grey: claimed but not reachable)")
    sc = axes[1].scatter(m.vertices[ok, 0], m.vertices[ok, 1], c=m.scallop[ok], s=0.3, cmap="viridis", vmin=0, vmax=h)
    fig.colorbar(sc, ax=axes[1], label="scallop left, mm")
    axes[1].set_title(f"verified scallop, target {h} mm")
    file = f"toolpath-{name.split()[0].lower()}.png"
    fig.tight_layout()
    fig.savefig(Path(__file__).resolve().parent / "results" / file, dpi=110)
    plt.close(fig)
    return file


HEAD = ("| part | h mm | verified max / target (ours, paper, raster) | certified mm | covered | max gouge mm (ours, paper, "
        "raster) | path mm ours | paper | ours / paper | ours / paper per mm² covered | raster | ours / raster | raster stepover mm | air mm (ours, raster) "
        "| retracts (ours, raster) | reached (ours, raster) | plan s (ours, paper, raster) | verify s |")
COLUMNS = HEAD.count("|") - 1


def _ratio(x, y):
    return x / y if y else float("nan")


def line(name, h, a, p):
    rs = a["raster"]
    cov = _ratio(a["covered"], a["total_area"])
    rast = (f"{rs['max'] / h:.4f}{'' if rs['met'] else ' (not met)'}", f"{rs['gouge']:.1e}", f"{rs['length']:.0f}",
            f"{_ratio(a['length'], rs['length']):.3f}", f"{rs['stepover']:.3f}", f"{rs['air']:.0f}", f"{rs['retracts']}",
            f"{rs['t_plan']:.1f}") if rs else ("-",) * 8
    # A program that leaves more than it certifies is marked in the table, not only in the notes.
    over = lambda row: " (over its certificate)" if row["max"] > row["certified"] * (1 + 1e-6) else ""
    # The share of the claimed area each program's ball reaches at all (verify's samples never touched
    # count against it); older section files have no raster figure.
    reached = f"{1 - _ratio(a['never'], a['covered']):.1%}, " + (
        f"{1 - _ratio(rs['uncut'], a['covered']):.1%}" if rs and "uncut" in rs else "-")
    return (f"| {name} | {h} | {a['max'] / h:.4f}{over(a)}, {p['max'] / h:.4f}{over(p)}, {rast[0]} "
            f"| {a['certified']:.5f} | {cov:.1%} "
            f"| {a['gouge']:.1e}, {p['gouge']:.1e}, {rast[1]} | {a['length']:.0f} | {p['length']:.0f} "
            f"| {_ratio(a['length'], p['length']):.3f} "
            f"| {_ratio(_ratio(a['length'], a['covered']), _ratio(p['length'], p['covered'])):.3f} | {rast[2]} | {rast[3]} | {rast[4]} | {a['air']:.0f}, {rast[5]} "
            f"| {a['retracts']}, {rast[6]} | {reached} | {a['t_plan']:.1f}, {p['t_plan']:.1f}, {rast[7]} | {a['t_verify']:.1f} |")


def _numbers(row: dict) -> dict:
    """A result row without the measurement objects, for the section's JSON file."""
    return {k: v for k, v in row.items() if k not in ("measure", "passes")}


def section_analytic() -> dict:
    rows = []
    for h in (0.16, 0.02):
        for name, surfaces in PARTS.items():
            a, p = run(surfaces, h, "adaptive", raster=True), run(surfaces, h, "paper")
            rows.append((name, h, _numbers(a), _numbers(p)))
            print(f"{name:24s} h={h}: ours {a['length']:.0f} mm, paper {p['length']:.0f} mm, raster "
                  f"{a['raster']['length']:.0f} mm; max/target {a['max'] / h:.4f} / {p['max'] / h:.4f} / "
                  f"{a['raster']['max'] / h:.4f}", flush=True)
    return {"rows": rows, "machine": describe_machine()}


def section_parts(heights: tuple[float, ...] = (0.16,)) -> dict:
    parts, pictures = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("fandisk", "block"):
            t0 = time.perf_counter()
            fitted = fitted_part(name, Path(tmp))
            if fitted is None:
                parts.append((f"{name} ×10", None, None, None))
                continue
            print(f"{name}: fitted {len(fitted[0])} surfaces in {time.perf_counter() - t0:.0f} s", flush=True)
            for h in heights:
                a, p = (run_part(*fitted, h, "adaptive", raster=h == 0.16,
                                 raster_tries=PART_RASTER_TRIES),
                        run_part(*fitted, h, "paper"))
                parts.append((f"{name} ×10", h, _numbers(a), _numbers(p)))
                print(f"{name} h={h}: ours {a['length']:.0f} mm, paper {p['length']:.0f} mm, raster "
                      f"{(a['raster'] or {}).get('length', 0):.0f} mm; max/target {a['max'] / h:.4f}, covered "
                      f"{a['covered'] / a['total_area']:.1%}", flush=True)
                if h == 0.16 and a["measure"]:
                    pictures.append((name, picture(f"{name} ×10", a, h)))
    return {"rows": parts, "pictures": pictures, "machine": describe_machine()}


SECTIONS = {"analytic": section_analytic, "parts": section_parts, "parts-fine": lambda: section_parts((0.02,))}
RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    """`python bench/toolpath.py [analytic] [parts] [parts-fine]` runs those sections (all by default), keeps each
    section's numbers in results/toolpath-<section>.json and writes toolpath.md from every section on file."""
    for name in sys.argv[1:] or list(SECTIONS):
        if name not in SECTIONS:
            raise SystemExit(f"unknown section {name!r}; choose from {', '.join(SECTIONS)}")
        (RESULTS / f"toolpath-{name}.json").write_text(json.dumps(SECTIONS[name](), indent=1,
                                                                     default=lambda o: o.item() if hasattr(o, "item") else float(o)))
    done = {k: json.loads((RESULTS / f"toolpath-{k}.json").read_text()) for k in SECTIONS
            if (RESULTS / f"toolpath-{k}.json").exists()}
    write_report(done)


def _analytic_from_log(path: Path) -> list[str]:
    """The analytic section as its own progress lines recorded it (lengths and verified max / target of all
    three), for when that section's full numbers are not on file."""
    out = [f"From the progress lines of a run of `python bench/toolpath.py analytic` on this machine "
           f"(`{path.name}`); plan and verify times, air moves and gouge are in the full table, which that "
           "command regenerates.", "",
           "| part | h mm | path mm ours | paper | raster | ours / paper | ours / raster | verified max / target "
           "(ours, paper, raster) |", "|---|---|---|---|---|---|---|---|"]
    pattern = re.compile(r"^(.*?)\s+h=([\d.]+): ours (\d+) mm, paper (\d+) mm, raster (\d+) mm; "
                         r"max/target ([\d.]+) / ([\d.]+) / ([\d.]+)$")
    ours_paper, ours_raster = [], []
    for text in path.read_text().splitlines():
        m = pattern.match(text.strip())
        if m:
            name, h, o, p, r, mo, mp, mr = m.groups()
            o, p, r = float(o), float(p), float(r)
            ours_paper.append(o / p)
            ours_raster.append(o / r)
            out.append(f"| {name} | {h} | {o:.0f} | {p:.0f} | {r:.0f} | {o / p:.3f} | {o / r:.3f} | {mo}, {mp}, {mr} |")
    if ours_paper:
        out += ["", f"Path length ours / paper: median {np.median(ours_paper):.3f}, worst {max(ours_paper):.3f}. "
                f"Ours / raster: median {np.median(ours_raster):.3f}, worst {max(ours_raster):.3f}."]
    return out


def write_report(done: dict) -> None:
    rows = done.get("analytic", {}).get("rows", [])
    parts = done.get("parts", {}).get("rows", []) + done.get("parts-fine", {}).get("rows", [])
    pictures = done.get("parts", {}).get("pictures", [])
    machines = sorted({d["machine"] for d in done.values()})
    lines = ["# Tool-path benchmark", "", f"Ball radius r = {R} mm. Our planner (adaptive rings joined into one spiral: "
             "admissible step per ring side, corner excursions) against (a) the paper's Algorithm 1 (one global minimum interval per direction, "
             "Δs shrunk until the corners hold) and (b) an OpenCAMLib drop-cutter raster along x over the same claimed "
             "rectangles (its first and last lines half a step inside, like our first ring), whose stepover is "
             "searched (up to 3 tries) for a verified maximum at the target "
             "(`bench/raster.py`). All three are verified independently from their own G-code (LinuxCNC dialect) by "
             "`cam.verify`. Chord share 10 % of h (sag along the normal, and sideways deviation "
             "times tan φ), 4-decimal rounding budgeted. `covered`: the share of the surfaces' "
             "area the program claims to finish (rectangles the planner kept); the raster is measured on the same "
             "claims. Generated by `python bench/toolpath.py [analytic] [parts] [parts-fine]` (each section's numbers are kept in "
             "`toolpath-<section>.json`).", "", f"Machine: {'; '.join(machines)}.", "",
             "## Analytic surfaces", "", HEAD, "|---" * COLUMNS + "|"]
    lines += [line(name, h, a, p) for name, h, a, p in rows]
    if not rows and (RESULTS / "toolpath-analytic.log").exists():
        lines[-2:] = _analytic_from_log(RESULTS / "toolpath-analytic.log")
    if rows:
        ratios = [_ratio(a["length"], p["length"]) for _, _, a, p in rows]
        rratios = [_ratio(a["length"], a["raster"]["length"]) for _, _, a, p in rows if a["raster"]]
        lines += ["", f"Path length ours / paper: median {np.median(ratios):.3f}, worst {max(ratios):.3f}. "
                  f"Ours / raster: median {np.median(rratios):.3f}, worst {max(rratios):.3f}.", ""]
    lines += ["## Fandisk ×10 and Block ×10", "",
              "Surfaces from our own stages on the clean meshes ×10 (mesh upload: denoise, remesh, segment, fit; "
              "default parameters), planned over the setups `segment` chose. At h = 0.16 mm (section `parts`) and "
              "0.02 mm (`parts-fine`, when run); the raster at h = 0.16 mm only, at one try (the flat "
              "stepover). Our plan and the paper's may claim different rectangles of a patch (where one path has to "
              "lift the ball off the patch and the other does not, that rectangle shrinks), so the fair length "
              "comparison is path per mm² covered.", "", HEAD, "|---" * COLUMNS + "|"]
    for name, h, a, p in parts:
        lines.append(f"| {name} | not run: {DATA} is absent |" if a is None else line(name, h, a, p))
    lines.append("")
    for name, file in pictures:
        lines += [f"![{name}: tool paths and verified scallop]({file})", ""]
    lines.append("")
    out = RESULTS / "toolpath.md"
    # A hand-written "## Notes" section (analysis of a run) survives a rerun of the tables.
    notes = out.read_text().partition("\n## Notes")[2] if out.exists() else ""
    out.write_text("\n".join(lines) + "\n" + (f"\n## Notes{notes}" if notes else ""))
    print(out)


if __name__ == "__main__":
    main()
