"""Cancel bites in every stage: a cancel raised at any check a stage makes ends that stage `canceled`, with
no child process left behind and nothing of it stored.

The README's example job runs once, stage by stage, counting each stage's cancel checks; then every stage
runs again on the same artifacts with a `check_cancel` that raises at its middle check. How soon a stage
checks (the cancel latency) is measured by `bench/cancel.py`, not here.
"""

from __future__ import annotations

import psutil
import pytest

from core.config import Settings
from core.params import JobParams
from core.stages import load_stages
from tests.conftest import ROOT
from worker.context import StageCanceled
from worker.local import run_stage

EXAMPLE_PARAMS = {"tool": {"radius_mm": 2}, "reconstruct": {"max_faces": 20000}, "fit": {"max_refinements": 0}}


class Counter:
    """check_cancel that counts its calls and raises StageCanceled from call `raise_at` on (never if None)."""

    def __init__(self, raise_at: int | None = None) -> None:
        self.calls, self.raise_at = 0, raise_at

    def __call__(self) -> None:
        self.calls += 1
        if self.raise_at is not None and self.calls >= self.raise_at:
            raise StageCanceled("canceled by the test")


@pytest.mark.slow
@pytest.mark.timeout(1800)  # the example job about 1.5 times over: ~2 min on a quiet machine
def test_every_stage_of_a_real_job_stops_at_any_cancel_check(tmp_path):
    settings = Settings(data_dir=tmp_path / "data")
    params = JobParams.model_validate(EXAMPLE_PARAMS)
    upload, job = ROOT / "examples" / "dome_block.xyz", tmp_path / "job"
    job.mkdir()
    stages = load_stages(settings.stage_plugins, settings.pipeline)
    for spec in stages:
        counter = Counter()
        report = run_stage(spec, upload, job, params=params, settings=settings, check_cancel=counter)
        assert report.status == "succeeded", report
        assert counter.calls >= 1, f"{spec.name} never checks for a cancel"
        stored = {p.name: p.stat().st_mtime_ns for p in job.iterdir()}

        report = run_stage(spec, upload, job, params=params, settings=settings,
                           check_cancel=Counter(raise_at=max(counter.calls // 2, 1)))
        assert report.status == "canceled", f"{spec.name}: {report}"
        assert not psutil.Process().children(recursive=True), f"{spec.name} left child processes running"
        assert {p.name: p.stat().st_mtime_ns for p in job.iterdir()} == stored, \
            f"{spec.name} stored something although it was canceled"
