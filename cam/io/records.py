"""The record every reader in :mod:`cam.io` returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["InputData"]


@dataclass(frozen=True, eq=False)
class InputData:
    """What a file holds, in the file's own frame and units (or in mm where ``in_mm`` says so).

    Attributes
    ----------
    points : (n, 3) float64
        Point or vertex coordinates. Non-finite rows are kept; :func:`cam.ingest.clean.clean_cloud` drops
        and counts them.
    normals : (n, 3) float64 or None
        Per-point normals as stored (not normalised).
    colors : (n, 3) uint8 or None
        Per-point RGB.
    faces : (m, 3) int64 or None
        Triangles indexing ``points`` (polygons are fan triangulated). None means the file is a point
        cloud.
    format : str
        The sniffed format name (see :data:`cam.io.formats.FORMATS`).
    comments : tuple of str
        The file's own comment or header lines, in order.
    notes : tuple of str
        What the reader decided that a user may want to know (columns ignored, polygons triangulated,
        ...), as sentences.
    in_mm : bool
        True when the file states its own length unit and the reader has converted ``points`` to mm (E57 is
        in metres by its standard; a LAS file's CRS may name its unit); ``ingest.units`` does not apply then.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    faces: np.ndarray | None = None
    format: str = "unknown"
    comments: tuple[str, ...] = field(default=())
    notes: tuple[str, ...] = field(default=())
    in_mm: bool = False

    @property
    def is_mesh(self) -> bool:
        """True when the file holds at least one face."""
        return self.faces is not None and len(self.faces) > 0
