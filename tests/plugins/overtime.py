"""Test-only stage that runs out of time after reporting its progress, to see what the user is told."""

from __future__ import annotations

from pathlib import Path

from celery.exceptions import SoftTimeLimitExceeded

from core.stages import StageSpec
from worker.context import StageContext


def run_overtime(ctx: StageContext) -> dict[str, Path]:
    ctx.progress(0.1, "step one")
    ctx.progress(0.4, "step two of five")
    ctx.progress(0.45)  # no message: the last one still says where it is
    raise SoftTimeLimitExceeded()


STAGES = (StageSpec(name="overtime", version="1", inputs=(), outputs=(), param_groups=(), time_limit_s=120.0,
                    faster="a larger overtime.step"),)
IMPLEMENTATIONS = {"overtime": run_overtime}
