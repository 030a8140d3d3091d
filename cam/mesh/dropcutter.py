"""Ball drop-cutter on a triangle mesh: how low a ball end mill can go above a point without cutting the part.

A ball of radius r lowered along the tool axis (+Z of the frame the triangles are in) stops at the first
contact with the part: on a facet (the centre r along the facet's normal from it), on an edge (the closed
form below) or on a vertex. The ball centre height over (x, y) is the highest of those contacts over all
triangles within r of (x, y); the ball lowered from above sweeps the cylinder over it, so the shank of a
ball-end mill lowered there is clear of the part too. Exact: every candidate triangle is tested, none is
sampled. Triangles are bucketed on an xy grid by their bounding boxes grown by r; each query runs through
its cell's triangles in compiled code (`_dropkernel`), in parallel over the queries. A clear query (`ball_clears`:
is the ball clear at this height?) runs through a second bucketing of the same cells, highest triangle first,
and stops at the first whose top is too low to lift the ball above its limit.

Edge contact: along an edge whose horizontal length is L and slope m = dz/L, at horizontal distance d
from the query's vertical line, the centre height at edge parameter σ (horizontal, from the foot of the
perpendicular) is z(σ) + √(ρ² − σ²) with ρ = √(r² − d²); it peaks at σ* = mρ / √(1 + m²), where it is
z(0) + ρ√(1 + m²).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.mesh._dropkernel import (
    bucket_boxes,
    clear_queries,
    drop_queries,
    surface_queries,
)

__all__ = ["DropIndex", "ball_clears", "drop_ball", "drop_index", "surface_height"]

@dataclass(frozen=True, eq=False)
class DropIndex:
    """Triangles bucketed for drop-cutter queries with one ball radius.

    Attributes
    ----------
    triangles : (m, 3, 3) float64
        Corners in mm, in the frame whose +Z is the tool axis.
    normals : (m, 3) float64
        Unit normals (zero for degenerate triangles), pointing out of the part.
    radius_mm : float
        Ball radius the buckets were grown by.
    origin : (2,) float64
        xy of the grid's lower corner, mm.
    cell_mm : float
        Grid spacing, mm.
    shape : tuple of int
        Cells along x and y.
    starts, members : (cells + 1,) int64, (k,) int64
        CSR buckets: the triangles near cell c are members[starts[c]:starts[c + 1]], in triangle order.
    by_top : (k,) int32, or None
        The same buckets (same starts), each cell's triangles highest `top` first (ties in triangle order):
        `ball_clears` stops a query at the first that cannot reach its limit. None: built without
        (`drop_index(clears=False)`).
    top : (m,) float64
        Highest corner of each triangle, mm.
    lo, hi : (m, 2) float64
        Each triangle's xy bounding box, mm.
    """

    triangles: np.ndarray
    normals: np.ndarray
    top: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    radius_mm: float
    origin: np.ndarray
    cell_mm: float
    shape: tuple[int, int]
    starts: np.ndarray
    members: np.ndarray
    by_top: np.ndarray | None


def drop_index(vertices: np.ndarray, faces: np.ndarray, *, radius_mm: float, closed: bool = False,
               cell_mm: float | None = None, clears: bool = True) -> DropIndex:
    """Bucket a triangle mesh for `drop_ball` with a ball of radius `radius_mm`.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex coordinates, mm, in the frame whose +Z is the tool axis.
    faces : (m, 3) int
        Triangles, oriented so that their normals point out of the part.
    radius_mm : float
        Ball radius, > 0.
    closed : bool
        The mesh is closed: a ball lowered from above first meets it on a triangle that faces up (or on
        such a triangle's edge or corner), so the others are left out. False keeps every triangle (an
        open scan, whose lower side may be reached past its border).
    cell_mm : float, optional
        Bucket size; default a quarter of the radius, at least a thousandth of the part's extent. The
        answers are the same for any size: coarser buckets build faster and answer each query slower.
    clears : bool
        Bucket the triangles a second time for `ball_clears` (`DropIndex.by_top`); False: an index for
        `drop_ball` and `surface_height` alone, built in about half the time.

    Returns
    -------
    DropIndex
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or not len(F):
        raise ValueError(f"need vertices (n, 3) and triangles (m >= 1, 3), got {V.shape} and {F.shape}")
    if not radius_mm > 0:
        raise ValueError(f"radius_mm must be positive, got {radius_mm}")
    tri = V[F]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    normals = np.where(length > 0, cross / np.maximum(length, 1e-300), 0.0)
    if closed:
        keep = normals[:, 2] > 1e-12
        tri, normals = tri[keep], normals[keep]
        if not len(tri):
            raise ValueError("no triangle of the closed mesh faces the tool")
    # three-way minimum and maximum of the corners: numpy's reduction over the short middle axis of a
    # strided view took a quarter of the build
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    box_lo = np.minimum(np.minimum(a[:, :2], b[:, :2]), c[:, :2])
    box_hi = np.maximum(np.maximum(a[:, :2], b[:, :2]), c[:, :2])
    lo, hi = box_lo - radius_mm, box_hi + radius_mm
    origin = lo.min(axis=0)
    extent = float((hi.max(axis=0) - origin).max())
    cell = float(cell_mm) if cell_mm is not None else max(0.25 * radius_mm, extent / 1000.0)
    shape = tuple(int(x) for x in np.floor((hi.max(axis=0) - origin) / cell).astype(np.int64) + 1)
    i0, j0 = np.floor((lo - origin) / cell).astype(np.int64).T
    i1, j1 = np.floor((hi - origin) / cell).astype(np.int64).T
    starts, members = bucket_boxes(i0, j0, i1, j1, shape)
    top = np.maximum(np.maximum(a[:, 2], b[:, 2]), c[:, 2])
    by_top = None
    if clears:
        high = np.argsort(-top, kind="stable")
        _, by_top = bucket_boxes(i0[high], j0[high], i1[high], j1[high], shape, ids=high.astype(np.int32))
    return DropIndex(triangles=tri, normals=normals, top=top, lo=box_lo, hi=box_hi,
                     radius_mm=float(radius_mm), origin=origin, cell_mm=cell,
                     shape=shape, starts=starts, members=members, by_top=by_top)


def drop_ball(index: DropIndex, xy: np.ndarray, *, contact: bool = False
              ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Lowest ball-centre height over each query point at which the ball does not cut the part.

    Parameters
    ----------
    index : DropIndex
        The part, bucketed for the ball radius (`drop_index`).
    xy : (n, 2) float
        Query points, mm, in the index's frame.
    contact : bool
        Also return where the ball touches.

    Returns
    -------
    z : (n,) float64
        Ball-centre heights, mm; -inf where no triangle lies within the radius (the ball falls past the
        part, or the point is not finite). The tool tip is r lower.
    contact_points : (n, 3) float64
        Only with ``contact=True``: the point of the part the ball touches (NaN where it touches none); the
        part's normal there is (centre − contact) / r.
    """
    q = np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    z = np.full(len(q), -np.inf)
    p = np.full((len(q), 3), np.nan)
    drop_queries(q, *_ball_arrays(index, index.members), z, p)
    return (z, p) if contact else z


def _ball_arrays(index: DropIndex, members: np.ndarray) -> tuple:
    """The index as the ball kernels (`_dropkernel.drop_queries`, `clear_queries`) take it, after the queries,
    with `members` (`index.members` or `index.by_top`) as its buckets."""
    return (index.triangles, index.normals, index.top, index.lo, index.hi, index.radius_mm, index.origin,
            index.cell_mm, np.asarray(index.shape, dtype=np.int64), index.starts, members)


def ball_clears(index: DropIndex, xy: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Whether the ball, its centre at height `limit` over each point, cuts none of the part.

    The answer of ``drop_ball(index, xy) <= limit``, found faster: a query stops at the first triangle that
    lifts the ball above its limit, and a triangle whose bound (the one `drop_ball` skips triangles by) is
    not above the limit is never solved.

    Parameters
    ----------
    index : DropIndex
        The part, bucketed for the ball radius (`drop_index`).
    xy : (n, 2) float
        Query points, mm, in the index's frame.
    limit : (n,) float
        Ball-centre heights, mm.

    Returns
    -------
    (n,) bool
    """
    if index.by_top is None:
        raise ValueError("this index was built for drop heights alone (drop_index(clears=False))")
    q = np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    z = np.ascontiguousarray(np.broadcast_to(np.asarray(limit, dtype=np.float64), (len(q),)))
    clear = np.zeros(len(q), dtype=np.bool_)
    clear_queries(q, z, *_ball_arrays(index, index.by_top), clear)
    return clear


def surface_height(index: DropIndex, xy: np.ndarray) -> np.ndarray:
    """Height of the part's top surface over each point: where a vertical line down meets it first.

    Parameters
    ----------
    index : DropIndex
        The part (any ball radius: only the buckets are used).
    xy : (n, 2) float
        Query points, mm.

    Returns
    -------
    (n,) float64
        Surface height, mm; -inf where the line misses the part.
    """
    q = np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    out = np.full(len(q), -np.inf)
    surface_queries(q, index.triangles, index.normals, index.lo, index.hi, index.origin, index.cell_mm,
                    np.asarray(index.shape, dtype=np.int64), index.starts, index.members, out)
    return out
