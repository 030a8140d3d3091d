"""The fit with and without the remesh's crease snapping: patches over tolerance on clean parts.

    python bench/snap_fit.py [--parts fandisk_tgvresult,bracket,...] [--data ../shared/data] [--out bench/results]

`remesh.snap_creases` moves the kept QuadriFlow layout's edges onto the creases (`cam.remesh.snap`). Whether that
helps is decided downstream, where a bicubic patch that a crease runs through misses it: each part goes through
the pipeline's own remesh, segment and fit stage code twice, with snapping off and on, default parameters
otherwise. Parts: the MeshTGV authors' denoised Fandisk and Block (as `bench/fit.py` takes them), and clean
meshes of `bench/remesh.py`'s corpus (Fandisk and Block ground truth ×10, CSG parts, ABC parts at 60 mm). Per
run: crease recall of the layout (over 50°, 0.2 % of the diagonal), patches, patches over `fit.tolerance_mm`,
the largest patch errors, the fit's time. Writes ``snap_fit.md`` and ``snap_fit.json``.

The parts looked at while snapping was written (`seen`) and those never looked at (`held`) are marked.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from machine_info import describe_machine  # bench/ is on the path when a script runs

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# name: held out (never looked at while snapping was written)
PARTS = {"fandisk_tgvresult": False, "block_tgvresult": False, "fandisk": False, "block": False, "bracket": False,
         "pockets": False, "box_pocket_fillet": False, "cylinder_chamfer": False, "plate_holes": True,
         "hex_countersink": True, "washer": True, "cross_boss": True, "abc4": True, "abc9": True}


def load(name: str, data: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """The part's triangle mesh in mm, or None when its data is absent."""
    if name.endswith("_tgvresult"):
        from cam.io import read_obj

        path = data / f"{name}.obj"
        if not path.exists():
            return None
        raw = read_obj(path)
        return raw.points * 10.0, raw.faces.astype(np.int64)
    from remesh import PARTS as CORPUS

    return CORPUS[name][0](data)


def run_part(mesh: tuple[np.ndarray, np.ndarray], snap: bool) -> dict:
    """remesh -> segment -> fit with `remesh.snap_creases` = snap: the layout's recall and the fit's errors."""
    from fit import job_params, run_stage

    from cam.io import write_ply_mesh
    from worker.stages.fit import run_fit
    from worker.stages.remesh import run_remesh
    from worker.stages.segment import run_segment

    params = job_params()
    params["remesh"]["snap_creases"] = snap
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        mesh_ply = write_ply_mesh(work / "mesh.ply", *mesh)
        remeshed, _ = run_stage(run_remesh, "remesh", work, {"mesh.ply": mesh_ply}, params)
        segments, _ = run_stage(run_segment, "segment", work, {"quads.obj": remeshed["quads.obj"]}, params)
        fitted, seconds = run_stage(run_fit, "fit", work, {"quads.obj": remeshed["quads.obj"],
                                                           "patches.json": segments["patches.json"],
                                                           "mesh.ply": mesh_ply}, params)
        doc = json.loads(Path(fitted["surfaces.json"]).read_text())
        remesh = json.loads(Path(remeshed["remesh.json"]).read_text())
    errors = sorted((s["max_error_mm"] for s in doc["surfaces"]), reverse=True)
    return {"crease_recall": remesh["crease_recall"], "straddling_quads": remesh["straddling_quads"],
            "patches": len(errors), "over_tolerance": sum(e > doc["tolerance_mm"] for e in errors),
            "tolerance_mm": doc["tolerance_mm"], "largest_errors_mm": errors[:3], "fit_s": seconds}


def write_table(rows: list[dict], out: Path, machine: str) -> None:
    lines = ["# The fit with and without crease snapping (`bench/snap_fit.py`)", "",
             __doc__.split("\n\n", 2)[2].strip(), "", f"Machine: {machine}.", "",
             ("| part | set | recall >50° off → on | straddling off → on | patches off → on | over tolerance off → on "
              "| largest errors off (mm) | largest errors on (mm) | fit s off / on |"),
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        off, on = r["off"], r["on"]
        lines.append(
            f"| {r['part']} | {'held' if r['held_out'] else 'seen'} | {off['crease_recall']:.3f} → "
            f"{on['crease_recall']:.3f} | {off['straddling_quads']} → {on['straddling_quads']} | {off['patches']} → "
            f"{on['patches']} | {off['over_tolerance']} → {on['over_tolerance']} | "
            f"{', '.join(f'{e:.3f}' for e in off['largest_errors_mm'])} | "
            f"{', '.join(f'{e:.3f}' for e in on['largest_errors_mm'])} | {off['fit_s']:.0f} / {on['fit_s']:.0f} |")
    for held in (False, True):
        part = [r for r in rows if r["held_out"] == held]
        if part:
            lines.append("")
            lines.append(f"{'Held out' if held else 'Seen'} ({len(part)} parts): patches over tolerance "
                         f"{sum(r['off']['over_tolerance'] for r in part)} → {sum(r['on']['over_tolerance'] for r in part)}"
                         f"; parts with none {sum(r['off']['over_tolerance'] == 0 for r in part)} → "
                         f"{sum(r['on']['over_tolerance'] == 0 for r in part)}.")
    (out / "snap_fit.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    from remesh import part_arguments

    names, data, out = part_arguments(__doc__.split("\n\n")[0], list(PARTS), argv)
    machine = describe_machine()
    rows = []
    for name in names:
        mesh = load(name, data)
        if mesh is None:
            print(f"{name}: data absent, skipped", flush=True)
            continue
        row = {"part": name, "held_out": PARTS[name], "off": run_part(mesh, False), "on": run_part(mesh, True)}
        rows.append(row)
        print(json.dumps(row), flush=True)
        (out / "snap_fit.json").write_text(json.dumps({"machine": machine, "rows": rows}, indent=1))
    write_table(rows, out, machine)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
