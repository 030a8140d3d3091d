"""What a stage implementation receives: input paths, an output folder, parameters, callbacks."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from cam import CheckCancel, Progress, progress_between
from cam.io.errors import ReadError
from core.params import JobParams


class StageError(Exception):
    """A failure the user can act on; its message is shown to them as it is.

    `outputs` (artifact name → path) are stored even though the stage failed,
    so the user can inspect what went wrong (e.g. `segments.ply` of a failed segmentation).
    """

    def __init__(self, message: str, *, outputs: dict[str, Path] | None = None) -> None:
        super().__init__(message)
        self.outputs = dict(outputs or {})


class StageCanceled(Exception):
    """The job was canceled while the stage ran."""


class StageSkipped(Exception):
    """The stage does not apply to this job (its message says why).

    `outputs` are stored all the same: a skipped stage may pass its input on
    under its own output name (denoise disabled passes `mesh_raw.ply` on as `mesh.ply`).
    """

    def __init__(self, message: str = "", *, outputs: dict[str, Path] | None = None) -> None:
        super().__init__(message)
        self.outputs = dict(outputs or {})


@dataclass
class StageContext:
    """Inputs by artifact name, a folder for outputs, the job's params and the stage's callbacks.

    `progress(fraction, message=None)` reports 0..1; `check_cancel()` raises `StageCanceled` when the
    job was canceled. Both are handed to `cam` as they are (cam's one convention, see `cam`).
    """

    job_id: str
    stage: str
    inputs: dict[str, Path]
    out_dir: Path
    params: JobParams
    settings: dict[str, Any]
    progress: Progress = field(default=lambda fraction, message=None: None)
    check_cancel: CheckCancel = field(default=lambda: None)

    def output(self, name: str) -> Path:
        """Where to write artifact `name` (the runner stores it after the stage returns)."""
        return self.out_dir / name

    def read(self, name: str, reader: Callable[[Path], Any]) -> Any:
        """Input artifact `name` as `reader` returns it; a file it cannot read fails the stage, naming the file."""
        try:
            return reader(self.inputs[name])
        except ReadError as exc:
            raise StageError(f"could not read {name}: {exc}") from exc

    def progress_between(self, start: float, end: float) -> Progress:
        """`progress` for a step that takes start..end of the stage."""
        return progress_between(self.progress, start, end)
