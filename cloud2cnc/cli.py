"""The `cloud2cnc` command: serve, worker, run, warm-up, openapi.

Each command imports what it needs when it runs, so `serve` does not load the
geometry stack and `run` does not load the web stack.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
from pathlib import Path


def _settings(data_dir: str | None = None):
    from core.config import Settings, get_settings

    if data_dir:
        os.environ["CLOUD2CNC_DATA_DIR"] = str(Path(data_dir).resolve())
        get_settings.cache_clear()
    settings: Settings = get_settings()
    return settings


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from service.app import create_app

    settings = _settings(args.data_dir)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, CLOUD2CNC_DATA_DIR=str(settings.data_dir.resolve()))
    worker = None
    if not args.no_worker:
        from worker.lifeline import prepare_embedded_worker

        # A real Celery worker in its own process and session (a terminal's Ctrl-C reaches it only through us,
        # and we stop it warmly), at a lower CPU priority than the API, bound to our life: a parent-death
        # signal and its own watch end it with all its processes if we die hard (worker/lifeline.py). Started
        # from this main thread, which lives as long as we do: the parent-death signal follows the thread.
        worker = subprocess.Popen(
            [sys.executable, "-m", "cloud2cnc.cli", "worker", "--concurrency", str(args.concurrency),
             "--parent-pid", str(os.getpid())],
            env=env, start_new_session=True,
            # No thread runs here yet (uvicorn starts below), so a preexec_fn is safe.
            preexec_fn=prepare_embedded_worker(os.getpid(), nice=settings.worker_nice))  # noqa: PLW1509
    url = f"http://{'127.0.0.1' if args.host in ('0.0.0.0', '::') else args.host}:{args.port}/"
    print(f"cloud2cnc: dashboard and API at {url} (API docs at {url}docs); data in {settings.data_dir.resolve()}",
          flush=True)
    # uvicorn shuts down on SIGTERM and then raises it again under the handler it found: with Python's
    # default one that would end this process before `finally` stops the worker. Exit cleanly instead.
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(0))
    try:
        uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level=args.log_level)
    finally:
        signal.signal(signal.SIGTERM, previous)
        if worker is not None:
            _stop(worker)
    return 0


def _stop(proc: subprocess.Popen, grace_s: float = 15.0) -> None:
    """Warm shutdown (SIGTERM: finish or hand back the current stage), then cold, then kill them all."""
    if proc.poll() is not None:
        return
    for sig, wait in ((signal.SIGTERM, grace_s), (signal.SIGQUIT, 5.0), (signal.SIGKILL, 5.0)):
        try:
            # Celery's main process stops its own pool; only the last resort reaches the whole group.
            (os.killpg if sig == signal.SIGKILL else os.kill)(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait)
            return
        except subprocess.TimeoutExpired:
            continue


def cmd_worker(args: argparse.Namespace) -> int:
    if args.parent_pid is not None:
        from worker.lifeline import follow_parent

        if os.getppid() != args.parent_pid:
            print(f"cloud2cnc worker: --parent-pid {args.parent_pid} is not this process's parent "
                  f"({os.getppid()})", file=sys.stderr)
            return 2
        follow_parent(args.parent_pid)  # before Celery forks its pool, so the pool is in our group
    os.environ["CLOUD2CNC_CONCURRENCY"] = str(args.concurrency)
    settings = _settings(args.data_dir)
    if settings.warm_up:
        from core.config import set_thread_limits
        from worker.warmup import run_warm_up

        set_thread_limits(settings)  # inherited by the warm-up's process, as by the pool's
        run_warm_up()
    from worker.celery_app import app

    argv = ["worker", "--loglevel", args.log_level.upper(), "--concurrency", str(args.concurrency),
            "-Q", "cloud2cnc", "--without-gossip", "--without-mingle"]
    if args.hostname:
        argv += ["--hostname", args.hostname]
    app.worker_main(argv)
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from core.config import set_thread_limits

    set_thread_limits(_settings())  # as a worker does, before numpy loads
    from core.params import merge_params, parse_assignment
    from worker.local import run_local

    params: dict = {}
    try:
        if args.params:
            params = json.loads(Path(args.params).read_text())
            if not isinstance(params, dict):
                raise ValueError(f"{args.params} must hold a JSON object")
        for item in args.set or []:
            params = merge_params(params, parse_assignment(item))
        reports = run_local(Path(args.input), Path(args.out), params=params, settings=_settings(),
                            until=args.until)
    except (ValueError, OSError) as exc:
        print(f"cloud2cnc run: {exc}", file=sys.stderr)
        return 2
    return 0 if reports and all(r.status in ("succeeded", "skipped") for r in reports) else 1


def cmd_warm_up(args: argparse.Namespace) -> int:
    from core.config import set_thread_limits

    set_thread_limits(_settings())  # as a worker does, before numpy loads
    from worker.warmup import main

    return main(["--force"] if args.force else [])


def cmd_openapi(args: argparse.Namespace) -> int:
    from service.openapi import write_openapi

    path = write_openapi(Path(args.output))
    print(f"wrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cloud2cnc", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("serve", help="the embedded service: API, dashboard and one worker")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--data-dir", help="overrides CLOUD2CNC_DATA_DIR")
    p.add_argument("--concurrency", type=int, default=1, help="worker processes of the embedded worker")
    p.add_argument("--no-worker", action="store_true", help="API only (workers run elsewhere)")
    p.add_argument("--log-level", default="info")
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("worker", help="a Celery worker (broker and database from the environment)")
    p.add_argument("--concurrency", type=int, default=1)
    p.add_argument("--data-dir", help="overrides CLOUD2CNC_DATA_DIR")
    p.add_argument("--hostname", help="Celery node name, e.g. w1@%%h")
    p.add_argument("--parent-pid", type=int,
                   help="end this worker, its pool and its stages' processes when that process (its parent) is "
                        "gone; `serve` passes its own")
    p.add_argument("--log-level", default="info")
    p.set_defaults(func=cmd_worker)

    p = sub.add_parser("run", help="run the pipeline in-process on one file")
    p.add_argument("input")
    p.add_argument("--out", required=True, help="folder for the artifacts")
    p.add_argument("--params", help="JSON file with JobParams")
    p.add_argument("--set", action="append", metavar="GROUP.NAME=VALUE", help="override one parameter")
    p.add_argument("--until", help="last stage to run")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("warm-up", help="compile the geometry kernels now (a worker does it before it takes work)")
    p.add_argument("--force", action="store_true", help="even where this code's kernels are compiled already")
    p.set_defaults(func=cmd_warm_up)

    p = sub.add_parser("openapi", help="write the OpenAPI schema")
    p.add_argument("--output", default="openapi/openapi.json")
    p.set_defaults(func=cmd_openapi)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
