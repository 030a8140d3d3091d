"""Test-only stage with a bug in it (a KeyError), to see what the user is told."""

from __future__ import annotations

from pathlib import Path

from core.stages import StageSpec
from worker.context import StageContext


def run_crash(ctx: StageContext) -> dict[str, Path]:
    return {"x": Path("/nonexistent")}[ctx.stage]


STAGES = (StageSpec(name="crash", version="1", inputs=(), outputs=(), param_groups=()),)
IMPLEMENTATIONS = {"crash": run_crash}
