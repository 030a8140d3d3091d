"""The API through TestClient (no worker): shapes, errors, pagination, idempotency, auth, schema drift."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from core.config import Settings
from core.stages import DESIGN_ORDER
from service.app import create_app
from tests.conftest import ROOT, xyz_bytes

PROBLEM = "application/problem+json"


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data", min_points=10)


@pytest.fixture
def client(settings: Settings):
    with TestClient(create_app(settings, reconcile=False)) as c:
        yield c


def submit(client, data=None, params=None, name="part.xyz", headers=None):
    files = {"file": (name, xyz_bytes(50) if data is None else data, "application/octet-stream")}
    form = {"params": params} if params is not None else {}
    return client.post("/v1/jobs", files=files, data=form, headers=headers or {})


def assert_problem(r, status: int, slug: str) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert body["type"] == f"urn:cloud2cnc:problem:{slug}", body
    assert body["status"] == status and body["title"] and body["detail"]
    assert "Traceback" not in r.text
    return body


def test_health_and_ready(client):
    assert client.get("/healthz").json() == {"status": "ok", "checks": {}}
    r = client.get("/readyz")
    assert r.status_code == 200, r.text
    assert r.json()["checks"] == {"database": "ok", "broker": "ok", "storage": "ok"}


def test_readyz_reports_a_dead_database(tmp_path):
    s = Settings(data_dir=tmp_path / "d", database_url="postgresql://nobody@127.0.0.1:1/none")
    with TestClient(create_app(s, reconcile=False)) as c:
        r = c.get("/readyz")
    body = assert_problem(r, 503, "not-ready")
    assert body["checks"]["database"].startswith("error") and body["checks"]["storage"] == "ok"


def test_create_returns_202_location_and_job(client):
    r = submit(client, params='{"tool": {"radius_mm": 2.5}}')
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    assert job["status"] == "queued" and job["progress"] == 0.0
    assert job["params"]["tool"]["radius_mm"] == 2.5
    assert job["params"]["toolpath"]["scallop_height_mm"] == 0.16  # defaults filled in
    assert [s["name"] for s in job["stages"]] == list(DESIGN_ORDER)
    assert {a["name"] for a in job["artifacts"]} == {"input.xyz", "params.json"}
    assert client.get(f"/v1/jobs/{job['id']}").json()["id"] == job["id"]
    params = client.get(f"/v1/jobs/{job['id']}/artifacts/params.json").json()
    assert params == job["params"]


def test_not_found_problems(client):
    assert_problem(client.get("/v1/jobs/nope"), 404, "job-not-found")
    job = submit(client).json()
    assert_problem(client.get(f"/v1/jobs/{job['id']}/artifacts/quads.obj"), 404, "artifact-not-found")
    assert_problem(client.get("/v1/nothing"), 404, "not-found")
    assert_problem(client.put("/v1/jobs"), 405, "method-not-allowed")


def test_cursor_pagination_and_status_filter(client):
    ids = [submit(client, data=xyz_bytes(20 + i)).json()["id"] for i in range(5)]
    seen, cursor = [], None
    while True:
        r = client.get("/v1/jobs", params={"limit": 2, **({"cursor": cursor} if cursor else {})})
        assert r.status_code == 200
        page = r.json()
        assert len(page["items"]) <= 2
        seen += [j["id"] for j in page["items"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert seen == ids[::-1]  # newest first, each once
    client.post(f"/v1/jobs/{ids[0]}/cancel")
    canceled = client.get("/v1/jobs", params={"status": "canceled"}).json()["items"]
    assert [j["id"] for j in canceled] == [ids[0]]
    assert_problem(client.get("/v1/jobs", params={"cursor": "garbage!"}), 400, "invalid-cursor")
    assert_problem(client.get("/v1/jobs", params={"status": "exploded"}), 422, "validation-error")
    assert_problem(client.get("/v1/jobs", params={"limit": 0}), 422, "validation-error")


def test_idempotency_key_replays_conflicts_and_mismatches(client, settings):
    data = xyz_bytes(60)
    first = submit(client, data=data, params="{}", headers={"Idempotency-Key": "k-1"})
    again = submit(client, data=data, params="{}", headers={"Idempotency-Key": "k-1"})
    assert first.status_code == again.status_code == 202
    assert again.json() == first.json()
    assert again.headers["location"] == first.headers["location"]
    assert len(client.get("/v1/jobs").json()["items"]) == 1
    assert_problem(submit(client, data=xyz_bytes(61), params="{}", headers={"Idempotency-Key": "k-1"}),
                   422, "idempotency-key-reused")
    assert_problem(submit(client, data=data, params='{"tool": {"radius_mm": 1}}', headers={"Idempotency-Key": "k-1"}),
                   422, "idempotency-key-reused")
    # A first request still being created: simulate its row.
    from core.db import IdempotencyKey, get_sessionmaker

    with get_sessionmaker(settings.resolved_database_url).begin() as s:
        s.add(IdempotencyKey(key="k-busy", state="creating"))
    assert_problem(submit(client, headers={"Idempotency-Key": "k-busy"}), 409, "idempotency-in-progress")
    # A failed first attempt does not burn the key.
    assert submit(client, data=b"", headers={"Idempotency-Key": "k-2"}).status_code == 422
    assert submit(client, headers={"Idempotency-Key": "k-2"}).status_code == 202


def test_api_key_guards_v1_but_not_health(tmp_path):
    s = Settings(data_dir=tmp_path / "d", api_key="s3cret")
    with TestClient(create_app(s, reconcile=False)) as c:
        body = assert_problem(c.get("/v1/jobs"), 401, "unauthorized")
        assert "X-API-Key" in body["detail"]
        assert_problem(c.get("/v1/jobs", headers={"X-API-Key": "wrong"}), 401, "unauthorized")
        assert c.get("/v1/jobs", headers={"X-API-Key": "s3cret"}).status_code == 200
        assert c.get("/healthz").status_code == 200


def test_rerun_validates_merged_params(client):
    job = submit(client).json()
    assert_problem(client.post(f"/v1/jobs/{job['id']}/rerun", json={"params": {"tool": {"radius_mm": -1}}}),
                   422, "invalid-params")
    assert_problem(client.post(f"/v1/jobs/{job['id']}/rerun", json={"nonsense": 1}), 422, "validation-error")
    r = client.post(f"/v1/jobs/{job['id']}/rerun", json={"params": {"toolpath": {"dialect": "grbl"}}})
    assert r.status_code == 202
    assert r.json()["params"]["toolpath"]["dialect"] == "grbl" and r.json()["parent_id"] == job["id"]


def test_delete_queued_job_removes_its_files(client, settings):
    job = submit(client, data=xyz_bytes(77)).json()
    files = [settings.artifacts_dir / a["sha256"][:2] / a["sha256"] for a in job["artifacts"]]
    assert all(f.is_file() for f in files)
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    assert not any(f.exists() for f in files)
    assert_problem(client.delete(f"/v1/jobs/{job['id']}"), 404, "job-not-found")


def test_openapi_file_matches_the_app():
    from service.openapi import render

    committed = (ROOT / "openapi" / "openapi.json").read_text()
    assert committed == render(), "openapi/openapi.json is stale: run `cloud2cnc openapi`"


def test_layers_do_not_import_across():
    probes = {
        "import service.app": ["numpy", "scipy", "torch", "trimesh", "skimage", "cam.io.ply"],
        "import worker.tasks": ["fastapi", "starlette"],
        "import cam.io, cam.ingest.clean": ["fastapi", "celery", "sqlalchemy", "service", "worker"],
    }
    for stmt, banned in probes.items():
        code = f"{stmt}; import sys; print([m for m in {banned!r} if m in sys.modules])"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
        assert json.loads(out.stdout.strip().replace("'", '"')) == [], (stmt, out.stdout)
