"""A test-only stage that takes a while: it lets tests kill, cancel and watch a running stage.

Loaded through CLOUD2CNC_STAGE_PLUGINS=tests.plugins.dwell. It reads
CLOUD2CNC_TEST_DWELL_S (seconds to take; only for clouds of at least
CLOUD2CNC_TEST_DWELL_MIN_POINTS points, default 0: smaller ones pass at once, so
a test can queue a quick job behind a slow one) and appends one line to
CLOUD2CNC_TEST_DWELL_LOG each time it runs to completion.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from cam.io import write_json
from core.stages import StageSpec
from worker.context import StageContext


def run_dwell(ctx: StageContext) -> dict[str, Path]:
    report = json.loads(ctx.inputs["ingest.json"].read_text())
    slow = report["counts"]["kept"] >= int(os.environ.get("CLOUD2CNC_TEST_DWELL_MIN_POINTS", "0"))
    seconds = float(os.environ.get("CLOUD2CNC_TEST_DWELL_S", "1")) if slow else 0.0
    t0 = time.monotonic()
    while (elapsed := time.monotonic() - t0) < seconds:
        ctx.check_cancel()
        ctx.progress(elapsed / seconds, "dwelling")
        time.sleep(0.05)
    log = os.environ.get("CLOUD2CNC_TEST_DWELL_LOG")
    if log:
        with open(log, "a") as fh:
            fh.write(f"{ctx.job_id} {os.getpid()}\n")
    return {"dwell.json": write_json(ctx.output("dwell.json"), {"points": report["counts"]["kept"],
                                                                 "seconds": seconds})}


STAGES = (StageSpec(name="dwell", version="1", inputs=("ingest.json",), outputs=("dwell.json",),
                    param_groups=("fit",)),)
IMPLEMENTATIONS = {"dwell": run_dwell}
