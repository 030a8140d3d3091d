"""Job and stage transitions on a real database: claims are exclusive, leases lapse, attempts are capped."""

from __future__ import annotations

import time

import pytest

from core import jobs
from core.db import Job, get_sessionmaker
from core.params import JobParams
from core.stages import DESIGN_ORDER, STAGES, cache_key, load_stages


@pytest.fixture
def Session(tmp_path):
    return get_sessionmaker(f"sqlite:///{tmp_path / 'jobs.db'}")


def _job(Session, stages=("ingest", "dwell")) -> str:
    with Session.begin() as s:
        job = jobs.create_job(s, input_name="a.xyz", input_sha256="0" * 64, input_size=1, input_format="xyz",
                              params={}, stage_names=list(stages))
        return job.id


def test_a_stage_is_claimed_once(Session):
    job_id = _job(Session)
    with Session.begin() as s:
        first = jobs.claim_stage(s, job_id, "ingest", lease_s=30, worker="a")
    with Session.begin() as s:
        second = jobs.claim_stage(s, job_id, "ingest", lease_s=30, worker="b")
    assert first is not None and second is None
    with Session() as s:
        assert s.get(Job, job_id).status == "running"


def test_only_the_lease_holder_finishes(Session):
    job_id = _job(Session, ("ingest",))
    with Session.begin() as s:
        claim = jobs.claim_stage(s, job_id, "ingest", lease_s=30, worker="a")
    with Session.begin() as s:
        assert not jobs.finish_stage(s, job_id, "not-the-token", status="succeeded")
    with Session.begin() as s:
        assert jobs.finish_stage(s, job_id, claim.token, status="succeeded")
    with Session.begin() as s:
        assert not jobs.finish_stage(s, job_id, claim.token, status="succeeded")  # not twice
    with Session() as s:
        assert s.get(Job, job_id).status == "succeeded"


def test_lapsed_lease_is_requeued_then_failed_after_max_attempts(Session):
    job_id = _job(Session, ("ingest",))
    for attempt in (1, 2, 3):
        with Session.begin() as s:
            claim = jobs.claim_stage(s, job_id, "ingest", lease_s=0.01, worker="w")
            assert claim.attempt == attempt
        time.sleep(0.03)
        with Session.begin() as s:
            requeued = jobs.reconcile(s, max_attempts=3)
        if attempt < 3:
            assert requeued == [jobs.Requeue(job_id, "ingest")]
        else:
            assert requeued == []
    with Session() as s:
        job = s.get(Job, job_id)
        assert job.status == "failed"
        assert job.error["type"] == "urn:cloud2cnc:problem:worker-lost" and "3 times" in job.error["detail"]


def test_a_live_lease_is_left_alone(Session):
    job_id = _job(Session, ("ingest",))
    with Session.begin() as s:
        claim = jobs.claim_stage(s, job_id, "ingest", lease_s=0.05, worker="w")
    for _ in range(4):
        time.sleep(0.02)
        with Session.begin() as s:
            assert jobs.renew_lease(s, claim.token, lease_s=0.05, progress=0.5)
        with Session.begin() as s:
            assert jobs.reconcile(s, max_attempts=3) == []


def test_cancel_marks_queued_stages_and_refuses_finished_jobs(Session):
    job_id = _job(Session)
    with Session.begin() as s:
        assert jobs.request_cancel(s, s.get(Job, job_id))
    with Session.begin() as s:
        job = s.get(Job, job_id)
        assert job.status == "canceled" and [st.status for st in job.stages] == ["canceled", "canceled"]
        assert not jobs.request_cancel(s, job)
        assert jobs.claim_stage(s, job_id, "ingest", lease_s=30, worker="w") is None


def test_cache_key_depends_only_on_what_the_stage_reads():
    spec = STAGES[0]
    base = JobParams(ingest={"units": "mm"}, tool={"radius_mm": 3})
    settings = {"min_points": 10, "max_points": 100}
    key = cache_key(spec, base, {"input": "a" * 64}, settings, code="c")
    assert key == cache_key(spec, JobParams(tool={"radius_mm": 1}), {"input": "a" * 64}, settings, code="c")
    assert key != cache_key(spec, JobParams(ingest={"units": "inch"}), {"input": "a" * 64}, settings, code="c")
    assert key != cache_key(spec, base, {"input": "b" * 64}, settings, code="c")
    assert key != cache_key(spec, base, {"input": "a" * 64}, {**settings, "max_points": 99}, code="c")
    assert key != cache_key(spec, base, {"input": "a" * 64}, settings, code="d")


def test_the_fit_cache_key_follows_the_tolerance_it_uses_not_the_toolpath_group():
    fit = next(s for s in STAGES if s.name == "fit")
    key = cache_key(fit, JobParams(), {}, {}, code="c")
    # A new dialect or tool changes the programs, not the surfaces: the fit is reused.
    assert key == cache_key(fit, JobParams(toolpath={"dialect": "fanuc"}, tool={"radius_mm": 2}), {}, {}, code="c")
    # The unset tolerance is a fifth of the scallop height: a new height is a new fit, an explicit
    # tolerance equal to the derived one is the same fit.
    assert key != cache_key(fit, JobParams(toolpath={"scallop_height_mm": 0.1}), {}, {}, code="c")
    assert key == cache_key(fit, JobParams(fit={"tolerance_mm": 0.032}), {}, {}, code="c")
    # How many processes fit the patches changes the speed, not the surfaces.
    assert key == cache_key(fit, JobParams(), {}, {"stage_processes": 2}, code="c")


def test_cache_key_follows_the_code_the_stage_runs(tmp_path, monkeypatch):
    # A plugin stage whose module imports a helper inside its function: editing the helper changes the
    # key (a deployment with new code does not reuse old results), editing a module it never imports does not.
    from core.stages import StageSpec, code_digest

    pkg = tmp_path / "plugpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "stage.py").write_text("def run(ctx):\n    from .helper import scale\n    return scale\n")
    (pkg / "helper.py").write_text("scale = 1.0\n")
    (pkg / "other.py").write_text("unused = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    spec = StageSpec(name="extra", version="1", inputs=(), outputs=(), param_groups=())

    def key_now() -> str:
        return cache_key(spec, JobParams(), {}, {}, code=code_digest("plugpkg.stage"))

    key = key_now()
    assert key == key_now()
    (pkg / "other.py").write_text("unused = 2\n")
    assert key_now() == key
    (pkg / "helper.py").write_text("scale = 2.0\n")
    assert key_now() != key


def test_a_lapsed_stage_of_a_canceled_job_is_canceled_not_requeued(Session):
    job_id = _job(Session, ("ingest",))
    with Session.begin() as s:
        jobs.claim_stage(s, job_id, "ingest", lease_s=0.01, worker="w")
        jobs.request_cancel(s, s.get(Job, job_id))
    time.sleep(0.03)
    with Session.begin() as s:
        assert jobs.reconcile(s, max_attempts=3) == []
    with Session() as s:
        assert [st.status for st in s.get(Job, job_id).stages] == ["canceled"]


def test_pipeline_subset_keeps_design_order_and_refuses_unknown_stages():
    assert [s.name for s in load_stages()] == list(DESIGN_ORDER)
    assert [s.name for s in load_stages(only="fit, ingest,denoise")] == ["ingest", "denoise", "fit"]
    with pytest.raises(ValueError, match=r"unknown stages \['fitt'\]"):
        load_stages(only="ingest,fitt")
