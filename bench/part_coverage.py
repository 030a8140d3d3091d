"""Does the program finish the part? The whole pipeline on real and CSG parts, checked against the true part.

Each part goes through `cloud2cnc run`'s code (default parameters: ball r = 3 mm, h = 0.16 mm) as a
user would send it: a clean mesh upload, or a 50k-point cloud with normals sampled from it. The programs
are then measured by the bench's own check (`partcheck.py`: pygcode, sphere tracing, OpenCAMLib reach; no
code of ours) on samples of the ground-truth mesh: reachable share from the job's setups, finished share of
the reachable (left ≤ h along the normal), largest left, deepest gouge by cutting moves and by rapids, path
and air length. In the same run, an OpenCAMLib program (`oclfinish.py`: raster on shallow, waterline on
steep, flat-surface stepover for h, same setups, same mesh.ply) gets the same check.

Parts: Fandisk and Block ×10 from ../shared/data (clean mesh upload and cloud), and two CSG parts made here
(an L-bracket with a through hole and a boss; a block with two pockets whose corner and floor fillets are
smaller than the ball). The planner was tuned on the test shapes (box, pocket box, dome) and on the clean
Fandisk; Block, both clouds and both CSG parts are held out. With `--rest`, the pockets part and Fandisk run
again with `tool.rest_radius_mm = 1` (with --reuse, plan and verify only, on the first run's setups).

    python bench/part_coverage.py [part ...] [--rest] [--reuse=DIR [--replan]] [--ocl-sweep]
        parts: fandisk, block, fandisk-cloud, block-cloud, bracket, pockets (default: all; `pockets+rest`:
        that part's rest variant alone); --reuse keeps
        each part's pipeline output in DIR and checks it again instead of running the pipeline anew;
        --replan runs plan and verify again on what is kept (a planner change, without a new fit);
        the OpenCAMLib baseline runs on the clean meshes only (on a cloud's ~200k-triangle reconstruction its
        waterline ran for more than 45 minutes);
        --ocl-sweep runs the OpenCAMLib baseline again at 0.8, 0.64, 0.5, 0.4, 0.32 of its stepover until it
        finishes as much as ours with no larger largest left, for the path lengths at equal coverage
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
# This checkout's code, not an installed one: oclfinish imports cam, and a bench run from a git worktree
# must measure the worktree's.
sys.path.insert(0, str(ROOT))

from machine_info import describe_machine  # bench/ is on the path when a script runs
from oclfinish import ocl_program
from partcheck import left_and_gouge, reachable, read_moves, sample_mesh

from tests.csgparts import bracket, rounded_box, solid_mesh

DATA = ROOT.parent / "shared" / "data"
RESULTS = ROOT / "bench" / "results"
R, H = 3.0, 0.16
CLOUD_POINTS = 50_000
HELD_OUT = {"block", "fandisk-cloud", "block-cloud", "bracket", "pockets"}
SWEEP_FRACTIONS = (0.8, 0.64, 0.5, 0.4, 0.32)


def pockets() -> tuple[np.ndarray, np.ndarray]:
    """A 60 × 40 × 20 block with a 24 × 16 × 10 pocket (corners and floor filleted 1.5 mm) and a
    12 × 12 × 6 pocket (corners 1 mm, sharp floor): every fillet smaller than the 3 mm ball."""
    from manifold3d import Manifold

    block = Manifold.cube([60.0, 40.0, 20.0])
    p1 = rounded_box((24.0, 16.0, 12.0), 1.5, 1.5).translate([6.0, 12.0, 10.0])
    p2 = rounded_box((12.0, 12.0, 8.0), 1.0, 0.0).translate([40.0, 14.0, 14.0])
    return solid_mesh(block - p1 - p2)


def ground_truth(part: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The part's true mesh, mm; None when its data is absent."""
    name = part.removesuffix("-cloud")
    if name == "bracket":
        return bracket()
    if name == "pockets":
        return pockets()
    src = DATA / f"{name}_gt.obj"
    if not src.exists():
        return None
    m = trimesh.load(src, process=False)
    return np.asarray(m.vertices, dtype=np.float64) * 10.0, np.asarray(m.faces, dtype=np.int64)


def upload(part: str, vertices: np.ndarray, faces: np.ndarray, folder: Path) -> Path:
    """What a user sends: the mesh as STL, or a 50k-point cloud with normals sampled from it."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if part.endswith("-cloud"):
        points, face = trimesh.sample.sample_surface(mesh, CLOUD_POINTS, seed=0)
        path = folder / f"{part}.xyz"
        np.savetxt(path, np.hstack([points, mesh.face_normals[face]]), fmt="%.6f")
        return path
    path = folder / f"{part}.stl"
    mesh.export(path)
    return path


def run_pipeline(path: Path, out: Path, params: dict) -> dict[str, tuple[str, float, str | None]]:
    from core.config import Settings
    from worker.local import run_local

    with open(os.devnull, "w") as quiet:
        reports = run_local(path, out, params=params, settings=Settings(data_dir=out.parent / "data"), stream=quiet)
    return {r.name: (r.status, r.seconds, r.error) for r in reports}


def replan(source: Path, out: Path, params: dict) -> dict[str, tuple[str, float, str | None]]:
    """Run `plan` and `verify` again with `params` on another run's mesh.ply, surfaces.json and setup.json
    (so a rest run is compared on the same setups, without a second remesh and fit)."""
    import shutil

    from core.config import Settings
    from core.params import JobParams
    from core.stages import load_stages
    from worker.context import StageContext, StageError
    from worker.stages import implementation

    out.mkdir(parents=True, exist_ok=True)
    for name in ("mesh.ply", "surfaces.json", "setup.json"):
        if (source / name).exists():
            shutil.copy(source / name, out / name)
    settings, job = Settings(data_dir=out.parent / "data"), JobParams.model_validate(params)
    reports = json.loads((source.parent / "stages.json").read_text())
    for spec in load_stages(settings.stage_plugins, settings.pipeline):
        if spec.name not in ("plan", "verify"):
            continue
        scratch = out / f".{spec.name}.tmp"
        scratch.mkdir(exist_ok=True)
        ctx = StageContext(job_id="bench", stage=spec.name, out_dir=scratch, params=job,
                           inputs={n: out / n for n in spec.inputs if (out / n).is_file()},
                           settings={k: getattr(settings, k) for k in spec.settings}, progress=lambda *a: None)
        t0 = time.perf_counter()
        try:
            outputs, status, error = implementation(spec.name, settings.stage_plugins)(ctx), "succeeded", None
        except StageError as exc:  # a verify that fails keeps its report, as run_local does
            outputs, status, error = exc.outputs, "failed", str(exc)
        for name, path in outputs.items():
            Path(path).replace(out / name)
        shutil.rmtree(scratch, ignore_errors=True)
        reports[spec.name] = (status, time.perf_counter() - t0, error)
        if status == "failed":
            break
    return reports


def _machine(setup: dict, points: np.ndarray) -> np.ndarray:
    return points @ np.asarray(setup["rotation"]).T + np.asarray(setup["translation"])


def check(vertices, faces, setups: list[dict], programs: list[tuple[int, str, float]], *, spacing: float,
          rest_radius: float | None = None) -> dict:
    """The bench check of programs [(setup index, G-code text, ball radius)] on the true part."""
    t0 = time.perf_counter()
    points, normals, area = sample_mesh(vertices, faces, spacing)
    total = float(area.sum())
    reach = np.zeros(len(area), bool)
    reach_rest = np.zeros(len(area), bool)
    for s in setups:
        V, p, n = _machine(s, vertices), _machine(s, points), normals @ np.asarray(s["rotation"]).T
        reach |= reachable(V, faces, p, n, R)
        if rest_radius:
            reach_rest |= reachable(V, faces, p, n, rest_radius)
    left = np.full(len(area), np.inf)
    unsettled = np.zeros(len(area), bool)
    gouge = rapid_gouge = 0.0
    length = air = 0.0
    range_mm = max(4 * H, 0.25 * R)
    for k, text, radius in programs:
        s = setups[k]
        moves = read_moves(text)
        p, n = _machine(s, points), normals @ np.asarray(s["rotation"]).T
        got, g, rg = left_and_gouge(moves, radius, p, n, range_mm=range_mm)
        unsettled |= np.isnan(got)
        left = np.fmin(left, got)
        gouge, rapid_gouge = max(gouge, float(g.max(initial=0))), max(rapid_gouge, float(rg.max(initial=0)))
        seg = np.linalg.norm(moves.end - moves.start, axis=1)
        length += float(seg[~moves.rapid].sum())
        air += float(seg[moves.rapid].sum())
    finished = reach & (left <= H)
    either = reach | reach_rest
    on_reach = left[reach & np.isfinite(left)]
    return {
        "reachable": float(area[reach].sum() / total), "finished": float(area[finished].sum() / max(area[reach].sum(), 1e-300)),
        "finished_any": float(area[either & (left <= H)].sum() / max(area[either].sum(), 1e-300)),
        "unreachable": float(area[~reach].sum() / total), "unreachable_either": float(area[~either].sum() / total),
        "largest_left": float(on_reach.max(initial=0.0)), "p99_left": float(np.percentile(on_reach, 99)) if len(on_reach) else 0.0,
        "over_target": float(area[reach & np.isfinite(left) & (left > H)].sum() / total),
        "not_cut": float(area[reach & ~np.isfinite(left) & ~np.isnan(left)].sum() / total),
        "unsettled": int((unsettled & reach & ~(left <= H)).sum()),
        "gouge": gouge, "rapid_gouge": rapid_gouge, "length": length, "air": air, "samples": len(area),
        "seconds": time.perf_counter() - t0,
        "classes": _classes(points, reach, left, either),
    }


def _classes(points, reach, left, either) -> dict:
    """A subsample of the check's samples with their class, for the pictures."""
    rng = np.random.default_rng(0)
    pick = rng.choice(len(points), size=min(len(points), 30000), replace=False)
    cls = np.where(~either, 0, np.where(~reach, 1, np.where(left <= H, 2, np.where(np.isfinite(left), 3, 4))))
    return {"points": points[pick].round(3).tolist(), "class": cls[pick].tolist()}


def run_part(part: str, *, rest: bool = False, reuse: Path | None = None, replanned: bool = False,
             sweep: bool = False) -> dict | None:
    """One part through the pipeline and the check, with the baseline; `reuse`: a folder where the
    pipeline's output of an earlier run is kept (run again only when it is not there); `replanned`: run
    plan and verify again on what is kept; `sweep`: the baseline again at smaller stepovers (_sweep)."""
    truth = ground_truth(part)
    if truth is None:
        return None
    vertices, faces = truth
    params = {"tool": {"radius_mm": R, **({"rest_radius_mm": 1.0} if rest else {})},
              "toolpath": {"scallop_height_mm": H}}
    spacing = 2.0 / 3.0 * np.sqrt(H * (2 * R - H))  # a third of the flat pass interval (longest piece edge)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) if reuse is None else reuse / f"{part}{'+rest' if rest else ''}"
        out = folder / "out"
        stored = folder / "stages.json"
        plain = None if reuse is None else reuse / part / "out"
        if reuse is not None and stored.exists() and replanned:
            import shutil

            shutil.rmtree(folder / "kept", ignore_errors=True)
            out.rename(folder / "kept")  # the pipeline's output as it was; plan and verify run again on it
            stages = replan(folder / "kept", out, params)
            shutil.rmtree(folder / "kept")
            stored.write_text(json.dumps(stages))
        elif reuse is not None and stored.exists():
            stages = json.loads(stored.read_text())
        elif rest and plain is not None and (plain / "setup.json").exists():  # the same setups, no second fit
            stages = replan(plain, out, params)
            stored.write_text(json.dumps(stages))
        else:
            folder.mkdir(parents=True, exist_ok=True)
            stages = run_pipeline(upload(part, vertices, faces, folder), out, params)
            stored.write_text(json.dumps(stages))
        row = {"part": part, "rest": rest, "stages": stages, "held_out": part in HELD_OUT}
        if not (out / "setup.json").exists() or stages.get("plan", ("",))[0] != "succeeded":
            row["error"] = next((e for s, _, e in stages.values() if s == "failed"), "no program")
            return row
        setups = json.loads((out / "setup.json").read_text())["setups"]
        verify = json.loads((out / "verify.json").read_text()) if (out / "verify.json").exists() else {}
        row["verify"] = {k: verify.get(k) for k in ("passed", "finished_share_of_reachable", "reachable_share",
                                                    "max_scallop_mm", "max_gouge_mm", "summary")}
        programs = []
        for k, s in enumerate(setups):
            programs.append((k, (out / s["program"]).read_text(), R))
            if s.get("rest_program"):
                programs.append((k, (out / s["rest_program"]).read_text(), 1.0))
        row["ours"] = check(vertices, faces, setups, programs, spacing=spacing, rest_radius=1.0 if rest else None)
        if rest or part.endswith("-cloud"):
            return row  # OpenCAMLib's waterline on a cloud's ~200k-triangle reconstruction runs for most of an hour
        mesh = trimesh.load(out / "mesh.ply", process=False)
        row["ocl"], row["ocl_seconds"] = _baseline(mesh, truth, setups, spacing, 1.0)
        if sweep:
            row["ocl_sweep"] = _sweep(mesh, truth, setups, spacing, row["ours"], row["ocl"], row["ocl_seconds"])
    return row


def _baseline(mesh, truth, setups: list[dict], spacing: float, fraction: float) -> tuple[dict, float]:
    """The OpenCAMLib program on every setup at `fraction` of the flat stepover, checked on the true part."""
    t0 = time.perf_counter()
    programs, counts = [], []
    for k, s in enumerate(setups):
        text, stats = ocl_program(_machine(s, np.asarray(mesh.vertices, float)), np.asarray(mesh.faces), r=R, h=H,
                                  step_fraction=fraction)
        programs.append((k, text, R))
        counts.append(stats)
    seconds = time.perf_counter() - t0
    result = check(*truth, setups, programs, spacing=spacing)
    result["passes"] = counts
    return result, seconds


def _sweep(mesh, truth, setups, spacing, ours: dict, first: dict, first_seconds: float) -> list[dict]:
    """The baseline at ever smaller stepovers until it leaves no more than our program does: finished share
    at least ours and largest left at most ours (the path-length comparison at equal coverage and equal
    largest left), or until SWEEP_FRACTIONS runs out."""
    rows = []
    for fraction in (1.0, *SWEEP_FRACTIONS):
        result, seconds = (first, first_seconds) if fraction == 1.0 else _baseline(mesh, truth, setups, spacing, fraction)
        rows.append({"fraction": fraction, "seconds": seconds, **{k: v for k, v in result.items() if k != "classes"}})
        print(f"  OpenCAMLib at {fraction:.2f} of the stepover: finished {result['finished']:.4f}, largest left "
              f"{result['largest_left']:.3f} mm, path {result['length'] / 1000:.2f} m", flush=True)
        if result["finished"] >= ours["finished"] and result["largest_left"] <= ours["largest_left"]:
            break
    return rows


def picture(row: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = np.array(["#9e9e9e", "#5c6bc0", "#43a047", "#fb8c00", "#e53935"])
    names = ["unreachable by any ball", "unreachable (main ball)", "finished", "over target", "not cut"]
    who = [k for k in ("ours", "ocl") if k in row]
    fig = plt.figure(figsize=(6 * len(who), 5))
    for c, key in enumerate(who):
        pts = np.asarray(row[key]["classes"]["points"])
        cls = np.asarray(row[key]["classes"]["class"])
        ax = fig.add_subplot(1, len(who), c + 1, projection="3d")
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], c=colours[cls], s=0.4, linewidths=0)
        ax.set_title(f"{row['part']}: {'ours' if key == 'ours' else 'OpenCAMLib'} "
                     f"({100 * row[key]['finished']:.1f} % of reachable finished)", fontsize=9)
        ax.set_axis_off()
        ax.view_init(elev=35, azim=-60)
    handles = [plt.Line2D([], [], marker="o", ls="", color=col, label=n) for col, n in zip(colours, names)]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str]) -> None:
    rest = "--rest" in argv
    reuse = next((Path(a.split("=", 1)[1]) for a in argv if a.startswith("--reuse=")), None)
    parts = [a for a in argv if not a.startswith("--")] or ["fandisk", "block", "fandisk-cloud", "block-cloud",
                                                           "bracket", "pockets"]
    RESULTS.mkdir(parents=True, exist_ok=True)
    store = RESULTS / "coverage.json"
    done = json.loads(store.read_text()) if store.exists() else {"rows": {}}
    done["machine"] = describe_machine()
    # "pockets+rest" runs that part's rest variant alone.
    jobs = ([(p.removesuffix("+rest"), p.endswith("+rest")) for p in parts]
            + ([(p, True) for p in ("pockets", "fandisk")] if rest else []))
    for part, with_rest in jobs:
        print(f"{part}{' (rest)' if with_rest else ''} ...", flush=True)
        row = run_part(part, rest=with_rest, reuse=reuse, replanned="--replan" in argv, sweep="--ocl-sweep" in argv)
        if row is None:
            print(f"  skipped: {part} needs ../shared/data", flush=True)
            continue
        key = f"{part}{'+rest' if with_rest else ''}"
        if not with_rest and "ours" in row:
            picture(row, RESULTS / f"coverage-{part}.png")
        for who in ("ours", "ocl"):
            row.get(who, {}).pop("classes", None)
        done["rows"][key] = row
        store.write_text(json.dumps(done, indent=1))
        print("  " + json.dumps(row), flush=True)
    write_report(done, RESULTS / "coverage.md")


def _pct(x) -> str:
    """A share with one decimal; one short of the whole (or above nothing) never reads 100.0 % (0.0 %)."""
    if x is None:
        return "—"
    if 0.9995 <= x < 1.0:
        return f"{min(np.floor(1e4 * x) / 100, 99.99):.2f} %"
    if 0.0 < x < 0.0005:
        return "< 0.1 %"
    return f"{100 * x:.1f} %"


def _row(key: str, row: dict) -> list[str]:
    """Our line and the baseline's for one part."""
    t = {name: sec for name, (status, sec, _) in row["stages"].items() if status != "skipped"}
    skipped = [name for name, (status, _, _) in row["stages"].items() if status == "skipped"]
    if "error" in row:
        return [f"| {key} | {'held out' if row['held_out'] else 'tuned on'} | **no program**: {row['error']} |" + " |" * 11]
    out = []
    for who, label in (("ours", "ours"), ("ocl", "OpenCAMLib")):
        c = row.get(who)
        if c is None:
            continue
        secs = (f"{sum(t.values()):.0f} (plan {t.get('plan', 0):.0f}, verify {t.get('verify', 0):.0f})" if who == "ours"
                else f"{row['ocl_seconds']:.0f}")
        out.append(f"| {key} | {'held out' if row['held_out'] else 'tuned on'} | {label} | {_pct(c['reachable'])} | "
                   f"**{_pct(c['finished'])}** | {c['largest_left']:.3f} | {c['p99_left']:.3f} | {_pct(c['over_target'])} | "
                   f"{_pct(c['not_cut'])} | {c['gouge']:.4f} | {c['rapid_gouge']:.4f} | {c['length'] / 1000:.2f} | "
                   f"{c['air'] / 1000:.2f} | {secs} |")
    if skipped and out:
        out[0] = out[0][:-1] + f" skipped: {', '.join(skipped)} |"
    return out


SWEEP_HEAD = ("Path length at equal coverage and equal largest left (`--ocl-sweep`): the OpenCAMLib program again "
              "at smaller stepovers (a fraction of the flat-surface interval, its raster and its waterline z step "
              "alike) until it finishes at least the share of the reachable that ours does and leaves no more than "
              "our largest left. `path ratio`: the baseline's cutting path over ours.\n\n"
              "| part | program | stepover fraction | finished of reachable | largest left mm | p99 left mm | path m | "
              "path ratio | seconds |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n")


def _sweep_rows(key: str, row: dict) -> str:
    ours = row["ours"]
    lines = [(f"| {key} | ours | — | {_pct(ours['finished'])} | {ours['largest_left']:.3f} | {ours['p99_left']:.3f} | "
              f"{ours['length'] / 1000:.2f} | 1.00 | — |")]
    for s in row["ocl_sweep"]:
        equal = s["finished"] >= ours["finished"] and s["largest_left"] <= ours["largest_left"]
        lines.append(f"| {key} | OpenCAMLib{' (equal)' if equal else ''} | {s['fraction']:.2f} | {_pct(s['finished'])} | "
                     f"{s['largest_left']:.3f} | {s['p99_left']:.3f} | {s['length'] / 1000:.2f} | "
                     f"{s['length'] / max(ours['length'], 1e-300):.2f} | {s['seconds']:.0f} |")
    return "\n".join(lines)


def write_report(done: dict, path: Path) -> None:
    """The markdown table of every part run so far, ours and the baseline, with the stage times."""
    head = ("| part | corpus | program | reachable | finished of reachable | largest left mm | p99 left mm | over h "
            "| not cut | gouge mm (cutting) | gouge mm (rapids) | path m | air m | seconds |\n"
            "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    rows = done["rows"]
    lines = [line for key, row in rows.items() if not row.get("rest") for line in _row(key, row)]
    rest = []
    for key, row in rows.items():
        if row.get("rest") and "ours" in row:
            c = row["ours"]
            rest.append(f"| {row['part']} | {_pct(c['unreachable'])} | {_pct(c['unreachable_either'])} | "
                        f"{_pct(c['finished_any'])} | {c['gouge']:.4f} |")
    stages = []
    for key, row in rows.items():
        cells = [f"{row['stages'][s][1]:.1f}" if s in row["stages"] and row["stages"][s][0] == "succeeded"
                 else row["stages"].get(s, ("—",))[0] for s in ("ingest", "reconstruct", "denoise", "remesh",
                                                                 "segment", "fit", "plan", "verify")]
        stages.append(f"| {key} | " + " | ".join(cells) + f" | {row.get('verify', {}).get('summary', '—')} |")
    sweeps = [_sweep_rows(key, row) for key, row in rows.items() if row.get("ocl_sweep")]
    keep = ""
    if path.exists() and "## Notes" in path.read_text():
        keep = path.read_text()[path.read_text().index("## Notes"):]
    text = (f"# Coverage benchmark\n\n`python bench/part_coverage.py [part ...] [--rest]`. {__doc__.split(chr(10) + chr(10))[1]}\n\n"
            f"Machine: {done['machine']}.\n\n"
            f"Ball r = {R} mm, h = {H} mm. Shares of the ground-truth part's area; `finished of reachable`: left ≤ h "
            "along the normal, of what the ball reaches from the job's setups; `largest left` and `p99 left` over the "
            "reachable samples where anything was measured (material is measured up to "
            f"{max(4 * H, 0.25 * R):.2f} mm: beyond it a sample counts as `not cut`).\n\n"
            + head + "\n" + "\n".join(lines) + "\n\n"
            "Stage seconds (ours) and what our own verify said:\n\n"
            "| part | ingest | reconstruct | denoise | remesh | segment | fit | plan | verify | verify's summary |\n"
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|\n" + "\n".join(stages) + "\n\n"
            + ("With a rest ball of r = 1 mm (`tool.rest_radius_mm = 1`):\n\n"
               "| part | unreachable by the main ball | unreachable by both | finished of what either reaches | gouge mm |\n"
               "|---|---:|---:|---:|---:|\n" + "\n".join(rest) + "\n\n" if rest else "")
            + (SWEEP_HEAD + "\n".join(sweeps) + "\n\n" if sweeps else "")
            + "Pictures: `coverage-<part>.png` (ours left, OpenCAMLib right).\n\n" + keep)
    path.write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
