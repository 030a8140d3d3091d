"""Exact closest points on a triangle mesh, for projecting vertices and measuring Hausdorff distances.

Candidates come from a k-d tree on triangle centroids: the nearest few
centroids give an upper bound ``d`` on the distance, and every triangle that
can hold a point within ``d`` has its centroid within ``d + R`` (``R`` the
largest centroid-to-corner distance), so the ball query misses none.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["closest_points", "point_triangle_closest"]


def point_triangle_closest(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest points of triangles ``abc`` to points ``p``, row by row.

    All inputs float64 (k, 3); returns float64 (k, 3). Uses the Voronoi
    regions of the triangle (vertices, edges, face) in barycentric terms;
    degenerate triangles fall back to their closest edge or vertex.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    out = np.empty_like(p)
    done = np.zeros(len(p), dtype=bool)

    def take(mask: np.ndarray, value: np.ndarray) -> None:
        # A degenerate triangle can make a region's formula 0/0: leave that row to the fallback.
        sel = mask & ~done & np.isfinite(value).all(axis=1)
        out[sel] = value[sel]
        done[sel] = True

    with np.errstate(divide="ignore", invalid="ignore"):
        take((d1 <= 0) & (d2 <= 0), a)
        take((d3 >= 0) & (d4 <= d3), b)
        t_ab = d1 / (d1 - d3)
        take((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[:, None] * ab)
        take((d6 >= 0) & (d5 <= d6), c)
        t_ac = d2 / (d2 - d6)
        take((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[:, None] * ac)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        take((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + t_bc[:, None] * (c - b))
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        inside = a + v[:, None] * ab + w[:, None] * ac
        take(np.ones(len(p), dtype=bool), inside)
    if not done.all():
        # Only degenerate (zero-area) triangles get here: take the best of their three edges.
        rest = ~done
        out[rest] = _closest_on_edges(p[rest], a[rest], b[rest], c[rest])
    return out


def _segment_closest(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    den = np.einsum("ij,ij->i", ab, ab)
    t = np.where(den > 0, np.einsum("ij,ij->i", p - a, ab) / np.where(den > 0, den, 1.0), 0.0)
    return a + np.clip(t, 0.0, 1.0)[:, None] * ab


def _closest_on_edges(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    cands = np.stack([_segment_closest(p, a, b), _segment_closest(p, b, c), _segment_closest(p, c, a)])
    dist = np.linalg.norm(cands - p[None], axis=2)
    return cands[np.argmin(dist, axis=0), np.arange(len(p))]


def closest_points(
    points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, *, chunk: int = 4096
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each point, the closest point on a triangle mesh.

    Parameters
    ----------
    points
        float (k, 3), mm.
    vertices, triangles
        The mesh: float (n, 3) and int (m, 3), m ≥ 1.
    chunk
        Points handled per batch (bounds memory).

    Returns
    -------
    closest float64 (k, 3), distance float64 (k,) in mm, triangle int64 (k,).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64)
    if len(tris) == 0:
        raise ValueError("closest_points needs at least one triangle, got none")
    corners = verts[tris]
    centroids = corners.mean(axis=1)
    radius = float(np.linalg.norm(corners - centroids[:, None], axis=2).max())
    tree = cKDTree(centroids)
    k = min(8, len(tris))
    closest = np.empty_like(pts)
    distance = np.empty(len(pts))
    which = np.empty(len(pts), dtype=np.int64)
    for s in range(0, len(pts), chunk):
        p = pts[s:s + chunk]
        _, near = tree.query(p, k=k)
        near = near.reshape(len(p), -1)
        rows = np.repeat(np.arange(len(p)), near.shape[1])
        q = point_triangle_closest(p[rows], *(corners[near.reshape(-1), j] for j in range(3)))
        bound = np.linalg.norm(q - p[rows], axis=1).reshape(len(p), -1).min(axis=1)
        groups = tree.query_ball_point(p, bound + radius + 1e-12)
        lens = np.fromiter((len(g) for g in groups), dtype=np.int64, count=len(groups))
        rows = np.repeat(np.arange(len(p)), lens)
        cand = np.fromiter((t for g in groups for t in g), dtype=np.int64, count=int(lens.sum()))
        q = point_triangle_closest(p[rows], corners[cand, 0], corners[cand, 1], corners[cand, 2])
        d = np.linalg.norm(q - p[rows], axis=1)
        # Per point, the candidate of least distance: sort by (row, distance) and take each row's first.
        order = np.lexsort((d, rows))
        first = order[np.r_[0, np.flatnonzero(np.diff(rows[order])) + 1]]
        closest[s:s + len(p)] = q[first]
        distance[s:s + len(p)] = d[first]
        which[s:s + len(p)] = cand[first]
    return closest, distance, which
