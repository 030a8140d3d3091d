"""Test-only stage that fails with a message and leaves a file for inspection."""

from __future__ import annotations

from pathlib import Path

from cam.io import write_json
from core.stages import StageSpec
from worker.context import StageContext, StageError


def run_inspectable_failure(ctx: StageContext) -> dict[str, Path]:
    debug = write_json(ctx.output("debug.json"), {"why": "patch 3 is L-shaped"})
    raise StageError("patch 3 is not a rectangular grid", outputs={"debug.json": debug})


STAGES = (
    StageSpec(name="inspect", version="1", inputs=("ingest.json",), outputs=("debug.json",), param_groups=()),
)
IMPLEMENTATIONS = {"inspect": run_inspectable_failure}
