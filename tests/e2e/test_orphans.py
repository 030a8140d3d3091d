"""No orphans: the embedded worker, its pool and its stage's processes end when `serve` dies hard.

With real processes: `serve` is killed with SIGKILL while a stage works in forked children (the
`forking` test stage, as `fit` and `plan` do); every process under it must be gone within 5 s. A
`serve` started again on the same data directory re-queues the stage, which completes exactly once.
The two guards of `worker.lifeline` are each checked alone as well, on a bare process tree.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import psutil
import pytest

from tests.conftest import ROOT, xyz_bytes

pytestmark = pytest.mark.slow

GONE_WITHIN_S = 5.0  # the bound; either guard acts well within a second


def _alive(procs: list[psutil.Process]) -> list[psutil.Process]:
    """The processes still running; a zombie (dead, not yet reaped by its new parent) counts as gone."""
    out = []
    for p in procs:
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


def _wait_gone(procs: list[psutil.Process], timeout_s: float) -> list[psutil.Process]:
    deadline = time.monotonic() + timeout_s
    while (alive := _alive(procs)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return alive


def _kill_all(procs: list[psutil.Process]) -> None:
    for p in _alive(procs):
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass


# --------------------------------------------------------------------------- the guards, one at a time

_WORKER = """
import os, sys, time
from worker.lifeline import follow_parent
parent, poll_s, pidfile = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
follow_parent(parent, poll_s=poll_s)
child = os.fork()
if child == 0:  # a stage's forked child: plain C sleep, no Python handler of its own
    os.execvp("sleep", ["sleep", "600"])
with open(pidfile + ".tmp", "w") as fh:
    fh.write(f"{os.getpid()} {child}")
os.replace(pidfile + ".tmp", pidfile)
while True:
    time.sleep(1)
"""

_SERVE = """
import os, subprocess, sys, time
from worker.lifeline import prepare_embedded_worker
guard, poll_s, pidfile = sys.argv[1], sys.argv[2], sys.argv[3]
preexec = prepare_embedded_worker(os.getpid(), nice=0) if guard == "signal" else None
subprocess.Popen([sys.executable, "-c", sys.argv[4], str(os.getpid()), poll_s, pidfile],
                 start_new_session=True, preexec_fn=preexec)
time.sleep(600)
"""


@pytest.mark.parametrize("guard,poll_s", [("signal", 3600.0), ("watch", 0.2)])
def test_each_guard_alone_ends_the_worker_and_its_children(tmp_path, guard, poll_s):
    # "signal": the parent-death signal only (the watch would look again in an hour); "watch": no signal
    # asked for, only the watching thread.
    pidfile = tmp_path / "pids"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    serve = subprocess.Popen([sys.executable, "-c", _SERVE, guard, str(poll_s), str(pidfile), _WORKER],
                             cwd=ROOT, env=env)
    procs: list[psutil.Process] = []
    try:
        deadline = time.monotonic() + 60
        while not pidfile.exists() and time.monotonic() < deadline and serve.poll() is None:
            time.sleep(0.05)
        assert pidfile.exists(), "the worker did not start"
        worker_pid, child_pid = map(int, pidfile.read_text().split())
        procs = [psutil.Process(worker_pid), psutil.Process(child_pid)]
        assert procs[0].ppid() == serve.pid and os.getpgid(child_pid) == worker_pid
        serve.kill()
        serve.wait(timeout=10)
        alive = _wait_gone(procs, GONE_WITHIN_S)
        assert not alive, f"left running after their parent was killed ({guard} guard): {alive}"
    finally:
        serve.kill()
        serve.wait(timeout=10)
        _kill_all(procs)


def test_a_parent_pid_that_is_not_the_parent_is_refused():
    r = subprocess.run([sys.executable, "-m", "cloud2cnc.cli", "worker", "--parent-pid", "1"], check=False,
                       cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "is not this process's parent" in r.stderr


# --------------------------------------------------------------------------- serve killed mid-stage

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(data_dir: Path, log: Path, env_extra: dict[str, str]) -> tuple[subprocess.Popen, str]:
    """`cloud2cnc serve` in its embedded default, its output (and its worker's) to `log`."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items()
           if k not in ("DATABASE_URL", "CELERY_BROKER_URL", "CLOUD2CNC_API_KEY", "CLOUD2CNC_WORKER_NICE")}
    env.update(env_extra, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    with open(log, "ab") as out:
        proc = subprocess.Popen([sys.executable, "-m", "cloud2cnc.cli", "serve", "--port", str(port),
                                 "--data-dir", str(data_dir), "--log-level", "warning"], cwd=ROOT, env=env,
                                stdout=out, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if httpx.get(f"{base}/readyz").status_code == 200:
                return proc, base
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise AssertionError(f"serve did not get ready:\n{log.read_text()[-3000:]}")


def _stage(job: dict, name: str) -> dict:
    return next(s for s in job["stages"] if s["name"] == name)


def test_serve_killed_hard_leaves_no_worker_and_a_restart_finishes_the_stage_once(tmp_path):
    runs = tmp_path / "runs.log"
    env = {
        "CLOUD2CNC_STAGE_PLUGINS": "tests.plugins.forking",
        "CLOUD2CNC_PIPELINE": "ingest,forking",
        "CLOUD2CNC_MIN_POINTS": "10",
        "CLOUD2CNC_TEST_DWELL_S": "4",
        "CLOUD2CNC_TEST_DWELL_LOG": str(runs),
        "CLOUD2CNC_STAGE_LEASE_S": "2",
        "CLOUD2CNC_RECONCILE_INTERVAL_S": "0.5",
    }
    data, log = tmp_path / "data", tmp_path / "serve.log"
    serve, base = _serve(data, log, env)
    procs: list[psutil.Process] = []
    try:
        r = httpx.post(f"{base}/v1/jobs", files={"file": ("part.xyz", xyz_bytes(200), "text/plain")})
        assert r.status_code == 202, r.text
        path = r.headers["location"]
        # The stage is running once the worker's pool child has forked both of its children:
        # serve > worker > pool child > 2 stage children.
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            job = httpx.get(base + path).json()
            procs = psutil.Process(serve.pid).children(recursive=True)
            if _stage(job, "forking")["status"] == "running" and len(procs) >= 4:
                break
            assert job["status"] not in ("succeeded", "failed", "canceled"), job
            time.sleep(0.1)
        else:
            raise AssertionError(f"the stage never ran in forked children: {job}, {procs}")
        worker = psutil.Process(serve.pid).children()
        assert len(worker) == 1 and all(p.pid != serve.pid for p in procs)
        # The embedded worker and everything under it run at a lower priority than the API.
        assert {p.nice() for p in procs} == {min(19, psutil.Process(serve.pid).nice() + 10)}

        serve.send_signal(signal.SIGKILL)
        serve.wait(timeout=10)
        alive = _wait_gone(procs, GONE_WITHIN_S)
        assert not alive, f"processes of the killed serve's worker still run: {alive}"
        assert not runs.exists() or runs.read_text() == "", "the stage completed under the killed serve"

        serve, base = _serve(data, log, env)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            job = httpx.get(base + path).json()
            if job["status"] in ("succeeded", "failed", "canceled"):
                break
            time.sleep(0.2)
        assert job["status"] == "succeeded", (job, log.read_text()[-3000:])
        stage = _stage(job, "forking")
        # Started twice (the killed run, then the re-queued one), finished once.
        assert stage["status"] == "succeeded" and stage["attempts"] == 2, stage
        assert _stage(job, "ingest")["attempts"] == 1
        assert [line.split()[0] for line in runs.read_text().splitlines()] == [job["id"]]
        # The killed run's scratch folder went when the new worker started; the finished run removed its own.
        assert list((data / "work").iterdir()) == []
        procs = psutil.Process(serve.pid).children(recursive=True)
    finally:
        serve.send_signal(signal.SIGTERM)
        try:
            serve.wait(timeout=40)
        except subprocess.TimeoutExpired:
            serve.kill()
        alive = _wait_gone(procs, 20)
        _kill_all(procs)
    assert not alive, f"worker processes left running after SIGTERM: {alive}"
