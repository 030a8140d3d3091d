"""`cloud2cnc serve`, the embedded default, as a user starts it: a job runs, Ctrl-C stops both processes."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import httpx
import psutil
import pytest

from tests.conftest import ROOT

pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(tmp_path, **env_extra) -> tuple[subprocess.Popen, int]:
    """`cloud2cnc serve` in its embedded default on a free port, started as a user would."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items()
           if k not in ("DATABASE_URL", "CELERY_BROKER_URL", "CLOUD2CNC_API_KEY", "CLOUD2CNC_STAGE_PLUGINS")}
    env.update(env_extra)
    proc = subprocess.Popen([sys.executable, "-m", "cloud2cnc.cli", "serve", "--port", str(port),
                             "--data-dir", str(tmp_path / "data")], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, port


def _wait_ready(base: str, deadline: float) -> None:
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{base}/readyz").status_code == 200:
                return
        except httpx.TransportError:
            time.sleep(0.2)


def test_serve_runs_a_job_and_stops_cleanly_on_ctrl_c(tmp_path):
    # What is tested here is serve itself (API + worker process, a job through the broker, Ctrl-C); the
    # geometry stages have their own tests, so the job runs ingest alone and the test stays short.
    proc, port = _serve(tmp_path, CLOUD2CNC_PIPELINE="ingest")
    try:
        banner = proc.stdout.readline()
        assert f"http://127.0.0.1:{port}/" in banner
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        _wait_ready(base, deadline)
        with open(ROOT / "examples" / "dome_block.xyz", "rb") as fh:
            r = httpx.post(f"{base}/v1/jobs", files={"file": ("dome_block.xyz", fh)})
        assert r.status_code == 202, r.text
        url = base + r.headers["location"]
        while time.monotonic() < deadline + 60:
            job = httpx.get(url).json()
            if job["status"] in ("succeeded", "failed"):
                break
            time.sleep(0.2)
        assert job["status"] == "succeeded", job
        children = psutil.Process(proc.pid).children(recursive=True)
        assert children, "serve started no worker process"
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=40)
    assert proc.returncode == 0
    gone, alive = psutil.wait_procs(children, timeout=20)
    assert not alive, f"worker processes left running: {alive}"


def test_sigterm_stops_the_worker_too(tmp_path):
    # What docker stop, systemd and kill send. uvicorn re-raises the signal after its own shutdown; with
    # Python's default handler that killed serve before it could stop its worker, which then kept taking
    # jobs with whatever code it had loaded.
    proc, port = _serve(tmp_path)
    try:
        assert f"http://127.0.0.1:{port}/" in proc.stdout.readline()
        deadline = time.monotonic() + 60
        children = []
        while time.monotonic() < deadline and not children:
            children = psutil.Process(proc.pid).children(recursive=True)
            time.sleep(0.2)
        _wait_ready(f"http://127.0.0.1:{port}", deadline)
        children = psutil.Process(proc.pid).children(recursive=True)
        assert children, "serve started no worker process"
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=40)
    gone, alive = psutil.wait_procs(children, timeout=20)
    for p in alive:
        p.kill()
    assert not alive, f"worker processes left running after SIGTERM: {alive}"
