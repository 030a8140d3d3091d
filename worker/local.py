"""Run the pipeline in-process on one file: no database, no queue, artifacts under DESIGN's names in a folder.

This is `cloud2cnc run`, and how benchmarks and scripts drive the pipeline.
"""

from __future__ import annotations

import shutil
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from cam import CheckCancel, GeometryError, Progress
from cam.io import write_json
from core.config import Settings
from core.params import JobParams
from core.stages import StageSpec, load_stages, stage_names_until
from worker.context import StageCanceled, StageContext, StageError, StageSkipped
from worker.stages import implementation


@dataclass(frozen=True)
class StageReport:
    name: str
    status: str
    seconds: float
    outputs: tuple[str, ...] = ()
    error: str | None = None


class _Bar:
    """A one-line progress bar on a terminal; plain lines when the stream is not a terminal (a log): one when
    the fraction moved by `step` since the last line, or when a report comes `every_s` or more after it,
    so that a log shows a long stage moving and what it is doing."""

    def __init__(self, stream: TextIO, name: str, *, step: float = 0.05, every_s: float = 10.0,
                 clock=time.monotonic) -> None:
        self.stream, self.name = stream, name
        self.tty = stream.isatty()
        self.step, self.every_s, self.clock = step, every_s, clock
        self.last, self.last_at = -1.0, clock()
        self.width = max(shutil.get_terminal_size((100, 24)).columns - 52, 20) if self.tty else 0

    def update(self, fraction: float, message: str | None = None) -> None:
        fraction = max(0.0, min(1.0, fraction))
        if self.tty:
            filled = int(fraction * 30)
            text = message or ""
            if len(text) > self.width:
                text = text[:self.width - 1] + "…"
            self.stream.write(f"\r{self.name:<12} [{'#' * filled}{'.' * (30 - filled)}] {fraction:4.0%} "
                              f"{text:<{self.width}}")
            self.stream.flush()
            return
        now = self.clock()
        if (fraction - self.last >= self.step - 1e-9 or now - self.last_at >= self.every_s
                or fraction >= 1.0 and self.last < 1.0):
            self.stream.write(f"{self.name}: {fraction:.0%} {message or ''}\n")
            self.stream.flush()
            self.last, self.last_at = fraction, now

    def end(self, text: str) -> None:
        line = f"{self.name:<12} {text}"
        # On a terminal the line overwrites the bar: as wide as it at least.
        self.stream.write(f"\r{line:<{self.width + 51}}\n" if self.tty else line + "\n")
        self.stream.flush()


def run_local(input_path: Path, out_dir: Path, *, params: dict[str, Any], settings: Settings,
              until: str | None = None, stream: TextIO = sys.stderr) -> list[StageReport]:
    """Run the implemented stages (up to `until`) on `input_path`; returns one report per stage.

    Stops at the first failed stage. Raises `ValueError` for invalid params or an unknown stage.
    """
    if not input_path.is_file():
        raise ValueError(f"input file not found: {input_path}")
    params = JobParams.model_validate(params)
    stages = load_stages(settings.stage_plugins, settings.pipeline)
    names = stage_names_until(stages, until)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "params.json", params.model_dump(mode="json"))
    reports = []
    for spec in stages:
        if spec.name not in names:
            break
        bar = _Bar(stream, spec.name)
        report = run_stage(spec, input_path, out_dir, params=params, settings=settings, progress=bar.update,
                           stream=stream)
        reports.append(report)
        if report.status == "succeeded":
            bar.end(f"done in {report.seconds:.2f} s: {', '.join(report.outputs)}")
        elif report.status == "skipped":
            bar.end(f"skipped {report.error or ''}")
        else:
            bar.end(f"FAILED: {report.error}")
            break
    return reports


def run_stage(spec: StageSpec, input_path: Path, out_dir: Path, *, params: JobParams, settings: Settings,
              progress: Progress | None = None, check_cancel: CheckCancel | None = None,
              stream: TextIO = sys.stderr) -> StageReport:
    """Run one stage on the artifacts in `out_dir` (the upload is `input_path`) and store its outputs there.

    The report's status is "succeeded", "skipped", "failed" or "canceled" (`check_cancel` raised
    `StageCanceled`); a bug's traceback goes to `stream`. Nothing of a canceled or failed stage is stored
    but the outputs it keeps for inspection.
    """
    inputs = {"input": input_path}
    inputs.update({n: out_dir / n for n in spec.inputs if (out_dir / n).is_file()})
    scratch = out_dir / f".{spec.name}.tmp"
    shutil.rmtree(scratch, ignore_errors=True)
    scratch.mkdir()
    ctx = StageContext(job_id="local", stage=spec.name, inputs=inputs, out_dir=scratch, params=params,
                       settings={k: getattr(settings, k) for k in spec.settings},
                       progress=progress or (lambda fraction, message=None: None),
                       check_cancel=check_cancel or (lambda: None))
    t0 = time.perf_counter()
    try:
        outputs = implementation(spec.name, settings.stage_plugins)(ctx)
    except StageSkipped as exc:
        for name, path in exc.outputs.items():
            Path(path).replace(out_dir / name)  # passed on (denoise disabled: mesh.ply)
        return StageReport(spec.name, "skipped", time.perf_counter() - t0, tuple(exc.outputs),
                           error=str(exc) or None)
    except StageCanceled as exc:
        return StageReport(spec.name, "canceled", time.perf_counter() - t0, error=str(exc) or "canceled")
    except (StageError, GeometryError) as exc:
        for name, path in getattr(exc, "outputs", {}).items():
            Path(path).replace(out_dir / name)  # kept for inspection
        return StageReport(spec.name, "failed", time.perf_counter() - t0, error=str(exc))
    except Exception as exc:  # noqa: BLE001 — our bug: the traceback goes to the stream, the run stops
        stream.write(traceback.format_exc())
        return StageReport(spec.name, "failed", time.perf_counter() - t0,
                           error=f"internal error in stage {spec.name} ({type(exc).__name__}: {exc})")
    else:
        for name, path in outputs.items():
            Path(path).replace(out_dir / name)  # same folder: an atomic rename
        return StageReport(spec.name, "succeeded", time.perf_counter() - t0, tuple(outputs))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
