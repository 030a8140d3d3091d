"""What a stage implementation receives: input paths, an output folder, parameters, callbacks."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable


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

    `progress(fraction, message)` reports 0..1; `check_cancel()` raises `StageCanceled`
    when the job was canceled — call both from long loops.
    """

    job_id: str
    stage: str
    inputs: dict[str, Path]
    out_dir: Path
    params: dict[str, Any]
    settings: dict[str, Any]
    progress: Callable[[float, str | None], None] = field(default=lambda f, m=None: None)
    check_cancel: Callable[[], None] = field(default=lambda: None)

    def output(self, name: str) -> Path:
        """Where to write artifact `name` (the runner stores it after the stage returns)."""
        return self.out_dir / name

    def read(self, name: str, reader: Callable[[Path], Any]) -> Any:
        """Input artifact `name` as `reader` returns it; a file it cannot read fails the stage, naming the file."""
        from cam.io.errors import (
            ReadError,  # here, not at the top: the API imports this module, not cam
        )

        try:
            return reader(self.inputs[name])
        except ReadError as exc:
            raise StageError(f"could not read {name}: {exc}") from exc


def write_json(path: Path, obj: Any) -> Path:
    """Write JSON to a temporary name beside `path` and rename it into place."""
    import json
    import os
    import tempfile

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(obj, fh, indent=2, sort_keys=False)
            fh.write("\n")
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)
    return path
