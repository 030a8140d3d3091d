"""Shared fixtures: settings on a fresh data folder, the app through TestClient, real worker processes.

`backend` runs a test twice: the embedded default (filesystem:// broker, SQLite)
and the scale-out one (Redis, PostgreSQL), which skips with a reason when
those servers are not reachable on 127.0.0.1.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
PG_ADMIN = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


@dataclass
class Backend:
    name: str
    env: dict[str, str]
    cleanup: list = field(default_factory=list)

    def settings(self):
        from core.config import Settings

        return Settings(**{k: v for k, v in self.env.items()})


def _postgres_database() -> tuple[str, callable]:
    from sqlalchemy import create_engine, text

    name = "c2c_" + uuid.uuid4().hex[:12]
    admin = create_engine(PG_ADMIN, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))

    def drop() -> None:
        from core.db import get_engine

        url = PG_ADMIN.rsplit("/", 1)[0] + "/" + name
        get_engine(url).dispose()
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()

    return PG_ADMIN.rsplit("/", 1)[0] + "/" + name, drop


@pytest.fixture(params=["embedded", "scaled"])
def backend(request, tmp_path: Path) -> Iterator[Backend]:
    env = {
        "CLOUD2CNC_DATA_DIR": str(tmp_path / "data"),
        "CLOUD2CNC_STAGE_LEASE_S": "2",
        "CLOUD2CNC_RECONCILE_INTERVAL_S": "0.5",
        "CLOUD2CNC_STAGE_PLUGINS": "tests.plugins.dwell",
        "CLOUD2CNC_PIPELINE": "ingest,dwell",
        "CLOUD2CNC_MIN_POINTS": "10",
    }
    b = Backend(request.param, env)
    if request.param == "scaled":
        if not (_port_open(6379) and _port_open(5432)):
            pytest.skip("scale-out backend needs Redis on 127.0.0.1:6379 and PostgreSQL on 127.0.0.1:5432")
        import redis

        db = 1 + uuid.uuid4().int % 15
        client = redis.Redis(host="127.0.0.1", port=6379, db=db)
        client.flushdb()
        url, drop = _postgres_database()
        env.update(CELERY_BROKER_URL=f"redis://127.0.0.1:6379/{db}", DATABASE_URL=url)
        b.cleanup += [drop, client.flushdb]
    yield b
    for fn in b.cleanup:
        fn()


@pytest.fixture
def embedded(tmp_path: Path) -> Backend:
    return Backend("embedded", {
        "CLOUD2CNC_DATA_DIR": str(tmp_path / "data"),
        "CLOUD2CNC_STAGE_PLUGINS": "tests.plugins.dwell",
        "CLOUD2CNC_PIPELINE": "ingest,dwell",
        "CLOUD2CNC_MIN_POINTS": "10",
    })


class Worker:
    """`cloud2cnc worker` as a child process in its own process group."""

    def __init__(self, env: dict[str, str], log: Path) -> None:
        full = dict(os.environ, **env, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
        self.log = log
        self.proc = subprocess.Popen([sys.executable, "-m", "cloud2cnc.cli", "worker", "--log-level", "info"],
                                     cwd=ROOT, env=full, stdout=open(log, "ab"), stderr=subprocess.STDOUT,
                                     start_new_session=True)

    def kill(self) -> None:
        """SIGKILL the whole worker (parent and pool children): a machine that died."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.kill()


@pytest.fixture
def start_worker(tmp_path: Path):
    workers: list[Worker] = []

    def start(backend: Backend, **extra_env: str) -> Worker:
        w = Worker({**backend.env, **extra_env}, tmp_path / f"worker{len(workers)}.log")
        workers.append(w)
        return w

    yield start
    for w in workers:
        w.stop()


@pytest.fixture
def client_for():
    """A TestClient over create_app(settings), with the lifespan (reconciler) running."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    clients = []

    def make(backend: Backend, **kw):
        c = TestClient(create_app(backend.settings(), **kw))
        c.__enter__()
        clients.append(c)
        return c

    yield make
    for c in clients:
        c.__exit__(None, None, None)


def wait_for(client, job_id: str, statuses: tuple[str, ...], timeout_s: float = 60.0,
              predicate=None) -> dict:
    deadline = time.monotonic() + timeout_s
    body = {}
    while time.monotonic() < deadline:
        body = client.get(f"/v1/jobs/{job_id}").json()
        if body.get("status") in statuses and (predicate is None or predicate(body)):
            return body
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not reach {statuses} in {timeout_s} s: {body}")


def xyz_bytes(n: int = 500, seed: int = 0) -> bytes:
    """A sphere sampled with n points, as XYZ text with normals (6 columns)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    rows = np.hstack([10 * p, p])
    return "\n".join(" ".join(f"{v:.9g}" for v in row) for row in rows).encode() + b"\n"
