"""The scallop between two neighbouring ball positions, measured on the part itself.

Two balls of radius r whose centres are closer than 2r meet in a circle; the point of that circle
nearest the part is the cusp of the material the two passes leave between them, and its distance to
the part's surface is that scallop's height: the exact scallop relation evaluated on the mesh, with
whatever curvature the part has across the passes, rather than a formula for a plane. A cusp inside
the part (a hump the balls pass on either side of), or balls that do not meet, leave more than any
target: their height is +inf.
"""

from __future__ import annotations

import numpy as np

from cam.mesh.closest import MeshIndex, closest_points, triangle_normals

__all__ = ["cusp_heights", "cusp_points"]


def cusp_points(c1: np.ndarray, c2: np.ndarray, toward: np.ndarray, *, tool_radius_mm: float) -> np.ndarray:
    """Where two balls meet nearest the part.

    Parameters
    ----------
    c1, c2 : (k, 3) float
        Ball centres, mm.
    toward : (k, 3) float
        A direction towards the part at each pair (down for a raster, into the wall for a waterline).
    tool_radius_mm : float
    over_mm : float
        `between` is worked out only where the height is over this (elsewhere it is True): the caller
        asks only about scallops over its share.

    Returns
    -------
    (k, 3) float64
        The cusp points, mm; NaN where the balls do not meet (centres 2r or more apart) or `toward`
        runs along the line between the centres.
    """
    r = float(tool_radius_mm)
    c1, c2 = np.asarray(c1, dtype=np.float64), np.asarray(c2, dtype=np.float64)
    d = c2 - c1
    dist = np.linalg.norm(d, axis=1)
    unit = d / np.maximum(dist, 1e-300)[:, None]
    w = np.asarray(toward, dtype=np.float64)
    w = w - (w * unit).sum(axis=1)[:, None] * unit
    wn = np.linalg.norm(w, axis=1)
    half = np.sqrt(np.maximum(r * r - 0.25 * dist * dist, 0.0))
    q = 0.5 * (c1 + c2) + half[:, None] * w / np.maximum(wn, 1e-300)[:, None]
    bad = (dist >= 2 * r) | (wn < 1e-9)
    q[bad] = np.nan
    return q


def cusp_heights(c1: np.ndarray, c2: np.ndarray, toward: np.ndarray, mesh: MeshIndex, *,
                 tool_radius_mm: float, over_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Height of the scallop two neighbouring balls leave between them, mm.

    Parameters
    ----------
    c1, c2 : (k, 3) float
        Ball centres, mm, in the mesh's frame.
    toward : (k, 3) float
        A direction towards the part at each pair.
    mesh : MeshIndex
        The part (closed, outward), same frame.
    tool_radius_mm : float

    Returns
    -------
    height : (k,) float64
        Distance from the cusp to the part's surface; +inf where the balls do not meet or the cusp lies
        inside the part.
    foot : (k, 3) float64
        The part's point nearest the cusp (NaN where the balls do not meet).
    normal : (k, 3) float64
        The part's unit normal there.
    between : (k,) bool
        Whether both balls touch the part and that point lies between their own nearest points of it
        (within the ball that has them on its diameter, grown by a tenth): only then is the material
        there a scallop the two passes leave; otherwise the cusp measures air.
    """
    q = cusp_points(c1, c2, toward, tool_radius_mm=tool_radius_mm)
    height = np.full(len(q), np.inf)
    foot, normal = np.full((len(q), 3), np.nan), np.full((len(q), 3), np.nan)
    between = np.zeros(len(q), dtype=bool)
    ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
    if not len(ok):
        return height, foot, normal, between
    foot[ok], dist, tri, _ = closest_points(mesh, q[ok])
    normal[ok] = triangle_normals(mesh, tri)
    outside = ((q[ok] - foot[ok]) * normal[ok]).sum(axis=1) >= -1e-9
    height[ok] = np.where(outside, dist, np.inf)
    between[ok] = True
    ask = ok[height[ok] > over_mm]
    if len(ask):
        t1, d1 = closest_points(mesh, np.asarray(c1, dtype=np.float64)[ask])[:2]
        t2, d2 = closest_points(mesh, np.asarray(c2, dtype=np.float64)[ask])[:2]
        half = 0.5 * np.linalg.norm(t2 - t1, axis=1)
        # Both balls touch the part (a ball clear of it leaves no scallop of its own), and the cusp's foot
        # lies between their contacts.
        touching = (d1 <= tool_radius_mm * 1.01) & (d2 <= tool_radius_mm * 1.01)
        between[ask] = touching & (np.linalg.norm(foot[ask] - 0.5 * (t1 + t2), axis=1) <= 1.1 * half + 1e-6)
    return height, foot, normal, between
