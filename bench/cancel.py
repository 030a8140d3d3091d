"""Does cancel bite? How long each stage of a real job runs between two cancel checks, and how long a
cancel takes to stop it.

The job is the README example (`examples/dome_block.xyz` with its documented parameters) unless a part is
given. First the whole job runs once (`run_local`, as `cloud2cnc run` does) so that every stage has its
inputs. Then each stage runs again, alone, twice, in this process, with the stage's settings as a worker
gives them:
1. with a `check_cancel` that records when it was called and from where: the longest gap between two
   calls (start and end of the stage count as calls) bounds how late a cancel is seen, and the two call
   sites around it say where the slow code is;
2. with a `check_cancel` that starts answering "canceled" half-way through the stage's measured time and
   raises `StageCanceled` from then on (as the worker's does, which polls the database every 0.5 s on top):
   the seconds from the request to the stage's return is the cancel latency. Stages that fork
   (`cam.map_forked`) kill their children on the way out; the bench checks no child is left.
Target (issue 38): every stage stops within 5 s of a cancel.

    python bench/cancel.py [input] [--set key=value ...] [--out-name NAME]
        writes bench/results/NAME.md (NAME: cancel). Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import psutil
from machine_info import describe_machine  # bench/ is on the path when a script runs

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
RESULTS = ROOT / "bench" / "results"
EXAMPLE = ROOT / "examples" / "dome_block.xyz"
EXAMPLE_SETS = ("tool.radius_mm=2", "reconstruct.max_faces=20000", "fit.max_refinements=0")
TARGET_S = 5.0
WORKER_POLL_S = 0.5  # worker/runner.py reads the cancel flag from the database at most this often


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


class Recorder:
    """A `check_cancel` that notes each call's time and call site; from `cancel_at` on it raises."""

    def __init__(self, cancel_at: float | None = None) -> None:
        self.t0 = time.perf_counter()
        self.calls: list[tuple[float, str]] = [(0.0, "stage start")]
        self.cancel_at = cancel_at

    def __call__(self) -> None:
        from worker.context import StageCanceled

        now = time.perf_counter() - self.t0
        frame = sys._getframe(1)
        self.calls.append((now, f"{Path(frame.f_code.co_filename).relative_to(ROOT)}:{frame.f_lineno}"
                                 f" ({frame.f_code.co_name})"))
        if self.cancel_at is not None and now >= self.cancel_at:
            raise StageCanceled("canceled by the bench")

    def longest_gap(self, end: float) -> tuple[float, str, str]:
        calls = self.calls + [(end, "stage end")]
        gaps = [(b[0] - a[0], a[1], b[1]) for a, b in zip(calls, calls[1:])]
        return max(gaps)


def run_stage(spec, job: Path, params, settings, check_cancel) -> tuple[str, float]:
    """Run one stage on the artifacts in `job` as `cloud2cnc run` does; its status and seconds."""
    from worker.local import run_stage as run_one

    report = run_one(spec, job / "input", job, params=params, settings=settings, check_cancel=check_cancel)
    if report.status == "failed":
        log(f"{spec.name} failed: {report.error}")
    return report.status, report.seconds


def leftover_children() -> int:
    return len(psutil.Process().children(recursive=True))


def measure(job: Path, params, settings) -> list[dict]:
    from core.stages import load_stages

    rows = []
    for spec in load_stages(settings.stage_plugins, settings.pipeline):
        rec = Recorder()
        status, seconds = run_stage(spec, job, params, settings, rec)
        if status != "succeeded":
            rows.append({"stage": spec.name, "status": status, "seconds": seconds})
            log(f"{spec.name}: {status}, not measured")
            continue
        gap, before, after = rec.longest_gap(seconds)
        cancel = Recorder(cancel_at=seconds / 2)
        cstatus, cseconds = run_stage(spec, job, params, settings, cancel)
        latency = cseconds - seconds / 2 + WORKER_POLL_S if cstatus == "canceled" else None
        rows.append({"stage": spec.name, "status": status, "seconds": seconds, "checks": len(rec.calls) - 1,
                     "gap": gap, "before": before, "after": after, "cancel_status": cstatus, "latency": latency,
                     "children": leftover_children()})
        log(f"{spec.name}: {seconds:.1f} s, {len(rec.calls) - 1} checks, longest gap {gap:.2f} s "
            f"({before} -> {after}); cancel at {seconds / 2:.1f} s: {cstatus}, latency "
            f"{'-' if latency is None else f'{latency:.2f} s'}")
    return rows


def write_report(rows: list[dict], args, machine: str, path: Path) -> None:
    lines = [
        "# Cancel latency per stage",
        "",
        f"`python bench/cancel.py {' '.join(sys.argv[1:])}` on {machine}.",
        f"Input: `{args.input.relative_to(ROOT) if args.input.is_relative_to(ROOT) else args.input}`"
        f" with {', '.join(f'`{s}`' for s in args.set) or 'default parameters'}.",
        "Longest gap: the most seconds the stage ran without checking for a cancel (between the two call sites"
        " named). Latency: seconds from a cancel requested half-way through the stage to the stage's return,"
        f" plus the worker's {WORKER_POLL_S} s database poll. Target: ≤ {TARGET_S:.0f} s.",
        "",
        "| stage | seconds | checks | longest gap (s) | between | and | canceled half-way | latency (s) | ok |",
        "|---|---:|---:|---:|---|---|---|---:|---|",
    ]
    for r in rows:
        if "gap" not in r:
            lines.append(f"| {r['stage']} | {r['seconds']:.1f} | | | {r['status']} | | | | |")
            continue
        ok = r["latency"] is not None and r["latency"] <= TARGET_S and r["children"] == 0
        lat = "—" if r["latency"] is None else f"{r['latency']:.2f}"
        lines.append(f"| {r['stage']} | {r['seconds']:.1f} | {r['checks']} | {r['gap']:.2f} | `{r['before']}` |"
                     f" `{r['after']}` | {r['cancel_status']} | {lat} | {'yes' if ok else '**no**'} |")
    path.write_text("\n".join(lines) + "\n")
    log(f"wrote {path}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", nargs="?", type=Path, default=EXAMPLE)
    parser.add_argument("--set", action="append", default=None, help="a job parameter, key=value")
    parser.add_argument("--out-name", default="cancel")
    args = parser.parse_args()
    args.input = args.input.resolve()
    if args.set is None:
        args.set = list(EXAMPLE_SETS) if args.input == EXAMPLE else []
    from core.config import Settings, set_thread_limits

    settings = Settings(data_dir=Path(tempfile.mkdtemp(prefix="cancel-data-")))
    set_thread_limits(settings)
    from core.params import JobParams, merge_params, parse_assignment
    from worker.local import run_local

    params: dict = {}
    for item in args.set:
        params = merge_params(params, parse_assignment(item))
    job = Path(tempfile.mkdtemp(prefix="cancel-job-"))
    try:
        shutil.copy(args.input, job / "input")
        log(f"whole job once in {job}")
        reports = run_local(job / "input", job, params=params, settings=settings)
        if not reports or reports[-1].status == "failed":
            log(f"the job failed: {reports[-1].error if reports else 'no stage ran'}")
            return 1
        rows = measure(job, JobParams.model_validate(params), settings)
    finally:
        shutil.rmtree(job, ignore_errors=True)
        shutil.rmtree(settings.data_dir, ignore_errors=True)
    write_report(rows, args, describe_machine(), RESULTS / f"{args.out_name}.md")
    return 0 if all("gap" not in r or (r["latency"] or 1e9) <= TARGET_S for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
