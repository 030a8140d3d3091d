"""Shared fixtures: settings on a fresh data folder, the app through TestClient, real worker processes.

`backend` runs a test twice: the embedded default (filesystem:// broker, SQLite)
and the scale-out one (Redis, PostgreSQL), which skips with a reason when
those servers are not reachable on 127.0.0.1. Those servers may be someone
else's: a test touches only what it made, every Redis key under its own
`CLOUD2CNC_REDIS_PREFIX` (deleted by that prefix afterwards, never FLUSHDB) and
a PostgreSQL database of its own (created under a unique name, dropped).
`CLOUD2CNC_TEST_REDIS_URL` picks the Redis database (default db 0 on 127.0.0.1).
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
REDIS_URL = os.environ.get("CLOUD2CNC_TEST_REDIS_URL", "redis://127.0.0.1:6379/0")
REDIS_TEST_PREFIX = "cloud2cnc-test-"  # + a unique part per test; no glob characters (SCAN MATCH)


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _redis_answers(url: str) -> bool:
    from urllib.parse import urlparse

    u = urlparse(url)
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex((u.hostname or "127.0.0.1", u.port or 6379)) == 0


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
        if not (_redis_answers(REDIS_URL) and _port_open(5432)):
            pytest.skip(f"scale-out backend needs Redis at {REDIS_URL} and PostgreSQL on 127.0.0.1:5432")
        prefix = f"{REDIS_TEST_PREFIX}{uuid.uuid4().hex[:12]}:"
        env.update(CELERY_BROKER_URL=REDIS_URL, CLOUD2CNC_REDIS_PREFIX=prefix)
        b.cleanup.append(lambda: delete_redis_keys(REDIS_URL, prefix))
        url, drop = _postgres_database()
        env.update(DATABASE_URL=url)
        b.cleanup.append(drop)
    try:
        yield b
    finally:
        _run_all(b.cleanup)


def _run_all(cleanup: list) -> None:
    """Call every function, even when one raises (then raise the first error)."""
    error = None
    for fn in cleanup:
        try:
            fn()
        except Exception as exc:  # noqa: BLE001 — the others still clean up
            error = error or exc
    if error is not None:
        raise error


def delete_redis_keys(url: str, prefix: str) -> int:
    """Delete the keys under `prefix` (what one test's broker wrote) and nothing else; how many went."""
    import redis

    if not prefix.startswith(REDIS_TEST_PREFIX) or any(c in prefix for c in "*?[]\\"):
        raise ValueError(f"refusing to delete Redis keys under {prefix!r}: not a test prefix")
    client = redis.Redis.from_url(url)
    try:
        keys = list(client.scan_iter(match=prefix + "*", count=1000))
        for start in range(0, len(keys), 500):
            client.delete(*keys[start:start + 500])
        return len(keys)
    finally:
        client.close()


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
