"""Split polygons given as ragged index lists into triangles."""

from __future__ import annotations

import numpy as np

__all__ = ["fan_triangulate"]


def fan_triangulate(counts: np.ndarray, flat: np.ndarray) -> tuple[np.ndarray, int]:
    """Fan-triangulate polygons, keeping their order.

    Parameters
    ----------
    counts : (m,) array_like of int
        Number of corners of each polygon.
    flat : (counts.sum(),) array_like of int
        The corners of all polygons, concatenated.

    Returns
    -------
    faces : (t, 3) int64
        Polygon ``(v0, v1, ..., vk)`` becomes ``(v0, vi, vi+1)`` for ``i = 1..k-2``; triangles of one
        polygon are consecutive and polygons keep their order. Fans are exact for the convex, planar
        polygons that CAD and scanner software export.
    skipped : int
        How many polygons had fewer than 3 corners and produced nothing.
    """
    counts = np.asarray(counts, dtype=np.int64)
    flat = np.asarray(flat, dtype=np.int64)
    starts = np.cumsum(counts) - counts
    skipped = int(np.count_nonzero(counts < 3))
    if np.all(counts == 3):
        return flat.reshape(-1, 3).copy(), 0
    pieces = []
    owners = []
    for corners in np.unique(counts[counts >= 3]):
        polygons = np.flatnonzero(counts == corners)
        rings = flat[starts[polygons, None] + np.arange(corners)]
        fan = np.stack(
            [
                np.repeat(rings[:, :1], corners - 2, axis=1),
                rings[:, 1:-1],
                rings[:, 2:],
            ],
            axis=2,
        )
        pieces.append(fan.reshape(-1, 3))
        owners.append(np.repeat(polygons, corners - 2))
    if not pieces:
        return np.empty((0, 3), dtype=np.int64), skipped
    order = np.argsort(np.concatenate(owners), kind="stable")
    return np.concatenate(pieces)[order], skipped
