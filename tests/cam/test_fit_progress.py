"""The fit stage's progress moves while a patch is fitted, not only when one is done: each patch's steps
reach the stage's progress, from the forked processes too, and change nothing of the surfaces."""

from __future__ import annotations

import json

import pytest

import cam
from tests.cam.test_fit_shapes import cylinder
from tests.cam.test_fit_stage import _job
from worker.stages.fit import run_fit

PHASES = ("fitting each patch on its own", "fitting each patch inside its shared borders")


def _fit_with_progress(tmp_path, processes: int) -> tuple[list[tuple[float, str | None]], dict]:
    ctx, _, _ = _job(tmp_path, cylinder(25.0), blocks=[(0, 7), (7, 14)])
    ctx.settings = {"stage_processes": processes}
    seen: list[tuple[float, str | None]] = []
    ctx.progress = lambda fraction, message=None: seen.append((fraction, message))
    out = run_fit(ctx)
    return seen, json.loads(out["surfaces.json"].read_text())


@pytest.mark.parametrize("processes", [1, 2])
def test_progress_moves_between_two_patches_done(tmp_path, monkeypatch, processes):
    monkeypatch.setattr(cam, "REPORT_INTERVAL_S", 0.0)  # every step's report passes: no timing in the test
    seen, _ = _fit_with_progress(tmp_path, processes)
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    for label in PHASES:
        reports = [(f, m[len(label) + 2:]) for f, m in seen if m and m.startswith(label + ": ")]
        # A patch done: "k of 2 done"; a patch's own step: "k of 2 done; patch i: ...".
        ends = [f for f, m in reports if ";" not in m]
        assert [m for _, m in reports if ";" not in m] == ["1 of 2 done", "2 of 2 done"]
        bounds = [reports[0][0], *ends]  # the phase's start: both patches at their first step
        # One after the other, every patch's steps come between the patch before it done and itself done;
        # two at once, at least the first patch to be done moved the progress before it was.
        for k in range(2 if processes == 1 else 1):
            inside = [f for f, m in reports if m.startswith(f"{k} of 2 done; patch ") and bounds[k] < f < bounds[k + 1]]
            assert inside, (label, k, reports)
    steps = [m for _, m in seen if m and "; patch " in m]
    assert any("step 2 of" in m for m in steps)


def test_the_surfaces_are_the_same_with_each_step_reported(tmp_path, monkeypatch):
    monkeypatch.setattr(cam, "REPORT_INTERVAL_S", 0.0)
    (tmp_path / "one").mkdir()
    (tmp_path / "two").mkdir()
    _, serial = _fit_with_progress(tmp_path / "one", 1)
    _, forked = _fit_with_progress(tmp_path / "two", 2)
    assert serial == forked
