"""Ball drop-cutter on a triangle mesh: how low a ball end mill can go above a point without cutting the part.

A ball of radius r lowered along the tool axis (+Z of the frame the triangles are in) stops at the first
contact with the part: on a facet (the centre r along the facet's normal from it), on an edge (the closed
form below) or on a vertex. The ball centre height over (x, y) is the highest of those contacts over all
triangles within r of (x, y); the ball lowered from above sweeps the cylinder over it, so the shank of a
ball-end mill lowered there is clear of the part too. Exact: every candidate triangle is tested, none is
sampled. Triangles are bucketed on an xy grid by their bounding boxes grown by r, and queries are
evaluated in chunks of (query, candidate) pairs with numpy.

Edge contact: along an edge whose horizontal length is L and slope m = dz/L, at horizontal distance d
from the query's vertical line, the centre height at edge parameter σ (horizontal, from the foot of the
perpendicular) is z(σ) + √(ρ² − σ²) with ρ = √(r² − d²); it peaks at σ* = mρ / √(1 + m²), where it is
z(0) + ρ√(1 + m²).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DropIndex", "drop_ball", "drop_index", "surface_height"]

_PAIRS_PER_CHUNK = 1 << 21


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
        CSR buckets: the triangles near cell c are members[starts[c]:starts[c + 1]].
    max_bucket : int
        The most triangles in one bucket (sizes the chunks of queries).
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
    max_bucket: int


def drop_index(vertices: np.ndarray, faces: np.ndarray, *, radius_mm: float, closed: bool = False,
               cell_mm: float | None = None) -> DropIndex:
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
        Bucket size; default a quarter of the radius, at least a thousandth of the part's extent.

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
    box_lo, box_hi = tri[:, :, :2].min(axis=1), tri[:, :, :2].max(axis=1)
    lo, hi = box_lo - radius_mm, box_hi + radius_mm
    origin = lo.min(axis=0)
    extent = float((hi.max(axis=0) - origin).max())
    cell = float(cell_mm) if cell_mm is not None else max(0.25 * radius_mm, extent / 1000.0)
    shape = tuple(int(x) for x in np.floor((hi.max(axis=0) - origin) / cell).astype(np.int64) + 1)
    i0, j0 = np.floor((lo - origin) / cell).astype(np.int64).T
    i1, j1 = np.floor((hi - origin) / cell).astype(np.int64).T
    ni, nj = i1 - i0 + 1, j1 - j0 + 1
    count = ni * nj
    owner = np.repeat(np.arange(len(tri)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    cells = (np.repeat(i0, count) + k // np.repeat(nj, count)) * shape[1] + np.repeat(j0, count) + k % np.repeat(nj, count)
    order = np.argsort(cells, kind="stable")
    starts = np.searchsorted(cells[order], np.arange(shape[0] * shape[1] + 1))
    return DropIndex(triangles=tri, normals=normals, top=tri[:, :, 2].max(axis=1), lo=box_lo, hi=box_hi,
                     radius_mm=float(radius_mm), origin=origin, cell_mm=cell,
                     shape=shape, starts=starts.astype(np.int64), members=owner[order].astype(np.int64),
                     max_bucket=max(int(np.diff(starts).max(initial=1)), 1))


def _candidates(index: DropIndex, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(query, triangle) pairs: every triangle bucketed in each query's cell."""
    ij = np.floor((xy - index.origin) / index.cell_mm).astype(np.int64)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < index.shape[0]) & (ij[:, 1] >= 0) & (ij[:, 1] < index.shape[1])
    cell = np.where(inside, ij[:, 0] * index.shape[1] + ij[:, 1], 0)
    start = index.starts[cell]
    count = np.where(inside, index.starts[cell + 1] - start, 0)
    query = np.repeat(np.arange(len(xy)), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    return query, index.members[np.repeat(start, count) + offset]


def _vertex_contacts(q: np.ndarray, tri: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Highest vertex contact per pair: centre z (-inf: none) and the contact point (k, 3)."""
    d2 = ((tri[:, :, :2] - q[:, None, :]) ** 2).sum(axis=2)
    z = np.where(d2 <= r * r, tri[:, :, 2] + np.sqrt(np.maximum(r * r - d2, 0.0)), -np.inf)
    best = np.argmax(z, axis=1)
    rows = np.arange(len(q))
    return z[rows, best], tri[rows, best]


def _edge_contacts(q: np.ndarray, tri: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Highest edge-interior contact per pair over the triangle's three edges (closed form, module docstring)."""
    best_z = np.full(len(q), -np.inf)
    best_p = np.zeros((len(q), 3))
    for a, b in ((0, 1), (1, 2), (2, 0)):
        p0, p1 = tri[:, a], tri[:, b]
        dxy = p1[:, :2] - p0[:, :2]
        length = np.linalg.norm(dxy, axis=1)
        ok = length > 1e-12
        u = dxy / np.where(ok, length, 1.0)[:, None]
        rel = q - p0[:, :2]
        s_q = (rel * u).sum(axis=1)
        d = np.abs(rel[:, 0] * u[:, 1] - rel[:, 1] * u[:, 0])
        ok &= d <= r
        rho = np.sqrt(np.maximum(r * r - d * d, 0.0))
        m = (p1[:, 2] - p0[:, 2]) / np.where(ok, length, 1.0)
        root = np.sqrt(1.0 + m * m)
        sigma = m * rho / root
        t = (sigma + s_q) / np.where(ok, length, 1.0)
        ok &= (t >= 0.0) & (t <= 1.0)
        z = np.where(ok, p0[:, 2] + m * s_q + rho * root, -np.inf)
        better = z > best_z
        best_z = np.where(better, z, best_z)
        at = p0 + t[:, None] * (p1 - p0)
        best_p = np.where(better[:, None], at, best_p)
    return best_z, best_p


def _facet_contacts(q: np.ndarray, tri: np.ndarray, n: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Facet-interior contact per pair: the ball touches the facet's plane inside the triangle (upward facets)."""
    up = n[:, 2] > 1e-12
    nz = np.where(up, n[:, 2], 1.0)
    p = q - r * n[:, :2]  # the contact point's xy
    a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    den = np.where(np.abs(den) > 1e-300, den, np.inf)
    s = (v2[:, 0] * v1[:, 1] - v2[:, 1] * v1[:, 0]) / den
    t = (v0[:, 0] * v2[:, 1] - v0[:, 1] * v2[:, 0]) / den
    inside = up & (s >= 0) & (t >= 0) & (s + t <= 1)
    plane_z = tri[:, 0, 2] - (n[:, 0] * (p[:, 0] - tri[:, 0, 0]) + n[:, 1] * (p[:, 1] - tri[:, 0, 1])) / nz
    z = np.where(inside, plane_z + r * n[:, 2], -np.inf)
    return z, np.column_stack([p, plane_z])


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
        part). The tool tip is r lower.
    contact_points : (n, 3) float64
        Only with ``contact=True``: the point of the part the ball touches (NaN where it touches none); the
        part's normal there is (centre − contact) / r.
    """
    q_all = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    r = index.radius_mm
    z_out = np.full(len(q_all), -np.inf)
    p_out = np.full((len(q_all), 3), np.nan)
    step = max(1, _PAIRS_PER_CHUNK // index.max_bucket)
    for lo in range(0, len(q_all), step):
        q = q_all[lo:lo + step]
        query, tri_id = _candidates(index, q)
        # No contact with a triangle can be higher than its top corner plus the ball's height over its
        # bounding box: pairs that cannot win are dropped before the exact test.
        gap = np.maximum(np.maximum(index.lo[tri_id] - q[query], q[query] - index.hi[tri_id]), 0.0)
        d2 = (gap ** 2).sum(axis=1)
        keep = d2 <= r * r
        query, tri_id = query[keep], tri_id[keep]
        if not len(query):
            continue
        bound = index.top[tri_id] + np.sqrt(r * r - d2[keep])
        # A first guess per query from its most promising triangle, then every triangle that may beat it.
        starts = np.flatnonzero(np.r_[True, query[1:] != query[:-1]])
        best_bound = np.maximum.reduceat(bound, starts)
        is_best = bound == np.repeat(best_bound, np.diff(np.r_[starts, len(query)]))
        first = np.flatnonzero(is_best)
        zq, pq = _exact(q[query[first]], index, tri_id[first], r)
        guess = np.full(len(q), -np.inf)
        np.maximum.at(guess, query[first], zq)
        rest = (bound > guess[query]) & ~is_best
        zr, pr = _exact(q[query[rest]], index, tri_id[rest], r)
        qid = np.concatenate([query[first], query[rest]])
        zall, pall = np.concatenate([zq, zr]), np.concatenate([pq, pr])
        order = np.lexsort((zall, qid))
        last = np.flatnonzero(np.r_[qid[order][1:] != qid[order][:-1], True])
        winners = order[last]
        z_out[lo + qid[winners]] = zall[winners]
        p_out[lo + qid[winners]] = np.where(np.isfinite(zall[winners])[:, None], pall[winners], np.nan)
    return (z_out, p_out) if contact else z_out


def _exact(q: np.ndarray, index: DropIndex, tri_id: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """The highest exact contact of each (query point, triangle) pair: centre z (k,) and contact point (k, 3)."""
    tri, n = index.triangles[tri_id], index.normals[tri_id]
    zs, ps = zip(_vertex_contacts(q, tri, r), _edge_contacts(q, tri, r), _facet_contacts(q, tri, n, r))
    z = np.stack(zs, axis=1)
    kind = np.argmax(z, axis=1)
    rows = np.arange(len(z))
    return z[rows, kind], np.stack(ps, axis=1)[rows, kind]


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
    q_all = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(q_all), -np.inf)
    step = max(1, _PAIRS_PER_CHUNK // index.max_bucket)
    for lo in range(0, len(q_all), step):
        q = q_all[lo:lo + step]
        query, tri_id = _candidates(index, q)
        inside_box = np.all((index.lo[tri_id] <= q[query]) & (q[query] <= index.hi[tri_id]), axis=1)
        query, tri_id = query[inside_box], tri_id[inside_box]
        z, _ = _facet_contacts(q[query], index.triangles[tri_id], index.normals[tri_id], 0.0)
        np.maximum.at(out, lo + query, z)
    return out
