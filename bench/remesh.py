"""The remesh on a corpus of closed parts: does it give a layout, and does the layout follow the creases?

Issue 35 asks for a quad layout on every closed part with crease recall 1.0 and no quad straddling a crease.
This bench runs both layouts of `cam.remesh.remesh_quads` on each part of a corpus of closed parts, in the same
run: QuadriFlow's (`remesh.layout = "quadriflow"`, the default `RemeshParams` otherwise: 3,000 quads, up to 3
attempts and 3 candidates, 300 s per run) and the crease-first layout (`remesh.layout = "creases"`,
`cam.remesh.layout`), and segments each layout with the default `SegmentParams` to count its patches:

- Fandisk and Block (`../shared/data/*_gt.obj`) ×10, as the other benches take them (mm);
- the seven ABC parts of `../shared/data/abc/`, each scaled to a 60 mm bounding-box diagonal (one of them,
  abc1, is not a closed manifold: the bench refuses it with the reason, before any remesh);
- CSG parts made with manifold3d: `bench/part_coverage.py`'s L-bracket and pockets block, the issue's test
  shapes of `tests/csgparts.py` (a box with a filleted pocket, a chamfered cylinder, a part with a gentle 40°
  ridge) and the shapes below (a thin-walled tray, steps, holes, a slot, ...).

Per part and layout: success or why it failed (for the crease-first layout: whether it fell back to
QuadriFlow), crease recall (the share of crease length, creases over `segment.sharp_angle_deg` = 50°, that quad
edges follow within 0.2 % of the bounding-box diagonal), quads straddling a crease, irregular vertices
(interior, valence ≠ 4), the two-sided Hausdorff distance over the diagonal, segment's patches, and the time
of `remesh_quads`. The measures are `cam.remesh.creases.measure_crease_conformity`'s. Parts are marked as the
tuning set or held out, about half each: a new remesh may be tuned on the first and is judged on the second.

    python bench/remesh.py [--parts fandisk,bracket,...] [--data ../shared/data] [--out bench/results]
                           [--pictures bracket,fandisk]

Writes ``remesh.md`` (table, machine, notes), ``remesh.json`` and, for the parts named in --pictures,
``remesh-<part>.png`` (both layouts side by side) into the output folder. Parts whose data is absent are skipped
and listed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from machine_info import describe_machine  # bench/ is on the path when a script runs
from part_coverage import bracket, pockets

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.csgparts import box_pocket_fillet, cylinder_chamfer, ridge40, solid_mesh

ABC_DIAGONAL_MM = 60.0
GENTLE_ANGLE_DEG = 35.0

Mesh = tuple[np.ndarray, np.ndarray]


def _prism(outline: list[tuple[float, float]], length: float):
    """The polygon ``outline`` (x, z, mm, counter-clockwise) extruded ``length`` mm along +y."""
    from manifold3d import CrossSection, Manifold

    return Manifold.extrude(CrossSection([outline]), length).rotate([90.0, 0.0, 0.0]).translate([0.0, length, 0.0])


def thin_walls() -> Mesh:
    """A tray 50 × 40 × 25 with 1.5 mm walls and floor, open at the top."""
    from manifold3d import Manifold

    return solid_mesh(Manifold.cube([50.0, 40.0, 25.0]) - Manifold.cube([47.0, 37.0, 30.0]).translate([1.5, 1.5, 1.5]))


def stepped_block() -> Mesh:
    """Three steps, 60 × 30 mm, 10, 20 and 30 mm high."""
    from manifold3d import Manifold

    return solid_mesh(Manifold.cube([60.0, 30.0, 10.0]) + Manifold.cube([40.0, 30.0, 20.0])
                       + Manifold.cube([20.0, 30.0, 30.0]))


def plate_holes() -> Mesh:
    """A 60 × 40 × 6 plate with four 8 mm through holes."""
    from manifold3d import Manifold

    plate = Manifold.cube([60.0, 40.0, 6.0])
    for x in (12.0, 48.0):
        for y in (10.0, 30.0):
            plate -= Manifold.cylinder(10.0, 4.0, circular_segments=64).translate([x, y, -2.0])
    return solid_mesh(plate)


def slot_block() -> Mesh:
    """A 50 × 30 × 20 block with a 10 mm wide, 10 mm deep slot through its length."""
    from manifold3d import Manifold

    return solid_mesh(Manifold.cube([50.0, 30.0, 20.0]) - Manifold.cube([60.0, 10.0, 20.0]).translate([-5.0, 10.0, 10.0]))


def hex_countersink() -> Mesh:
    """A hexagonal prism (25 mm across corners, 15 mm tall) with a 6 mm hole countersunk at 90° to 14 mm."""
    from manifold3d import Manifold

    hexagon = Manifold.cylinder(15.0, 25.0, circular_segments=6)
    hole = Manifold.cylinder(20.0, 3.0, circular_segments=64).translate([0.0, 0.0, -2.0])
    # The cone runs on past the top face, so the boolean cuts the face cleanly (no coplanar faces).
    sink = Manifold.cylinder(5.0, 3.0, 8.0, circular_segments=64).translate([0.0, 0.0, 11.0])
    return solid_mesh(hexagon - hole - sink)


def ramp45() -> Mesh:
    """A 50 × 30 block, 10 mm high at one end and 25 mm at the other, over a 45° ramp: two 45° creases, gentler
    than segment's 50°."""
    return solid_mesh(_prism([(0.0, 0.0), (50.0, 0.0), (50.0, 25.0), (25.0, 25.0), (10.0, 10.0), (0.0, 10.0)], 30.0))


def dome_block() -> Mesh:
    """A 50 × 50 × 15 block with a spherical cap of 40 mm radius, 8 mm high, on top."""
    from manifold3d import Manifold

    cap = (Manifold.sphere(40.0, 96).translate([25.0, 25.0, 15.0 + 8.0 - 40.0])
           ^ Manifold.cube([50.0, 50.0, 20.0]).translate([0.0, 0.0, 15.0]))
    return solid_mesh(Manifold.cube([50.0, 50.0, 15.0]) + cap)


def cross_boss() -> Mesh:
    """A 60 × 60 × 8 plate with a plus-shaped boss (two 40 × 10 bars, 12 mm high) on it."""
    from manifold3d import Manifold

    return solid_mesh(Manifold.cube([60.0, 60.0, 8.0]) + Manifold.cube([40.0, 10.0, 12.0]).translate([10.0, 25.0, 8.0])
                       + Manifold.cube([10.0, 40.0, 12.0]).translate([25.0, 10.0, 8.0]))


def washer() -> Mesh:
    """A ring of 20 / 10 mm radii, 8 mm thick, its outer top edge chamfered 1.5 mm."""
    from manifold3d import Manifold

    outer = (Manifold.cylinder(6.5, 20.0, circular_segments=96)
             + Manifold.cylinder(1.5, 20.0, 18.5, circular_segments=96).translate([0.0, 0.0, 6.5]))
    return solid_mesh(outer - Manifold.cylinder(12.0, 10.0, circular_segments=96).translate([0.0, 0.0, -2.0]))


def _shared(name: str) -> Callable[[Path], Mesh | None]:
    def load(data: Path) -> Mesh | None:
        from cam.io import read_obj

        path = data / f"{name}_gt.obj"
        if not path.exists():
            return None
        mesh = read_obj(path)
        return mesh.points * 10.0, mesh.faces.astype(np.int64)
    return load


def abc_part(name: str, data: Path) -> Mesh | None:
    """ABC part `name` read as an upload is (STL corners merged into vertices), moved to the origin and scaled
    to an ABC_DIAGONAL_MM bounding-box diagonal; None when its file is absent."""
    from cam.io import read_input

    path = data / "abc" / f"{name}.stl"
    if not path.exists():
        return None
    mesh = read_input(path)
    v = mesh.points - mesh.points.min(axis=0)
    return v * (ABC_DIAGONAL_MM / np.linalg.norm(np.ptp(v, axis=0))), mesh.faces.astype(np.int64)


def _abc(name: str) -> Callable[[Path], Mesh | None]:
    return lambda data: abc_part(name, data)


def _made(make: Callable[[], Mesh]) -> Callable[[Path], Mesh | None]:
    return lambda data: make()


# name: (loader, held out). The four test shapes (bracket, filleted pocket, chamfered cylinder, 40° ridge)
# and Fandisk are in the tuning set; Block and every part not named in the tests are held out.
PARTS: dict[str, tuple[Callable[[Path], Mesh | None], bool]] = {
    "fandisk": (_shared("fandisk"), False),
    "block": (_shared("block"), True),
    "abc1": (_abc("abc1"), True),
    "abc3": (_abc("abc3"), False),
    "abc4": (_abc("abc4"), True),
    "abc5": (_abc("abc5"), False),
    "abc7": (_abc("abc7"), True),
    "abc8": (_abc("abc8"), False),
    "abc9": (_abc("abc9"), True),
    "bracket": (_made(bracket), False),
    "pockets": (_made(pockets), False),
    "box_pocket_fillet": (_made(box_pocket_fillet), False),
    "cylinder_chamfer": (_made(cylinder_chamfer), False),
    "ridge40": (_made(ridge40), False),
    "thin_walls": (_made(thin_walls), False),
    "stepped_block": (_made(stepped_block), False),
    "plate_holes": (_made(plate_holes), True),
    "slot_block": (_made(slot_block), True),
    "hex_countersink": (_made(hex_countersink), True),
    "ramp45": (_made(ramp45), True),
    "dome_block": (_made(dome_block), True),
    "cross_boss": (_made(cross_boss), True),
    "washer": (_made(washer), True),
}


def closed_manifold_problem(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """Why a triangle mesh is not a closed, consistently oriented manifold, or None when it is one."""
    directed = np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    _, uses = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    _, same_way = np.unique(directed, axis=0, return_counts=True)
    problems = []
    if (uses == 1).any():
        problems.append(f"{int((uses == 1).sum())} boundary edges")
    if (uses > 2).any():
        problems.append(f"{int((uses > 2).sum())} edges shared by more than two triangles")
    if (same_way > 1).any():
        problems.append(f"{int((same_way > 1).sum())} edges run the same way in two triangles (flipped faces)")
    if not problems:
        return None
    import trimesh

    pieces = len(trimesh.Trimesh(vertices, faces, process=False).split(only_watertight=False))
    return f"not a closed manifold: {', '.join(problems)} ({pieces} separate pieces)"


def short_reason(message: str) -> str:
    """The distinct reasons of a RemeshFailed message, without seeds and face counts, for the table."""
    head, _, rest = message.partition(": ")
    attempts = rest.rsplit(". Try another", 1)[0].split("; seed ")
    reasons = []
    for attempt in attempts:
        reason = attempt.split(" faces: ", 1)[-1]
        for part in reason.split("; "):
            part = part.split(": ")[0] if part.startswith("QuadriFlow") and ": " in part else part
            part = part.split(": boundary loops")[0]  # the loops' lengths stay in remesh.json's message
            if part not in reasons:
                reasons.append(part)
    return f"{head.replace('QuadriFlow gave no usable quad mesh in ', '')}: " + "; ".join(reasons)


LAYOUTS = ("quadriflow", "creases")


def bench_layout(vertices: np.ndarray, faces: np.ndarray, layout: str) -> dict:
    """One layout of one part (mm): the report's measures and segment's patches, or why it failed."""
    from cam import GeometryError
    from cam.params import RemeshParams, SegmentParams
    from cam.remesh import remesh_quads
    from cam.segment import segment_quads

    started = time.perf_counter()
    try:
        result = remesh_quads(vertices, faces, RemeshParams(layout=layout))
    except GeometryError as exc:
        return {"ok": False, "reason": short_reason(str(exc)), "message": str(exc),
                "seconds": time.perf_counter() - started}
    seconds = time.perf_counter() - started
    report = result.report
    try:
        segmentation = segment_quads(result.vertices, result.faces, SegmentParams())
        patches, invalid = len(segmentation.patches), len(segmentation.invalid)
    except GeometryError as exc:
        patches, invalid = None, str(exc)
    return {"ok": True, "seconds": seconds, "made_by": report["layout"], "fallback": report.get("layout_fallback"),
            "quads": len(result.faces), "crease_recall": report["crease_recall"],
            "crease_length_mm": report["crease_recall_length_mm"], "straddling_quads": report["straddling_quads"],
            "irregular_vertices": report["check"]["extraordinary_vertices"],
            "hausdorff_ratio": report["hausdorff_ratio"], "patches": patches, "invalid_patches": invalid,
            "coarse": {k: v for k, v in report.items() if k.startswith("coarse_") or k in (
                "crease_chains", "spurs_dropped", "thin_dropped", "regions")},
            "failed_attempts": report.get("failed_attempts", []), "layout": result}


def bench_part(name: str, mesh: Mesh) -> dict:
    """Both layouts on one part (mm), or why the part is refused."""
    vertices, faces = mesh
    diagonal = float(np.linalg.norm(np.ptp(vertices[np.unique(faces)], axis=0)))
    row = {"part": name, "held_out": PARTS[name][1], "triangles": len(faces), "diagonal_mm": diagonal}
    problem = closed_manifold_problem(vertices, faces)
    if problem is not None:
        return {**row, "refused": problem}
    return {**row, **{layout: bench_layout(vertices, faces, layout) for layout in LAYOUTS}}


def _fmt(value, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def _cells(r: dict) -> list[str]:
    """The table cells of one layout of one part."""
    if not r["ok"]:
        return [f"failed: {r['reason']}", "—", "—", "—", "—", "—", "—", f"{r['seconds']:.0f}"]
    made = "ok" if r["fallback"] is None else "QuadriFlow (fell back)"
    patches = "—" if r["patches"] is None else f"{r['patches']}" + (f" ({r['invalid_patches']} invalid)"
                                                                   if r["invalid_patches"] else "")
    return [made, f"{r['quads']}", f"{_fmt(r['crease_recall'], '.3f')}", f"{r['straddling_quads']}",
            f"{r['irregular_vertices']}", f"{r['hausdorff_ratio']:.2%}", patches, f"{r['seconds']:.1f}"]


def write_table(rows: list[dict], absent: list[str], out: Path, machine: str) -> None:
    """``remesh.md``: the table and the summary line (the Notes under it are written by hand after a run)."""
    lines = [
        "# remesh: QuadriFlow's layout and the crease-first layout on a corpus of closed parts (issue 35)",
        "",
        "`python bench/remesh.py` — `cam.remesh.remesh_quads` with the default `RemeshParams` (3,000 quads) and",
        "`layout` `quadriflow` (QF: up to 3 attempts and 3 candidates, 300 s per run, the candidate following the",
        "most crease length kept) or `creases` (CF: `cam.remesh.layout`, coarse edges 8 quads long), one after the",
        "other on each part as a clean triangle mesh, in one run. Recall: the share of crease length (dihedral over",
        "50°, `segment.sharp_angle_deg`) that quad edges within 30° of its direction follow within 0.2 % of the",
        "bounding-box diagonal. Straddling: quads with no crease-bounded region holding all four corners (corners",
        "within the tolerance of a crease count on both sides). Irregular: interior vertices of valence ≠ 4.",
        "Hausdorff: two-sided, over the diagonal. Patches: `segment_quads` with the default `SegmentParams` on the",
        "layout. Fandisk and Block ×10; ABC parts scaled to a 60 mm bounding-box diagonal. Set: `tune` = tuning set,",
        "`held` = held out.",
        "",
        f"Machine: {machine}.",
        "",
        ("| part | set | triangles | QF | quads | recall | straddling | irregular | Hausdorff | patches | s "
         "| CF | quads | recall | straddling | irregular | Hausdorff | patches | s |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        held = "held" if r["held_out"] else "tune"
        if "refused" in r:
            lines.append(f"| {r['part']} | {held} | {r['triangles']} | refused: {r['refused']} |"
                         + " — |" * 15)
            continue
        lines.append(f"| {r['part']} | {held} | {r['triangles']} | " + " | ".join(_cells(r["quadriflow"])) + " | "
                     + " | ".join(_cells(r["creases"])) + " |")
    closed = [r for r in rows if "refused" not in r]
    for layout, label in (("quadriflow", "QuadriFlow"), ("creases", "crease-first")):
        ok = [r[layout] for r in closed if r[layout]["ok"]]
        own = [x for x in ok if x["made_by"] == layout]
        recalls = [x["crease_recall"] for x in ok if x["crease_recall"] is not None]
        if not ok:
            continue
        lines += ["", (f"{label}: layouts on {len(ok)} of {len(closed)} closed parts ({len(own)} made by it); crease "
                  f"recall {min(recalls):.3f}–{max(recalls):.3f} (median {np.median(recalls):.3f}, 1.0 on "
                  f"{sum(x == 1.0 for x in recalls)}); no straddling quad on {sum(x['straddling_quads'] == 0 for x in ok)}"
                  f"; irregular vertices {sum(x['irregular_vertices'] for x in ok)}, patches "
                  f"{sum(x['patches'] or 0 for x in ok)} in all; {sum(x['seconds'] for x in ok):.0f} s in all.")]
    if absent:
        lines += ["", f"Not run (data absent): {', '.join(absent)}."]
    (out / "remesh.md").write_text("\n".join(lines) + "\n")


def draw_layouts(path: Path, name: str, row: dict) -> None:
    """Both layouts of a part side by side, quads edged, seen from the same direction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = plt.figure(figsize=(12, 6))
    for k, layout in enumerate(LAYOUTS):
        r = row[layout]
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        if not r["ok"]:
            continue
        v, q = r["layout"].vertices, r["layout"].faces
        normal = np.cross(v[q[:, 2]] - v[q[:, 0]], v[q[:, 3]] - v[q[:, 1]])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        shade = 0.35 + 0.6 * np.clip(normal @ np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), 0, 1)
        ax.add_collection3d(Poly3DCollection(v[q], facecolors=np.stack([shade * 0.75, shade * 0.85, shade], 1),
                                             edgecolors=(0.1, 0.1, 0.1, 0.6), linewidths=0.2))
        lo, hi = v.min(axis=0), v.max(axis=0)
        c, half = (lo + hi) / 2, (hi - lo).max() / 2
        ax.set_xlim(c[0] - half, c[0] + half)
        ax.set_ylim(c[1] - half, c[1] + half)
        ax.set_zlim(c[2] - half, c[2] + half)
        ax.view_init(elev=30, azim=-60)
        ax.set_axis_off()
        ax.set_title(f"{name}, {'QuadriFlow' if layout == 'quadriflow' else 'crease-first'}: {r['quads']} quads, "
                     f"{r['irregular_vertices']} irregular, recall {_fmt(r['crease_recall'], '.3f')}", fontsize=9)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def part_arguments(description: str, known: list[str], argv: list[str] | None) -> tuple[list[str], Path, Path]:
    """The bench's --parts (checked against ``known``), --data and --out; the output folder is made."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--parts", default=",".join(known), help="comma-separated part names (default: all)")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    args = ap.parse_args(argv)
    names = [n for n in args.parts.split(",") if n]
    unknown = [n for n in names if n not in known]
    if unknown:
        ap.error(f"unknown parts {unknown}; known: {', '.join(known)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return names, Path(args.data), out


def main(argv: list[str] | None = None) -> int:
    pictures = []
    if argv is None:
        argv = sys.argv[1:]
    if "--pictures" in argv:
        at = argv.index("--pictures")
        pictures = argv[at + 1].split(",")
        argv = argv[:at] + argv[at + 2:]
    names, data, out = part_arguments(__doc__.split("\n\n")[0], list(PARTS), argv)
    machine = describe_machine()
    rows, absent = [], []
    for name in names:
        mesh = PARTS[name][0](data)
        if mesh is None:
            absent.append(name)
            print(f"{name}: data absent, skipped", flush=True)
            continue
        row = bench_part(name, mesh)
        if name in pictures and "refused" not in row:
            draw_layouts(out / f"remesh-{name}.png", name, row)
        for layout in LAYOUTS:
            row.get(layout, {}).pop("layout", None)
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items()}, default=str)[:600], flush=True)
        (out / "remesh.json").write_text(json.dumps({"machine": machine, "parts": rows, "absent": absent}, indent=1))
    write_table(rows, absent, out, machine)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
