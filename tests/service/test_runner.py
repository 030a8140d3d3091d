"""The stage runner in-process: failures keep inspection files, bugs give a reference and no trace."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from core.config import Settings
from service.app import create_app
from tests.conftest import xyz_bytes
from worker.runner import Outcome, run_stage


@pytest.fixture
def setup(tmp_path):
    settings = Settings(data_dir=tmp_path / "d", min_points=10, stage_plugins="tests.plugins.broken",
                        pipeline="ingest,inspect")
    with TestClient(create_app(settings, reconcile=False)) as client:
        job = client.post("/v1/jobs", files={"file": ("a.xyz", xyz_bytes(50))}).json()
        yield settings, client, job["id"]


def test_failed_stage_keeps_its_inspection_output(setup):
    settings, client, job_id = setup
    assert run_stage(settings, job_id, "ingest") is Outcome.CONTINUE
    assert run_stage(settings, job_id, "inspect") is Outcome.STOP
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["status"] == "failed"
    inspect = job["stages"][1]
    assert inspect["error"]["detail"] == "patch 3 is not a rectangular grid"
    assert client.get(f"/v1/jobs/{job_id}/artifacts/debug.json").json() == {"why": "patch 3 is L-shaped"}
    assert run_stage(settings, job_id, "inspect") is Outcome.STOP  # a failed job runs nothing more


def test_a_bug_in_a_stage_fails_it_with_a_reference_and_no_trace(tmp_path):
    settings = Settings(data_dir=tmp_path / "c", min_points=10, stage_plugins="tests.plugins.crash",
                        pipeline="ingest,crash")
    with TestClient(create_app(settings, reconcile=False)) as client:
        job_id = client.post("/v1/jobs", files={"file": ("a.xyz", xyz_bytes(50))}).json()["id"]
        run_stage(settings, job_id, "ingest")
        assert run_stage(settings, job_id, "crash") is Outcome.STOP
        r = client.get(f"/v1/jobs/{job_id}")
    error = r.json()["stages"][1]["error"]
    assert error["type"] == "urn:cloud2cnc:problem:stage-error"
    assert "internal error in stage crash (reference " in error["detail"]
    assert "KeyError" not in r.text and "Traceback" not in r.text


def test_a_repeated_message_for_a_finished_stage_continues_the_chain(setup):
    settings, client, job_id = setup
    assert run_stage(settings, job_id, "ingest") is Outcome.CONTINUE
    before = client.get(f"/v1/jobs/{job_id}").json()["stages"][0]
    assert run_stage(settings, job_id, "ingest") is Outcome.CONTINUE  # a redelivered duplicate
    after = client.get(f"/v1/jobs/{job_id}").json()["stages"][0]
    assert before == after and after["attempts"] == 1


@pytest.mark.parametrize(("configured", "per_stage", "limit"),
                         [(None, {}, "120 s"), (600.0, {}, "600 s"), (600.0, {"overtime": 300.0}, "300 s")])
def test_a_stage_out_of_time_says_where_it_got_to_and_what_makes_it_faster(tmp_path, configured, per_stage, limit):
    settings = Settings(data_dir=tmp_path / "o", min_points=10, stage_plugins="tests.plugins.overtime",
                        pipeline="ingest,overtime", stage_time_limit_s=configured, stage_time_limits=per_stage)
    with TestClient(create_app(settings, reconcile=False)) as client:
        job_id = client.post("/v1/jobs", files={"file": ("a.xyz", xyz_bytes(50))}).json()["id"]
        run_stage(settings, job_id, "ingest")
        assert run_stage(settings, job_id, "overtime") is Outcome.STOP
        detail = client.get(f"/v1/jobs/{job_id}").json()["stages"][1]["error"]["detail"]
    assert detail.startswith(f"stage overtime ran longer than its limit of {limit}; it had got to 45 % (step two of five)")
    assert "a larger overtime.step make it faster" in detail and "smaller input" not in detail
    assert detail.endswith("an operator can raise the limit (CLOUD2CNC_STAGE_TIME_LIMITS=overtime=SECONDS)")


def test_per_stage_time_limits_are_read_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("CLOUD2CNC_STAGE_TIME_LIMITS", "fit=2400, plan=1200")
    monkeypatch.setenv("CLOUD2CNC_STAGE_TIME_LIMIT_S", "1000")
    settings = Settings(data_dir=tmp_path)
    assert settings.stage_time_limits == {"fit": 2400.0, "plan": 1200.0}
    assert [settings.time_limit_s(name, 900.0) for name in ("fit", "plan", "verify")] == [2400.0, 1200.0, 1000.0]
    for bad in ("fit", "fit=soon", "fit=0", "=60"):
        monkeypatch.setenv("CLOUD2CNC_STAGE_TIME_LIMITS", bad)
        with pytest.raises(ValueError, match="stage=seconds"):
            Settings(data_dir=tmp_path)
