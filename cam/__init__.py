"""cloud2cnc geometry core: arrays in, arrays or small frozen records out.

One package per stage, in pipeline order (`ingest`, `reconstruct`, `denoise`, `remesh`, `segment`,
`fit`, `plan`, `verify`), and shared packages (`mesh`, `spline`, `gcode`, `io`, `params`). A stage's
entry point takes its own parameter group from `cam.params` and two optional callbacks, the one
convention every long computation here follows:

- ``progress(fraction, message=None)`` reports how far it got, fraction in [0, 1];
- ``check_cancel()`` is called from long loops and raises the caller's own exception to stop it
  (cam never catches it).

What a user can act on (a cloud too small, a patch that is no quad grid, a file that is not a mesh)
is raised as a `GeometryError` whose message says what was found and what to change; any other
exception is a bug.
"""

from __future__ import annotations

from typing import Callable

__all__ = ["CheckCancel", "GeometryError", "Progress", "progress_between"]

#: progress(fraction in [0, 1], message or None)
Progress = Callable[..., None]
#: check_cancel() raises to stop the computation, returns otherwise
CheckCancel = Callable[[], None]


class GeometryError(ValueError):
    """The input or the parameters do not allow the result, for a reason the user can act on; the message
    names what was found and what to change, and reaches the user as it is."""


def progress_between(progress: Progress | None, start: float, end: float) -> Progress:
    """A progress callback for a sub-step: its 0..1 is reported as start..end of `progress`."""

    def report(fraction: float, message: str | None = None) -> None:
        if progress is not None:
            progress(start + (end - start) * min(max(float(fraction), 0.0), 1.0), message)

    return report
