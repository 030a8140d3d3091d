"""Whole jobs through the API and real `cloud2cnc worker` processes, on both backends."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from tests.conftest import wait_for, xyz_bytes

pytestmark = pytest.mark.slow


def _submit(client, data: bytes, params: str | None = None, name: str = "part.xyz", **headers):
    files = {"file": (name, data, "application/octet-stream")}
    form = {"params": params} if params is not None else {}
    return client.post("/v1/jobs", files=files, data=form, headers=headers)


def _stage(body: dict, name: str) -> dict:
    return next(s for s in body["stages"] if s["name"] == name)


def test_lifecycle_upload_run_download_rerun_delete(backend, start_worker, client_for):
    start_worker(backend, CLOUD2CNC_TEST_DWELL_S="0.3")
    client = client_for(backend)
    r = _submit(client, xyz_bytes(400), '{"fit": {"tolerance_mm": 0.05}}')
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    assert [s["name"] for s in job["stages"]] == ["ingest", "dwell"]

    done = wait_for(client, job["id"], ("succeeded", "failed"), timeout_s=90)
    assert done["status"] == "succeeded", done
    assert done["progress"] == 1.0
    names = {a["name"] for a in done["artifacts"]}
    assert {"input.xyz", "params.json", "cloud.ply", "ingest.json", "dwell.json"} <= names
    ingest = client.get(f"/v1/jobs/{job['id']}/artifacts/ingest.json").json()
    assert ingest["counts"]["kept"] == 400 and ingest["has_normals"] is True

    r = client.get(f"/v1/jobs/{job['id']}/artifacts/cloud.ply")
    assert r.status_code == 200
    assert r.content.startswith(b"ply\n")
    assert r.headers["content-type"] == "application/x-ply"
    assert 'filename="cloud.ply"' in r.headers["content-disposition"]
    etag = r.headers["etag"]
    cloud = next(a for a in done["artifacts"] if a["name"] == "cloud.ply")
    assert etag == f'"{cloud["sha256"]}"'
    assert client.get(f"/v1/jobs/{job['id']}/artifacts/cloud.ply", headers={"If-None-Match": etag}).status_code == 304

    # Rerun with a downstream parameter changed: ingest is reused as it was, dwell runs again.
    r = client.post(f"/v1/jobs/{job['id']}/rerun", json={"params": {"fit": {"tolerance_mm": 0.02}}})
    assert r.status_code == 202, r.text
    rerun = wait_for(client, r.json()["id"], ("succeeded", "failed"), timeout_s=90)
    assert rerun["status"] == "succeeded" and rerun["parent_id"] == job["id"]
    assert rerun["params"]["fit"]["tolerance_mm"] == 0.02
    old_ingest, new_ingest = _stage(done, "ingest"), _stage(rerun, "ingest")
    assert new_ingest["reused_from"] == job["id"]
    assert (new_ingest["started_at"], new_ingest["finished_at"]) == (old_ingest["started_at"], old_ingest["finished_at"])
    hashes = lambda b, stage: {a["name"]: a["sha256"] for a in b["artifacts"] if a["stage"] == stage}  # noqa: E731
    assert hashes(rerun, "ingest") == hashes(done, "ingest")
    assert _stage(rerun, "dwell")["reused_from"] is None
    assert _stage(rerun, "dwell")["started_at"] > _stage(done, "dwell")["finished_at"]

    # Delete: the job goes, files the rerun still uses stay, the rest leave the store.
    store = Path(backend.env["CLOUD2CNC_DATA_DIR"]) / "artifacts"
    path = lambda sha: store / sha[:2] / sha  # noqa: E731
    dwell_sha = hashes(done, "dwell")["dwell.json"]
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    assert client.get(f"/v1/jobs/{job['id']}").status_code == 404
    assert not path(dwell_sha).exists() or dwell_sha == hashes(rerun, "dwell")["dwell.json"]
    assert client.get(f"/v1/jobs/{rerun['id']}/artifacts/cloud.ply").status_code == 200
    assert client.delete(f"/v1/jobs/{rerun['id']}").status_code == 204
    for sha in hashes(rerun, "ingest").values():
        assert not path(sha).exists()


def test_cancel_running_job(backend, start_worker, client_for):
    # One worker: the job queued behind the canceled one starts once the cancel bites.
    start_worker(backend, CLOUD2CNC_TEST_DWELL_S="60", CLOUD2CNC_TEST_DWELL_MIN_POINTS="100")
    client = client_for(backend)
    job = _submit(client, xyz_bytes(200)).json()
    wait_for(client, job["id"], ("running",), timeout_s=90,
             predicate=lambda b: _stage(b, "dwell")["status"] == "running" and _stage(b, "dwell")["progress"] > 0)
    queued = _submit(client, xyz_bytes(50)).json()
    t0 = time.monotonic()
    r = client.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code == 202 and r.json()["status"] == "canceled"
    body = wait_for(client, job["id"], ("canceled",), timeout_s=20,
                    predicate=lambda b: _stage(b, "dwell")["status"] == "canceled")
    assert time.monotonic() - t0 < 20
    assert _stage(body, "ingest")["status"] == "succeeded"
    assert client.post(f"/v1/jobs/{job['id']}/cancel").status_code == 409
    wait_for(client, queued["id"], ("succeeded",), timeout_s=60)


def test_cancel_queued_job_never_runs(embedded, start_worker, client_for):
    client = client_for(embedded)
    job = _submit(client, xyz_bytes(200)).json()
    assert client.post(f"/v1/jobs/{job['id']}/cancel").status_code == 202
    start_worker(embedded, CLOUD2CNC_TEST_DWELL_S="0.1")
    # A second job proves the worker is consuming; the canceled one must stay untouched.
    other = _submit(client, xyz_bytes(201)).json()
    wait_for(client, other["id"], ("succeeded",), timeout_s=90)
    body = client.get(f"/v1/jobs/{job['id']}").json()
    assert body["status"] == "canceled"
    assert all(s["status"] == "canceled" and s["started_at"] is None for s in body["stages"])


def test_worker_killed_mid_stage_job_still_succeeds_once(backend, start_worker, client_for, tmp_path):
    log = tmp_path / "dwell.log"
    env = {"CLOUD2CNC_TEST_DWELL_S": "4", "CLOUD2CNC_TEST_DWELL_LOG": str(log)}
    worker = start_worker(backend, **env)
    client = client_for(backend)
    job = _submit(client, xyz_bytes(300)).json()
    wait_for(client, job["id"], ("running",), timeout_s=90,
             predicate=lambda b: _stage(b, "dwell")["status"] == "running" and _stage(b, "dwell")["progress"] > 0.2)
    worker.kill()
    assert not log.exists()  # it died mid-stage
    start_worker(backend, **env)
    body = wait_for(client, job["id"], ("succeeded", "failed"), timeout_s=120)
    assert body["status"] == "succeeded", body
    dwell = _stage(body, "dwell")
    assert dwell["attempts"] == 2
    assert _stage(body, "ingest")["attempts"] == 1
    assert log.read_text().count(job["id"]) == 1  # ran to completion exactly once
