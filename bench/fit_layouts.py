"""Compare quad layouts by what the fit makes of them: one table row per remesh setting.

    python bench/fit_layouts.py [--data ../shared/data] [--jobs 2] [--out FILE.md] \\
        fandisk_tgvresult:remesh.seed=1,remesh.candidates=1,remesh.attempts=1 \\
        block_tgvresult:remesh.target_faces=4500 ...

Each argument is a mesh of the data folder and the parameters that differ from the
defaults (`group.name=value`, comma-separated; none after the colon means the defaults).
Each runs remesh → segment → fit with the stages' own code, as `bench/fit.py` does,
in its own process (`--jobs` at a time, each single-threaded). A row gives the layout
(quads, crease length missed, Hausdorff distance, from remesh.json) and the fit
(patches, how many over the tolerance, sum and largest of the patch maxima).
Fit times are printed too, but jobs run side by side share the machine: they are
not a speed measurement. Stop 32's layout tables in `bench/results/fit.md` were made with
these stage calls (on 16 cores, 16 jobs at a time).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from machine_info import describe_machine  # bench/ is on the path when a script runs

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def parse_setting(text: str) -> tuple[str, dict[str, str]]:
    """'mesh:group.name=value,...' -> (mesh, {'group.name': 'value'})."""
    mesh, _, rest = text.partition(":")
    overrides = {}
    for item in filter(None, rest.split(",")):
        key, sep, value = item.partition("=")
        if not sep or key.count(".") != 1:
            raise ValueError(f"a setting is group.name=value, got {item!r} in {text!r}")
        overrides[key] = value
    return mesh, overrides


def apply_overrides(params: dict, overrides: dict[str, str]) -> dict:
    """Set `group.name` entries of a JobParams dump, converting each value to its default's type."""
    for key, value in overrides.items():
        group, name = key.split(".")
        if group not in params or name not in params[group]:
            raise ValueError(f"no parameter {key!r}")
        default = params[group][name]
        if isinstance(default, bool):
            params[group][name] = value.lower() in ("1", "true", "yes")
        elif default is None:
            params[group][name] = float(value)
        else:
            params[group][name] = type(default)(value)
    return params


def run_one(mesh: str, overrides: dict[str, str], data: Path, work: Path) -> dict:
    """remesh → segment → fit on one mesh ×10 with the overrides (`bench/fit.py`'s run); the row's figures."""
    from fit import bench_mesh, job_params

    run = bench_mesh(mesh, data, work, apply_overrides(job_params(), overrides))
    report, doc = run["remesh"], run["doc"]
    errors = [s["max_error_mm"] for s in doc["surfaces"]]
    return {"quads": report["faces"], "seed": report["seed"], "missed_crease_mm": report.get("missed_crease_mm"),
            "crease_length_mm": report.get("crease_length_mm"), "hausdorff_mm": report["hausdorff_mm"],
            "patches": len(errors), "over": len(doc["over_tolerance"]), "sum_mm": sum(errors), "worst_mm": max(errors),
            "remesh_s": run["times"][0], "fit_s": run["times"][2]}


def _child(argv: list[str]) -> int:
    mesh, overrides = parse_setting(argv[0])
    try:
        row = run_one(mesh, overrides, Path(argv[1]), Path(argv[2]))
    except Exception as exc:  # a setting remesh refuses is a row too, with the stage's message
        row = {"error": str(exc).splitlines()[0][:300]}
    print(json.dumps(row))
    return 0


def _run(setting: str, data: Path, timeout_s: float) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory(prefix="fit-layouts-") as tmp:
        try:
            out = subprocess.run([sys.executable, __file__, "--child", setting, str(data), tmp], env=env,
                                 capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return {"error": f"still running after {timeout_s:.0f} s"}
    lines = out.stdout.strip().splitlines()
    if out.returncode or not lines:
        return {"error": (out.stderr.strip().splitlines() or ["no output"])[-1][:300]}
    return json.loads(lines[-1])


def format_row(setting: str, r: dict) -> str:
    if "error" in r:
        return f"| `{setting}` | {r['error']} ||||||||||"
    missed = "—" if r["missed_crease_mm"] is None else f"{r['missed_crease_mm']:.1f}"
    return (f"| `{setting}` | {r['seed']} | {r['quads']} | {missed} | {r['hausdorff_mm']:.3f} | {r['patches']} | "
            f"{r['over']} | {r['sum_mm']:.3f} | {r['worst_mm']:.3f} | {r['remesh_s']:.1f} | {r['fit_s']:.1f} |")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        return _child(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("settings", nargs="+", help="mesh:group.name=value,... (see the module docstring)")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout-s", type=float, default=1800.0, help="per setting")
    ap.add_argument("--out", help="also write the table to this markdown file")
    args = ap.parse_args(argv)
    from fit import job_params

    data = Path(args.data)
    for s in args.settings:  # bad settings fail here, before any job starts
        try:
            mesh, overrides = parse_setting(s)
            apply_overrides(job_params(), overrides)
        except ValueError as exc:
            print(exc, file=sys.stderr)
            return 2
        if not (data / f"{mesh}.obj").is_file():
            print(f"no {mesh}.obj in {data}", file=sys.stderr)
            return 2
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(lambda s: _run(s, data, args.timeout_s), args.settings))
    lines = [f"Machine: {describe_machine()}; {args.jobs} jobs side by side, {time.perf_counter() - t0:.0f} s in all.",
             "", "| setting | seed kept | quads | crease missed (mm) | Hausdorff (mm) | patches | over | "
             "sum of maxima (mm) | worst (mm) | remesh (s) | fit (s) |", "|---|" + "---:|" * 10]
    lines += [format_row(s, r) for s, r in zip(args.settings, rows)]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
