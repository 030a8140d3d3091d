"""Errors raised by the readers and writers in :mod:`cam.io`."""

from __future__ import annotations

from cam import GeometryError

__all__ = ["ReadError", "WriteError"]


class ReadError(GeometryError):
    """An input file cannot be read.

    The message names what was found and what the user can do about it, e.g.
    ``"binary PLY ends after 1200 of 5000 vertices (file truncated?)"``; the
    service shows it to the user as it is.
    """


class WriteError(ValueError):
    """Arrays handed to a writer cannot be written (wrong shape, non-finite values, bad indices): a bug of
    the caller, not something the user can change."""
