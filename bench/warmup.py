"""Benchmark of the first job after a fresh install: the numba kernels compiled in it, or before it.

Run from the repository root:

    python bench/warmup.py [--runs N]     # about 7 minutes a run on 2 cores; writes bench/results/warmup.md

Each measurement starts from an empty numba cache of its own (`NUMBA_CACHE_DIR` in a temporary folder): what a
fresh install, a new container or a new version of the code has. The job is the README example
(`examples/dome_block.xyz` with its documented parameters), run as a user runs it:

1. `cloud2cnc run` on an empty cache (the kernels compile in the job);
2. `cloud2cnc warm-up` on an empty cache, `cloud2cnc warm-up` again (the stamp is there), then `cloud2cnc run`;
3. `cloud2cnc serve` (API and embedded worker) on an empty cache and a new data folder, the example submitted
   as soon as the API answers: seconds from serve's start to the job's end, with the worker's warm-up
   (the default) and without it (`CLOUD2CNC_WARM_UP=0`);
4. the same with the warm-up, the example submitted once the worker's warm-up line is in its log: seconds
   from the submission to the job's end (a user who uploads a minute after starting the service).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine_info import describe_machine  # bench/ is on the path when a script runs

from service import (  # bench/service.py: the served API driven over HTTP
    FINAL,
    Server,
    _submit,
    _wait_job,
)

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "dome_block.xyz"
EXAMPLE_SETS = ("tool.radius_mm=2", "reconstruct.max_faces=20000", "fit.max_refinements=0")
EXAMPLE_PARAMS = {"tool": {"radius_mm": 2}, "reconstruct": {"max_faces": 20000}, "fit": {"max_refinements": 0}}
JOB_TIMEOUT_S = 900.0


def _cli(cache: Path, *args: str) -> tuple[float, subprocess.CompletedProcess]:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "cloud2cnc.cli", *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=JOB_TIMEOUT_S, check=False)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"cloud2cnc {' '.join(args)} exited with {done.returncode}:\n{done.stderr[-3000:]}")
    return seconds, done


def _run_example(cache: Path, out: Path) -> float:
    sets = [a for s in EXAMPLE_SETS for a in ("--set", s)]
    return _cli(cache, "run", str(EXAMPLE), "--out", str(out), *sets)[0]


def measure_cli(tmp: Path) -> dict[str, float]:
    """Steps 1 and 2 of the module's docstring, seconds."""
    cold = _run_example(tmp / "cache-cold", tmp / "job-cold")
    warm_up, _ = _cli(tmp / "cache-warm", "warm-up")
    again, _ = _cli(tmp / "cache-warm", "warm-up")
    after = _run_example(tmp / "cache-warm", tmp / "job-after")
    return {"run, empty cache": cold, "warm-up, empty cache": warm_up, "warm-up, stamp there": again,
            "run after the warm-up": after}


def measure_serve(tmp: Path, name: str, *, warm_up: bool, wait_for_warm_up: bool) -> tuple[float, float]:
    """Step 3 or 4: (seconds from serve's start to the job's end, seconds from the submission to its end)."""
    env = {"NUMBA_CACHE_DIR": str(tmp / f"cache-{name}"), "CLOUD2CNC_WARM_UP": "1" if warm_up else "0"}
    t0 = time.perf_counter()
    server = Server(tmp, name, env, worker=True)
    try:
        server.wait_ready()
        if wait_for_warm_up:
            deadline = time.monotonic() + JOB_TIMEOUT_S
            while "compiled the kernels" not in server.log_tail(100_000):
                if time.monotonic() > deadline or server.proc.poll() is not None:
                    raise RuntimeError(f"no warm-up line in the worker's log:\n{server.log_tail()}")
                time.sleep(0.2)
        submitted = time.perf_counter()
        job_id = _submit(server, EXAMPLE.name, EXAMPLE.read_bytes(), EXAMPLE_PARAMS)
        job = _wait_job(server, job_id, lambda j: j["status"] in FINAL, JOB_TIMEOUT_S)
        ended = time.perf_counter()
        if job["status"] != "succeeded":
            raise RuntimeError(f"the example ended {job['status']}:\n{json.dumps(job)[:2000]}\n{server.log_tail()}")
    finally:
        server.stop()
    return ended - t0, ended - submitted


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = parser.parse_args()
    machine = describe_machine()
    rows: dict[str, list[float]] = {}
    for run in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="cloud2cnc-bench-warmup-") as name:
            tmp = Path(name)
            for key, seconds in measure_cli(tmp).items():
                rows.setdefault(key, []).append(seconds)
            for key, (warm_up, wait) in {"serve, warm-up on, submitted at once": (True, False),
                                         "serve, warm-up off, submitted at once": (False, False),
                                         "serve, warm-up on, submitted after it": (True, True)}.items():
                start_to_end, submit_to_end = measure_serve(tmp, key.split(",")[1].strip().replace(" ", "-")
                                                            + str(int(wait)), warm_up=warm_up,
                                                            wait_for_warm_up=wait)
                rows.setdefault(f"{key}: start to end", []).append(start_to_end)
                rows.setdefault(f"{key}: submission to end", []).append(submit_to_end)
        print(f"run {run + 1}: " + ", ".join(f"{k} {v[-1]:.1f} s" for k, v in rows.items()), flush=True)
    write_table(args.out / "warmup.md", rows, machine=machine, runs=args.runs)
    (args.out / "warmup.json").write_text(json.dumps({"machine": machine, "runs": args.runs, "seconds": rows},
                                                     indent=1) + "\n")
    return 0


def write_table(path: Path, rows: dict[str, list[float]], *, machine: str, runs: int) -> None:
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                            check=False).stdout.strip()
    cold = statistics.median(rows["run, empty cache"])
    lines = [
        "# The first job after a fresh install: kernels compiled in it or before it",
        "",
        (f"`python bench/warmup.py --runs {runs}` on {dt.date.today()}, commit {commit} (with the working tree's "
        f"changes, if any). Machine: {machine}."),
        "",
        ("Each row starts from an empty numba cache of its own. The job is the README example (`cloud2cnc run "
        "examples/dome_block.xyz` with its documented parameters, or the same file and parameters submitted to "
        "`cloud2cnc serve`). Seconds, median of the runs (each run's figure in brackets); ratio: against the "
        "first row, `cloud2cnc run` on an empty cache, measured in the same run."),
        "",
        "| what | seconds | ratio to the first row |",
        "|---|---:|---:|",
    ]
    for key, values in rows.items():
        med = statistics.median(values)
        each = ", ".join(f"{v:.1f}" for v in values)
        lines.append(f"| {key} | {med:.1f} ({each}) | {med / cold:.2f} |")
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
