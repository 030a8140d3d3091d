"""A test-only stage that works in forked child processes, as `fit` and `plan` do (`cam.map_forked`).

Loaded through CLOUD2CNC_STAGE_PLUGINS=tests.plugins.forking. Its `forking` stage runs two calls in two
forked children, each of which takes CLOUD2CNC_TEST_DWELL_S seconds; when both are back it appends
one line (`job pid`) to CLOUD2CNC_TEST_DWELL_LOG, so a test counts the runs that completed. Lets tests
kill a worker whose stage has children of its own and check that none of them survives.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from cam import map_forked
from cam.io import write_json
from core.stages import StageSpec
from worker.context import StageContext

CHILDREN = 2


def _sleep_in_child(index: int, check_cancel) -> int:
    deadline = time.monotonic() + float(os.environ.get("CLOUD2CNC_TEST_DWELL_S", "1"))
    while time.monotonic() < deadline:
        check_cancel()
        time.sleep(0.05)
    return os.getpid()


def run_forking(ctx: StageContext) -> dict[str, Path]:
    report = json.loads(ctx.inputs["ingest.json"].read_text())
    pids = map_forked(_sleep_in_child, CHILDREN, processes=CHILDREN, check_cancel=ctx.check_cancel,
                      progress=lambda fraction, message=None: ctx.progress(fraction, "in children"))
    log = os.environ.get("CLOUD2CNC_TEST_DWELL_LOG")
    if log:
        with open(log, "a") as fh:
            fh.write(f"{ctx.job_id} {os.getpid()}\n")
    return {"forking.json": write_json(ctx.output("forking.json"), {"points": report["counts"]["kept"],
                                                                     "children": pids})}


STAGES = (StageSpec(name="forking", version="1", inputs=("ingest.json",), outputs=("forking.json",),
                    param_groups=("fit",)),)
IMPLEMENTATIONS = {"forking": run_forking}
