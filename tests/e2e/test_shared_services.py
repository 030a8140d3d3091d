"""A test run on a machine whose Redis and PostgreSQL are someone else's touches only what it made.

The scale-out backend writes every Redis key under its `CLOUD2CNC_REDIS_PREFIX` and works in a PostgreSQL
database of its own; the cleanup removes exactly those. A key of a bystander in the same Redis database
survives, and no key outside the prefix appears.
"""

from __future__ import annotations

import uuid

import pytest
from sqlalchemy import create_engine, text

from tests.conftest import (
    PG_ADMIN,
    REDIS_TEST_PREFIX,
    REDIS_URL,
    delete_redis_keys,
    wait_for,
    xyz_bytes,
)

pytestmark = pytest.mark.slow


def _outside(client) -> set[bytes]:
    """Keys of the database that no test of this suite owns (another run's prefix is not ours to judge)."""
    return {k for k in client.scan_iter(count=1000) if not k.startswith(REDIS_TEST_PREFIX.encode())}


def _databases() -> set[str]:
    engine = create_engine(PG_ADMIN)
    try:
        with engine.connect() as conn:
            return set(conn.execute(text("SELECT datname FROM pg_database")).scalars())
    finally:
        engine.dispose()


@pytest.mark.parametrize("backend", ["scaled"], indirect=True)
def test_a_scaled_job_writes_redis_keys_only_under_its_prefix(backend, start_worker, client_for):
    import redis

    prefix = backend.env["CLOUD2CNC_REDIS_PREFIX"]
    assert prefix.startswith(REDIS_TEST_PREFIX)
    r = redis.Redis.from_url(REDIS_URL)
    bystander = f"someone-else:{uuid.uuid4().hex}"
    r.set(bystander, b"theirs")
    try:
        before = _outside(r)
        worker = start_worker(backend, CLOUD2CNC_TEST_DWELL_S="0.2")
        client = client_for(backend)
        job = client.post("/v1/jobs", files={"file": ("part.xyz", xyz_bytes(200), "application/octet-stream")})
        assert job.status_code == 202, job.text
        done = wait_for(client, job.json()["id"], ("succeeded", "failed"), timeout_s=90)
        assert done["status"] == "succeeded", done
        # Cancel of a queued job broadcasts a revoke: the control channels are under the prefix as well.
        queued = client.post("/v1/jobs", files={"file": ("q.xyz", xyz_bytes(200, seed=1), "text/plain")}).json()
        client.post(f"/v1/jobs/{queued['id']}/cancel")
        wait_for(client, queued["id"], ("succeeded", "canceled", "failed"), timeout_s=90)
        worker.stop()

        ours = list(r.scan_iter(match=prefix + "*"))
        assert ours, "the broker wrote no key under the prefix: the prefix is not applied"
        assert _outside(r) - before == set(), "keys written outside the test's prefix"

        assert delete_redis_keys(REDIS_URL, prefix) == len(ours)
        assert list(r.scan_iter(match=prefix + "*")) == []
        assert r.get(bystander) == b"theirs"
    finally:
        r.delete(bystander)
        r.close()


def test_the_redis_cleanup_refuses_a_prefix_that_is_not_a_tests():
    with pytest.raises(ValueError, match="not a test prefix"):
        delete_redis_keys(REDIS_URL, "")
    with pytest.raises(ValueError, match="not a test prefix"):
        delete_redis_keys(REDIS_URL, REDIS_TEST_PREFIX + "*")


def test_the_postgres_database_is_the_tests_own_and_is_dropped():
    pytest.importorskip("psycopg")
    from tests.conftest import _port_open, _postgres_database

    if not _port_open(5432):
        pytest.skip("needs PostgreSQL on 127.0.0.1:5432")
    before = _databases()
    url, drop = _postgres_database()
    name = url.rsplit("/", 1)[1]
    assert name not in before and name.startswith("c2c_")
    assert name in _databases()
    drop()
    assert name not in _databases()
