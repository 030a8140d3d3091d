"""Fast enough to use? A 50k-point part from cloud to verified program, stage by stage, time and memory.

Each run is a fresh `cloud2cnc run` process (the same interpreter as this script, its own --out folder) on
what a user would send: a 50k-point cloud with normals sampled from Fandisk or Block ×10 (made as
`part_coverage.py` makes them), the two CSG parts of `part_coverage.py` uploaded as meshes, and the README example
(`examples/dome_block.xyz`, r = 2 mm, at most 20,000 triangles, no knot refinement). Default parameters
otherwise. Per stage: the seconds the stage reports and the process's peak resident memory while it ran;
per run: wall time from start to exit and the run's peak resident memory. Medians over --runs.

With --base REV the same parts also run on the code of revision REV (a `git worktree` under /tmp, put
first on PYTHONPATH), interleaved with the new code's runs (base, new, base, new ...) so that other load
on the machine hits both alike; the programs (`program*.nc`) of both are compared byte for byte, and each run's
outcome is listed (the layout's crease recall, the surfaces over the fit's tolerance, verify's verdict and
finished share), so that a change that alters the result shows what it did beside its time. The new
code is this working tree, uncommitted changes included (the report says if it changed during the run).
--set KEY=VALUE (repeatable) is given to the new code's runs only: with --base HEAD it compares a parameter
against the defaults on the same code. --profile adds one run of the new code per part under py-spy and lists, per stage, where its samples went.
--scaling times Fandisk ×10 clouds of 50k, 200k and 1M points at h = 0.16 and 0.02 mm (new code, one run
each). Targets (the issue): whole 50k job ≤ 120 s, fit ≤ 20 s, plan ≤ 30 s, verify ≤ 15 s, README example
≤ 30 s, peak RSS ≤ 2 GB at 1M points; on two cores.

    python bench/e2e.py [part ...] [--runs N] [--base REV] [--set KEY=VALUE ...] [--profile]
        [--scaling [--scaling-points 200000,1000000] [--scaling-h 0.16]] [--out-name NAME]
        parts: fandisk-cloud, block-cloud, bracket, pockets, example (default: all, or none with --scaling);
        writes bench/results/NAME.md and NAME.json (NAME: e2e). Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

from machine_info import describe_machine  # bench/ is on the path when a script runs

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
PACKAGES = ("cam", "cloud2cnc", "core", "service", "worker")
# main() returns the exit status; without sys.exit a failed run would exit 0.
RUN_CODE = "import sys; from cloud2cnc.cli import main; sys.exit(main())"
STAGES = ("ingest", "reconstruct", "denoise", "remesh", "segment", "fit", "plan", "verify")
PARTS = ("fandisk-cloud", "block-cloud", "bracket", "pockets", "example")
EXAMPLE_SETS = ("tool.radius_mm=2", "reconstruct.max_faces=20000", "fit.max_refinements=0")
TARGETS_50K = {"fit": 20.0, "plan": 30.0, "verify": 15.0, "total": 120.0}
TARGETS_EXAMPLE = {"total": 30.0}
RSS_TARGET_1M_MB = 2048
SCALING_POINTS = (50_000, 200_000, 1_000_000)
SCALING_H = (0.16, 0.02)
PROFILE_RATE = 50
TOP_FUNCTIONS = 8
# `cloud2cnc run` ends each stage with "<name padded to 12> done in 1.23 s: a, b", "skipped <why>" or
# "FAILED: <why>" (worker/local.py, written to stderr).
PROCESS_FRAME = re.compile(r'process \d+:".*?";')
STAGE_LINE = re.compile(r"^(?P<stage>[a-z_][a-z0-9_]*) +(?:done in (?P<seconds>[0-9.]+) s\b.*|skipped\b ?(?P<why>.*)"
                        r"|FAILED: (?P<error>.*))$")


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def git(*args: str) -> str:
    # Right side only: porcelain lines begin with a status column that may be a space. No optional locks:
    # someone may be committing in this tree meanwhile.
    done = subprocess.run(["git", "--no-optional-locks", *args], cwd=ROOT, check=True, capture_output=True, text=True)
    return done.stdout.rstrip()


# --- the code under test ---------------------------------------------------------------------------------

def code_env(root: Path, work: Path) -> dict[str, str]:
    """The children's environment: `root`'s packages first on the path (ahead of the editable install)."""
    path = str(root) + (os.pathsep + os.environ["PYTHONPATH"] if os.environ.get("PYTHONPATH") else "")
    return dict(os.environ, PYTHONPATH=path, PYTHONUNBUFFERED="1", CLOUD2CNC_DATA_DIR=str(work / "data"))


def check_imports(label: str, root: Path, env: dict[str, str], cwd: Path) -> None:
    """Exit unless a child with this environment imports every package of the project from `root`."""
    code = (f"import json, sys, {', '.join(PACKAGES)}; "
            f"print(json.dumps({{m: sys.modules[m].__file__ for m in {list(PACKAGES)!r}}}))")
    got = subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True,
                         check=False)
    if got.returncode != 0:
        sys.exit(f"e2e: the {label} code does not import: {got.stderr.strip()[-2000:]}")
    files = json.loads(got.stdout.strip().splitlines()[-1])
    wrong = {m: f for m, f in files.items() if not Path(f).resolve().is_relative_to(root.resolve())}
    if wrong:
        sys.exit(f"e2e: the {label} code should come from {root}, but {wrong}")
    log(f"{label}: {', '.join(PACKAGES)} import from {root}")


def add_worktree(rev: str) -> tuple[Path, str]:
    sha = git("rev-parse", "--verify", f"{rev}^{{commit}}")
    path = Path(tempfile.gettempdir()) / f"e2e-base-{sha[:10]}"
    if path.exists():  # left by an interrupted run
        subprocess.run(["git", "worktree", "remove", "--force", str(path)], cwd=ROOT, capture_output=True, check=False)
        shutil.rmtree(path, ignore_errors=True)
        git("worktree", "prune")
    git("worktree", "add", "--detach", str(path), sha)
    return path, sha


def remove_worktree(path: Path) -> None:
    done = subprocess.run(["git", "worktree", "remove", "--force", str(path)], cwd=ROOT, capture_output=True,
                          text=True, check=False)
    if done.returncode != 0:
        log(f"e2e: could not remove the worktree {path}: {done.stderr.strip()}")


def code_fingerprint() -> str:
    """HEAD, the uncommitted diff and the untracked files of the packages: changes when the new code does."""
    digest = hashlib.sha256((git("rev-parse", "HEAD") + git("diff", "HEAD", "--", *PACKAGES)).encode())
    for name in git("ls-files", "--others", "--exclude-standard", "--", *PACKAGES).splitlines():
        digest.update(name.encode() + (ROOT / name).read_bytes())
    return digest.hexdigest()[:12]


def describe_new() -> str:
    # Untracked files count too when they are the packages' (a new module the changed code imports).
    dirty = [line[3:] for line in git("status", "--porcelain").splitlines()
             if not line.startswith("??") or line[3:].startswith(tuple(f"{p}/" for p in PACKAGES))]
    head = git("rev-parse", "--short=10", "HEAD")
    return f"working tree at {head}" + (f" with uncommitted changes to {', '.join(dirty)}" if dirty else "")


# --- inputs ----------------------------------------------------------------------------------------------

def sample_cloud(vertices, faces, points: int, path: Path) -> Path:
    """`coverage.upload`'s cloud (same sampler, seed and format) with any number of points."""
    import numpy as np
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    xyz, face = trimesh.sample.sample_surface(mesh, points, seed=0)
    np.savetxt(path, np.hstack([xyz, mesh.face_normals[face]]), fmt="%.6f")
    return path


def prepare_input(part: str, folder: Path) -> tuple[Path, tuple[str, ...]] | str:
    """The file a user would send for `part` and its --set assignments, or why the part cannot run."""
    if part == "example":
        return ROOT / "examples" / "dome_block.xyz", EXAMPLE_SETS
    try:  # bench/part_coverage.py (bench/ is first on the path)
        from part_coverage import ground_truth, upload

        truth = ground_truth(part)
    except ImportError as exc:  # the bench extras (opencamlib, pygcode, manifold3d) are missing
        return f"bench/part_coverage.py needs {exc.name}: {exc}"
    if truth is None:
        return f"its ground truth is missing (../shared/data/{part.removesuffix('-cloud')}_gt.obj)"
    folder.mkdir(parents=True, exist_ok=True)
    return upload(part, *truth, folder), ()


# --- one run ---------------------------------------------------------------------------------------------

def _peak_mb(pid: int) -> float | None:
    """The process's peak resident memory since its last reset (VmHWM), MB."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def _reset_peak(pid: int) -> bool:
    """Start the peak over, so that the next reading is the next stage's own (Linux: clear_refs 5)."""
    try:
        Path(f"/proc/{pid}/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _stage_record(match: re.Match, since: float, now: float) -> dict:
    seconds = match["seconds"]
    status = "succeeded" if seconds is not None else "skipped" if match["error"] is None else "failed"
    # Skipped and failed lines give no time: the time since the previous line stands in for it.
    return {"stage": match["stage"], "status": status,
            "seconds": float(seconds) if seconds is not None else round(now - since, 3),
            "message": match["why"] or match["error"] or None}


def run_once(args: list[str], env: dict[str, str], cwd: Path, tag: str, prefix: tuple[str, ...] = ()) -> dict:
    """One `cloud2cnc run ARGS` child: its stages, wall time and peak memory (peaks only without `prefix`)."""
    cmd = [*prefix, sys.executable, "-c", RUN_CODE, "run", *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    watch = not prefix  # under py-spy the child is py-spy's, not ours
    resets = watch and _reset_peak(proc.pid)
    stages, tail, last = [], [], t0
    for line in proc.stdout:
        now, line = time.perf_counter(), line.rstrip("\n")
        tail = (tail + [line])[-30:]
        match = STAGE_LINE.match(line)
        if match is None:
            continue
        record = _stage_record(match, last, now)
        record["peak_mb"] = _peak_mb(proc.pid) if watch else None
        if resets:
            _reset_peak(proc.pid)
        stages.append(record)
        last = now
        log(f"[{tag}] {line}")
    return _finish(proc, watch, t0, stages, tail, tag, resets)


def _finish(proc: subprocess.Popen, watch: bool, t0: float, stages: list, tail: list, tag: str,
            resets: bool) -> dict:
    if watch:
        # wait4's ru_maxrss (what /usr/bin/time %M prints): the larger of the child's peak and its helpers'.
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        # The child's own share of it is only its peak since the last reset: the stages' peaks hold the rest.
        peak = max([usage.ru_maxrss / 1024] + [s["peak_mb"] for s in stages if s["peak_mb"] is not None])
    else:
        proc.wait()
        peak = None
    wall = time.perf_counter() - t0
    run = {"returncode": proc.returncode, "wall_s": round(wall, 3), "peak_mb": peak, "stages": stages,
           "stage_peaks_reset": resets}
    if proc.returncode != 0 and not any(s["status"] == "failed" for s in stages):
        run["error"] = "\n".join(tail[-12:])  # a crash or a refused input: no stage said why
    log(f"[{tag}] wall {wall:.1f} s" + (f", peak RSS {peak:.0f} MB" if peak else "") + f", exit {proc.returncode}")
    return run


def programs_digest(out: Path) -> str | None:
    """One hash over the names and bytes of the run's programs; None when it wrote none."""
    files = sorted(out.glob("program*.nc"))
    if not files:
        return None
    digest = hashlib.sha256()
    for f in files:
        digest.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return digest.hexdigest()


def read_outcome(out: Path) -> dict:
    """What the run made, beside its time: the layout's crease recall, the surfaces over the fit's tolerance,
    verify's verdict and finished share of the reachable part (each None where its stage wrote nothing)."""
    def load(name: str) -> dict:
        try:
            return json.loads((out / name).read_text())
        except (OSError, ValueError):
            return {}

    remesh, surfaces, verify = load("remesh.json"), load("surfaces.json"), load("verify.json")
    return {"crease_recall": remesh.get("crease_recall"),
            "patches": len(surfaces["surfaces"]) if "surfaces" in surfaces else None,
            "over_tolerance": len(surfaces["over_tolerance"]) if "over_tolerance" in surfaces else None,
            "verify_passed": verify.get("passed"),
            "finished_of_reachable": verify.get("finished_share_of_reachable")}


def timed_run(args: list[str], code: dict, out: Path, tag: str) -> dict:
    run = run_once([*args, "--out", str(out)], code["env"], code["cwd"], tag)
    run["programs"] = programs_digest(out)
    run["outcome"] = read_outcome(out)
    shutil.rmtree(out, ignore_errors=True)  # a 1M-point run's artifacts are large; the hash is kept
    return run


def cli_args(path: Path, sets: tuple[str, ...]) -> list[str]:
    return [str(path), *[a for s in sets for a in ("--set", s)]]


# --- summaries -------------------------------------------------------------------------------------------

def summarise(runs: list[dict]) -> dict:
    """Per stage (in pipeline order) and in total: median seconds, median peak MB, statuses."""
    order = [s["stage"] for s in max(runs, key=lambda r: len(r["stages"]))["stages"]] if runs else []
    out = {}
    for name in order:
        got = [s for r in runs for s in r["stages"] if s["stage"] == name]
        peaks = [s["peak_mb"] for s in got if s["peak_mb"] is not None]
        out[name] = {"seconds": statistics.median(s["seconds"] for s in got),
                     "peak_mb": statistics.median(peaks) if peaks else None,
                     "status": dict(Counter(s["status"] for s in got)), "runs": len(got),
                     "messages": sorted({s["message"] for s in got if s["status"] == "failed"})}
    walls = [r["wall_s"] for r in runs]
    inside = [sum(s["seconds"] for s in r["stages"]) for r in runs]
    peaks = [r["peak_mb"] for r in runs if r["peak_mb"] is not None]
    out["outside stages"] = {"seconds": statistics.median(w - i for w, i in zip(walls, inside)), "peak_mb": None}
    out["total"] = {"seconds": statistics.median(walls), "peak_mb": statistics.median(peaks) if peaks else None,
                    "status": dict(Counter("succeeded" if r["returncode"] == 0 else "failed" for r in runs)),
                    "runs": len(runs),
                    "errors": sorted({r["error"] for r in runs if "error" in r})}
    return out


def compare_programs(base: list[dict], new: list[dict]) -> str:
    got = {"base": {r["programs"] for r in base}, "new": {r["programs"] for r in new}}
    if None in got["base"] | got["new"]:
        return "not compared: a run wrote no program"
    verdict = "identical" if got["base"] == got["new"] and len(got["new"]) == 1 else "differ"
    unstable = [side for side, digests in got.items() if len(digests) > 1]
    return verdict + (f" (the {' and '.join(unstable)} runs differ among themselves)" if unstable else "")


# --- py-spy ----------------------------------------------------------------------------------------------

def profile_run(args: list[str], code: dict, out: Path, raw: Path, tag: str) -> dict:
    # --subprocesses: fit maps its patches over forked processes, whose stacks still hold run_fit.
    spy = ["py-spy", "record", "--subprocesses", "-r", str(PROFILE_RATE), "-f", "raw", "-o", str(raw), "--"]
    run = run_once([*args, "--out", str(out)], code["env"], code["cwd"], tag, prefix=tuple(spy))
    shutil.rmtree(out, ignore_errors=True)
    run["profile"] = attribute_samples(raw) if raw.exists() else {}
    return run


def _frame_key(frame: str) -> str:
    """'func (path:line)' → 'func (path)': one row per function, whatever line it was on."""
    return re.sub(r":\d+\)$", ")", frame)


# Plumbing between a stage and its work (the forked map, its lambdas): in every sample of the pieces, they
# would fill the table's top rows and say nothing.
PLUMBING = re.compile(r"^(map_forked|_map_in_children|_fork_child|_Each\.map|\S*<lambda>) ")


def _sample_stage(frames: list[str], processes: int) -> tuple[str, list[str]]:
    """The stage a sample belongs to and its frames below that stage's `run_<stage>` frame."""
    # The outermost run_<stage> frame is the stage run_local called (a forked worker's stack keeps it too).
    at = next((i for i, f in enumerate(frames) if f.split(" ", 1)[0] in {f"run_{s}" for s in STAGES}), None)
    if at is not None:
        return frames[at].split(" ", 1)[0].removeprefix("run_"), frames[at + 1:]
    # A process started anew (QuadriFlow's child) has no stage frame; the run's own are start-up and exit.
    return ("(helper processes)" if processes > 1 else "(outside stages)"), frames


def attribute_samples(raw: Path) -> dict:
    """Per stage: its sample count and the functions below its `run_<stage>` frame that took most of them."""
    counts: dict[str, int] = Counter()
    inclusive: dict[str, Counter] = defaultdict(Counter)
    own: dict[str, Counter] = defaultdict(Counter)
    for line in raw.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        if not n.isdigit():
            continue  # a line of a command line that held a newline
        # With --subprocesses a stack begins with a 'process PID:"cmdline";' frame per process level (the
        # command lines hold semicolons of their own).
        processes = PROCESS_FRAME.findall(stack)
        frames = [_frame_key(f) for f in PROCESS_FRAME.sub("", stack).split(";")]
        stage, below = _sample_stage(frames, len(processes))
        below = [f for f in below if not PLUMBING.match(f)]
        counts[stage] += int(n)
        for f in set(below):
            inclusive[stage][f] += int(n)
        own[stage][(below or frames)[-1]] += int(n)
    return {stage: {"samples": total, "top": [(f, c / total, own[stage][f] / total)
                                              for f, c in inclusive[stage].most_common(TOP_FUNCTIONS)]}
            for stage, total in counts.items()}


# --- the parts -------------------------------------------------------------------------------------------

def run_part(part: str, codes: dict[str, dict], runs: int, work: Path, profile: bool,
             new_sets: tuple[str, ...] = ()) -> dict:
    got = prepare_input(part, work / "inputs")
    if isinstance(got, str):
        log(f"{part}: skipped, {got}")
        return {"skipped": got}
    args = cli_args(*got)
    result: dict = {"input": str(got[0]), "sets": list(got[1]), "new_sets": list(new_sets),
                    "runs": {side: [] for side in codes}}
    for i in range(runs):
        for side, code in codes.items():  # base before new, run after run
            out = work / part / f"{side}-{i + 1}"
            side_args = cli_args(got[0], (*got[1], *new_sets)) if side == "new" else args
            result["runs"][side].append(timed_run(side_args, code, out, f"{part} {side} {i + 1}/{runs}"))
    result["summary"] = {side: summarise(r) for side, r in result["runs"].items()}
    if "base" in codes:
        result["programs"] = compare_programs(result["runs"]["base"], result["runs"]["new"])
        log(f"{part}: programs {result['programs']}")
    if profile:
        result["profiled"] = profile_run(args, codes["new"], work / part / "profile",
                                         work / f"{part}.pyspy.txt", f"{part} new profile")
    return result


def run_scaling(code: dict, work: Path, points_list=SCALING_POINTS, heights=SCALING_H) -> dict:
    """Fandisk ×10 clouds of each size at each scallop height, new code, one run each."""
    try:
        from part_coverage import ground_truth
    except ImportError as exc:
        log(f"scaling: skipped, bench/part_coverage.py needs {exc.name}")
        return {"skipped": f"bench/part_coverage.py needs {exc.name}: {exc}"}
    truth = ground_truth("fandisk-cloud")
    if truth is None:
        log("scaling: skipped, Fandisk's ground truth is missing (../shared/data/fandisk_gt.obj)")
        return {"skipped": "Fandisk's ground truth is missing"}
    rows = []
    for points in points_list:
        cloud = sample_cloud(*truth, points, work / f"fandisk-{points}.xyz")
        for h in heights:
            tag = f"scaling {points} h={h}"
            run = timed_run(cli_args(cloud, (f"toolpath.scallop_height_mm={h}",)), code, work / "scaling", tag)
            rows.append({"points": points, "h_mm": h, "run": run, "summary": summarise([run])})
        cloud.unlink()
    return {"rows": rows}


# --- the report ------------------------------------------------------------------------------------------

def _s(x: float | None) -> str:
    return "–" if x is None else f"{x:.1f}"


def _mb(x: float | None) -> str:
    return "–" if x is None else f"{x:.0f}"


def _ok(row: dict) -> bool:
    return set(row.get("status", {})) <= {"succeeded", "skipped"}


def _status(row: dict) -> str:
    status = row.get("status")
    if not status:
        return ""
    if set(status) == {"succeeded"}:
        return "ok"
    return ", ".join(f"{k} {v}/{row['runs']}" for k, v in status.items())


def _target(targets: dict, stage: str, row: dict) -> str:
    if stage not in targets:
        return ""
    # A stage or run that failed has no time to hold against the target.
    mark = (" ✓" if row["seconds"] <= targets[stage] else " ✗") if _ok(row) else ""
    return f"≤ {targets[stage]:.0f} s{mark}"


def _stage_order(summary: dict) -> list[str]:
    """Every stage either side ran, in pipeline order (one side may have stopped early), then the totals."""
    names = {n for side in summary.values() for n in side} - {"outside stages", "total"}
    return [s for s in STAGES if s in names] + sorted(names - set(STAGES)) + ["outside stages", "total"]


def _ratio(old: dict, new: dict) -> str:
    if not (old and new and _ok(old) and _ok(new) and new["seconds"] > 0):
        return "–"
    return f"{old['seconds'] / new['seconds']:.2f}"


def part_table(part: str, result: dict) -> list[str]:
    summary = result["summary"]
    base = "base" in summary
    targets = TARGETS_EXAMPLE if part == "example" else TARGETS_50K
    lines = [("| stage | base s | new s | base/new | base peak MB | new peak MB | target (new) | status base / new |\n"
              "|---|---:|---:|---:|---:|---:|---|---|") if base else
             "| stage | new s | new peak MB | target | status |\n|---|---:|---:|---|---|"]
    for stage in _stage_order(summary):
        new, old = summary["new"].get(stage, {}), summary.get("base", {}).get(stage, {})
        cells = [_s(new.get("seconds")), _mb(new.get("peak_mb")), _target(targets, stage, new) if new else "",
                 _status(new) or ("not run" if not new else "")]
        if base:
            status = f"{_status(old) or ('not run' if not old else '')} / {cells[3]}".strip(" /")
            cells = [_s(old.get("seconds")), cells[0], _ratio(old, new), _mb(old.get("peak_mb")), cells[1], cells[2],
                     status]
        name = "**total (wall)**" if stage == "total" else stage
        lines.append("| " + " | ".join([name, *cells]) + " |")
    return lines


def _failures(result: dict) -> list[str]:
    out = []
    for side, summary in result["summary"].items():
        for stage, row in summary.items():
            out += [f"- {side}, {stage} failed: {m}" for m in row.get("messages", [])]
            out += [f"- {side}, run ended without a stage saying why:\n\n```\n{e}\n```" for e in row.get("errors", [])]
    return out


def scaling_table(scaling: dict) -> list[str]:
    if "skipped" in scaling:
        return [f"Skipped: {scaling['skipped']}."]
    stages = [s for s in STAGES if any(s in r["summary"] for r in scaling["rows"])]
    lines = ["| points | h mm | " + " | ".join(stages) + " | total (wall) | peak MB |",
             "|---:|---:|" + "---:|" * (len(stages) + 2)]
    for r in scaling["rows"]:
        cells = [(f"{_s(r['summary'][s]['seconds'])} s, {_mb(r['summary'][s]['peak_mb'])} MB"
                  + (f" ({_status(r['summary'][s])})" if _status(r["summary"][s]) else ""))
                 if s in r["summary"] else "–" for s in stages]
        total = r["summary"]["total"]
        mark = (" ✓" if total["peak_mb"] <= RSS_TARGET_1M_MB else " ✗") if r["points"] >= 1_000_000 else ""
        lines.append(f"| {r['points']:,} | {r['h_mm']} | " + " | ".join(cells)
                     + f" | {_s(total['seconds'])} s | {_mb(total['peak_mb'])}{mark} |")
    return lines


def profile_tables(part: str, run: dict) -> list[str]:
    stages = ", ".join(f"{s['stage']} {s['seconds']:.1f} s" for s in run["stages"])
    lines = [f"### {part}", "", f"Stages of the profiled run: {stages}; wall {run['wall_s']:.1f} s.", ""]
    for stage in [*STAGES, "(helper processes)", "(outside stages)"]:
        got = run["profile"].get(stage)
        if not got:
            continue
        busy = got["samples"] / PROFILE_RATE
        lines += [f"**{stage}**: {got['samples']} samples (≈ {busy:.1f} s busy, summed over processes)", "",
                  "| function (file) | inclusive | self |", "|---|---:|---:|"]
        lines += [f"| `{f}` | {100 * inc:.1f} % | {100 * own:.1f} % |" for f, inc, own in got["top"]]
        lines.append("")
    return lines


def _header(report: dict, path: Path) -> list[str]:
    load0, load1 = (" / ".join(f"{x:.2f}" for x in report[k]) for k in ("load_start", "load_end"))
    base = f"; base = {report['base']} (a git worktree, first on PYTHONPATH)" if report.get("base") else ""
    return [f"# End to end: cloud to verified program (`{path.stem}`)", "",
            (f"`{report['command']}`: {report['runs']} run(s) per part and code, medians; "
             f"new = {report['new']}{base}."), "",
            *(["**The new code (the working tree) changed while this ran**: its runs may mix two versions.", ""]
              if report.get("new_changed") else []),
            *([("Warm-up: one unmeasured run of the README example per code first (its numba kernels compiled): "
                + ", ".join(f"{side} {_s(wall)} s" for side, wall in report["warm"].items()) + "."), ""]
              if report.get("warm") else []),
            f"Machine: {report['machine']}. Load average (1 / 5 / 15 min): {load0} at the start, {load1} at the end.",
            "", ("Targets (the issue, two cores): whole 50k-point job ≤ 120 s, fit ≤ 20 s, plan ≤ 30 s, "
                 f"verify ≤ 15 s; README example ≤ 30 s; peak RSS ≤ {RSS_TARGET_1M_MB} MB at 1M points."), "",
            MEASURES, ""]


def _part_section(part: str, result: dict) -> list[str]:
    if "skipped" in result:
        return [f"## {part}", "", f"Skipped: {result['skipped']}.", ""]
    sets = f", `--set {' --set '.join(result['sets'])}`" if result["sets"] else ", default parameters"
    if result.get("new_sets"):
        sets += f"; the new code's runs also `--set {' --set '.join(result['new_sets'])}`"
    text = [f"## {part}", "", f"Input: `{result['input']}`{sets}.", "", *part_table(part, result), ""]
    if "programs" in result:
        text += [f"Programs (`program*.nc`), base against new: **{result['programs']}**.", ""]
    text += outcome_lines(result)
    if not all(r["stage_peaks_reset"] for side in result["runs"].values() for r in side):
        text += ["The peak could not be reset here: a stage's peak MB is the run's peak so far.", ""]
    failures = _failures(result)
    return text + failures + ([""] if failures else [])


def outcome_lines(result: dict) -> list[str]:
    """One line per code: what its runs made (`read_outcome`), run by run."""
    def one(o: dict) -> str:
        recall = "–" if o.get("crease_recall") is None else f"{o['crease_recall']:.3f}"
        over = "–" if o.get("patches") is None else f"{o['over_tolerance']} of {o['patches']}"
        fin = o.get("finished_of_reachable")
        verdict = {True: "passed", False: "not passed", None: "–"}[o.get("verify_passed")]
        return (f"layout crease recall {recall}, surfaces over tolerance {over}, verify {verdict}"
                + ("" if fin is None else f" ({100 * fin:.2f} % of the reachable part finished)"))

    lines = [f"- {side}: " + "; ".join(one(r["outcome"]) for r in runs)
             for side, runs in result["runs"].items() if runs and all("outcome" in r for r in runs)]
    return ["What the runs made, run by run:", "", *lines, ""] if lines else []


def write_report(report: dict, path: Path) -> None:
    text = _header(report, path)
    for part, result in report["parts"].items():
        text += _part_section(part, result)
    if "scaling" in report:
        text += ["## Scaling (Fandisk ×10 clouds, new code, one run each)", "",
                 f"Target: peak RSS ≤ {RSS_TARGET_1M_MB} MB at 1M points.", "", *scaling_table(report["scaling"]), ""]
    profiled = {p: r["profiled"] for p, r in report["parts"].items() if "profiled" in r}
    if profiled:
        text += ["## Profiles (new code, one extra run per part)", "", PROFILE_NOTE, ""]
        for part, run in profiled.items():
            text += profile_tables(part, run)
    path.write_text("\n".join(text).rstrip() + "\n")


MEASURES = ("Seconds: what each stage reports (`done in`); for a skipped or failed stage, the time since the previous "
            "stage line. `outside stages`: interpreter start, imports and writing params, the wall time less the "
            "stages. Peak MB per stage: the `cloud2cnc run` process's own VmHWM when the stage's line arrives, "
            "reset after each line (`/proc/PID/clear_refs` 5), so each stage's own peak (not its helper processes'). "
            "The total's: the largest of the stages' peaks and the run's `ru_maxrss` from `wait4` (what "
            "`/usr/bin/time -f %M` prints: the larger of the process's peak since the last reset and that of the "
            "helpers it waited for, fit's forked workers and QuadriFlow's child); one process at a time, never a "
            "sum (forked workers share their parent's pages). ✓ / ✗: the new median against the target.")
PROFILE_NOTE = (f"`py-spy record --subprocesses -r {PROFILE_RATE} -f raw`: samples of the run and of every process "
                "it starts (fit's forked workers, QuadriFlow's child); idle samples left out, so a process waiting on "
                "others shows little, and threads outside Python (numba's, BLAS's) are not seen. A sample belongs to "
                "the stage whose `run_<stage>` frame (worker/stages/) is in its stack (a forked worker's stack keeps "
                "its parent's); `(helper processes)`: processes started anew, without such a frame. Inclusive: share "
                "of the stage's samples with the function in the stack below that frame; self: share with it "
                "innermost (C extensions count as their Python caller). Py-spy slows the run a little.")


# --- main ------------------------------------------------------------------------------------------------

def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="bench/e2e.py", description=__doc__.splitlines()[0])
    parser.add_argument("parts", nargs="*", metavar="part", help=f"of {', '.join(PARTS)}")
    parser.add_argument("--runs", type=int, default=3, help="runs per part and code (median)")
    parser.add_argument("--base", metavar="REV", help="also run git revision REV, interleaved")
    parser.add_argument("--profile", action="store_true", help="one more run of the new code under py-spy")
    parser.add_argument("--scaling", action="store_true", help="Fandisk clouds of 50k, 200k, 1M points")
    parser.add_argument("--scaling-points", default=",".join(map(str, SCALING_POINTS)),
                        help="the clouds' sizes for --scaling, comma-separated")
    parser.add_argument("--scaling-h", default=",".join(map(str, SCALING_H)),
                        help="the scallop heights (mm) for --scaling, comma-separated")
    parser.add_argument("--warm", action="store_true",
                        help="first run the README example once per code, unmeasured: a fresh checkout compiles "
                             "its numba kernels on its first run")
    parser.add_argument("--out-name", default="e2e", help="bench/results/NAME.md and .json")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a parameter of the new code's runs only (with --base: the same code, say, against "
                             "its defaults)")
    args = parser.parse_args(argv)
    unknown = [p for p in args.parts if p not in PARTS]
    if unknown:
        parser.error(f"unknown part(s) {', '.join(unknown)}; parts: {', '.join(PARTS)}")
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    if args.profile and shutil.which("py-spy") is None:
        parser.error("--profile needs py-spy on PATH")
    if not args.parts and not args.scaling:
        args.parts = list(PARTS)
    try:
        args.scaling_points = [int(x) for x in args.scaling_points.split(",")]
        args.scaling_h = [float(x) for x in args.scaling_h.split(",")]
    except ValueError as exc:
        parser.error(f"--scaling-points and --scaling-h take comma-separated numbers ({exc})")
    return args


def save(report: dict, name: str) -> None:
    """Write the report so far (after each part: a long run that stops keeps what it measured)."""
    report["load_end"] = os.getloadavg()
    if code_fingerprint() != report["fingerprint"] and not report.get("new_changed"):
        report["new_changed"] = True
        log("e2e: the new code (working tree) changed during this run; its figures may mix two versions")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(report, indent=1, default=str))
    write_report(report, RESULTS / f"{name}.md")


def codes_to_run(base: str | None, work: Path, report: dict) -> tuple[dict[str, dict], Path | None]:
    """The environments of the base (a worktree of `base`) and the new code, each checked to import its own."""
    codes, tree = {}, None
    if base:
        tree, sha = add_worktree(base)
        report["base"] = f"{base} ({sha[:10]})"
        codes["base"] = {"env": code_env(tree, work), "cwd": work / "cwd", "root": tree}
    codes["new"] = {"env": code_env(ROOT, work), "cwd": work / "cwd", "root": ROOT}
    for side, code in codes.items():
        check_imports(side, code["root"], code["env"], code["cwd"])
    return codes, tree


def warm(codes: dict[str, dict], work: Path, report: dict) -> None:
    """Run the README example once per code, unmeasured, so that no measured run compiles the kernels."""
    path, sets = prepare_input("example", work)
    report["warm"] = {}
    for side, code in codes.items():
        run = timed_run(cli_args(path, sets), code, work / f"warm-{side}", f"warm-up {side}")
        report["warm"][side] = run.get("wall_s")


def main(argv: list[str]) -> None:
    args = parse_args(argv)
    report = {"command": "python bench/e2e.py " + shlex.join(argv), "runs": args.runs, "new": describe_new(),
              "fingerprint": code_fingerprint(),
              "machine": describe_machine(), "load_start": os.getloadavg(), "parts": {}}
    work = Path(tempfile.mkdtemp(prefix="e2e-"))
    (work / "cwd").mkdir()  # an empty folder: `python -c` puts the cwd first on the path
    tree = None
    try:
        codes, tree = codes_to_run(args.base, work, report)
        if args.warm:
            warm(codes, work, report)
        for part in args.parts:
            report["parts"][part] = run_part(part, codes, args.runs, work, args.profile, tuple(args.set))
            save(report, args.out_name)
        if args.scaling:
            report["scaling"] = run_scaling(codes["new"], work, args.scaling_points, args.scaling_h)
            save(report, args.out_name)
    finally:
        if tree is not None:
            remove_worktree(tree)
        shutil.rmtree(work, ignore_errors=True)
    log(f"wrote {RESULTS / args.out_name}.md and .json")


if __name__ == "__main__":
    main(sys.argv[1:])
