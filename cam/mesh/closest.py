"""Exact closest points on a triangle mesh: projections, Hausdorff distances and every fit error.

Triangles sit in the leaves of a bounding-volume tree built once per mesh; a
query descends it nearer box first and skips every box farther than the best
distance found, so the answer is exact, not a nearest-vertex approximation. The
search is compiled (`_closestkernel`) and runs the queries in parallel; its
arithmetic is `closest_on_triangles`'s, bit for bit.

A CAD mesh has a few triangles spanning whole faces beside many small ones; a
box around a large one overlaps most of the tree and is near every query.
Triangles with a radius over a fiftieth of the mesh's diagonal are therefore
indexed as pieces (halved across their longest edge until small enough); a
piece's closest point is its triangle's, reported with the triangle's index and
barycentrics, so the answer is the same. A point equally near two triangles
gets the one with the nearer centroid (then the lower index), however they were
cut and in whatever order the search met them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.mesh._closestkernel import closest_queries, make_tree

__all__ = ["MeshIndex", "closest_on_triangles", "closest_points", "mesh_index", "triangle_normals"]

# Distances this close are one distance (round-off of the same point reached through different pieces).
TIE_MM = 1e-9


@dataclass(frozen=True, eq=False)
class MeshIndex:
    """A triangle mesh prepared for closest-point queries (build once with `mesh_index`, query often).

    Attributes
    ----------
    vertices : (n, 3) float64
        Vertex coordinates in mm.
    faces : (m, 3) int64
        Triangles as vertex indices.
    centroids : (m, 3) float64
        Each triangle's centroid, mm (it breaks ties between equally near triangles).
    piece_face : (p,) int64
        The triangle each piece is part of.
    piece_corners : (p, 3, 3) float64
        Each piece's corners, mm.
    piece_bary : (p, 3, 3) float64
        Each piece's corners as barycentric weights of its triangle's corners (rows: corners).
    tree : tuple
        The pieces' bounding-volume tree (`_closestkernel.make_tree`).
    """

    vertices: np.ndarray  # float64 (n, 3), mm
    faces: np.ndarray  # int64 (m, 3)
    centroids: np.ndarray  # float64 (m, 3): each triangle's centroid, mm
    piece_face: np.ndarray  # int64 (p,)
    piece_corners: np.ndarray  # float64 (p, 3, 3)
    piece_bary: np.ndarray  # float64 (p, 3, 3)
    tree: tuple


def _radii(corners: np.ndarray) -> np.ndarray:
    return np.linalg.norm(corners - corners.mean(axis=1)[:, None, :], axis=2).max(axis=1)


def _cut_large(corners: np.ndarray, bary: np.ndarray, face: np.ndarray, limit: float):
    """Halve every piece with a radius over `limit` across its longest edge, until none is left."""
    while True:
        big = _radii(corners) > limit
        if not big.any():
            return corners, bary, face
        c, b = corners[big], bary[big]
        k = np.argmax(np.linalg.norm(np.roll(c, -1, axis=1) - c, axis=2), axis=1)  # edge k: corner k to k + 1
        rows = np.arange(len(c))
        i0, i1, i2 = k, (k + 1) % 3, (k + 2) % 3
        mid_c = 0.5 * (c[rows, i0] + c[rows, i1])
        mid_b = 0.5 * (b[rows, i0] + b[rows, i1])
        # (A, M, C) and (M, B, C): the corner order, and so the normal, is kept.
        first_c = np.stack([c[rows, i0], mid_c, c[rows, i2]], axis=1)
        second_c = np.stack([mid_c, c[rows, i1], c[rows, i2]], axis=1)
        first_b = np.stack([b[rows, i0], mid_b, b[rows, i2]], axis=1)
        second_b = np.stack([mid_b, b[rows, i1], b[rows, i2]], axis=1)
        corners = np.concatenate([corners[~big], first_c, second_c])
        bary = np.concatenate([bary[~big], first_b, second_b])
        face = np.concatenate([face[~big], face[big], face[big]])


def mesh_index(vertices: np.ndarray, faces: np.ndarray) -> MeshIndex:
    """Build the query structure of a triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex coordinates in mm.
    faces : (m, 3) array_like of int
        Triangles as vertex indices in [0, n).

    Returns
    -------
    index : MeshIndex
        The mesh with its pieces bucketed.

    Raises
    ------
    ValueError
        For arrays of the wrong shape, a mesh without triangles, or an index outside the vertices.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"need vertices (n, 3) and triangles (m, 3), got {V.shape} and {F.shape}")
    if F.size == 0:
        raise ValueError("the mesh has no triangles")
    if F.min() < 0 or F.max() >= len(V):
        raise ValueError(f"triangle indices must lie in 0..{len(V) - 1}, got {F.min()}..{F.max()}")
    used = np.unique(F)
    corners = V[F]
    # A fiftieth of the diagonal: a scan's or remesher's triangles are smaller and stay as they are; the
    # whole-face triangles and slivers of a CAD mesh are cut (finer pieces only add pieces to search).
    limit = float(np.linalg.norm(np.ptp(V[used], axis=0))) / 50.0
    corners, bary, face = _cut_large(corners, np.broadcast_to(np.eye(3), (len(F), 3, 3)).copy(),
                                     np.arange(len(F), dtype=np.int64), max(limit, 1e-12))
    return MeshIndex(vertices=V, faces=F, centroids=V[F].mean(axis=1), piece_face=face, piece_corners=corners,
                     piece_bary=bary, tree=make_tree(corners))


def triangle_normals(index: MeshIndex, triangles: np.ndarray) -> np.ndarray:
    """Unit normals of the mesh's triangles (as `closest_points` returns them).

    Parameters
    ----------
    index : MeshIndex
        The mesh.
    triangles : (k,) array_like of int
        Triangle indices into ``index.faces``.

    Returns
    -------
    normals : (k, 3) float64
        Unit normals by the right-hand rule over each triangle's corner order; zero for a degenerate
        triangle.
    """
    corners = index.vertices[index.faces[np.asarray(triangles, dtype=np.int64)]]
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on triangle (a, b, c) to p, row by row.

    Voronoi-region classification of p against the triangle's corners and edges; a degenerate
    (zero-area) triangle gives the closest point of its three edges.

    Parameters
    ----------
    p : (n, 3) float64
        Query points in mm.
    a, b, c : (n, 3) float64
        The corners of each row's triangle in mm.

    Returns
    -------
    points : (n, 3) float64
        Closest points in mm.
    barycentric : (n, 3) float64
        Their weights of a, b and c, summing to 1.
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

    total = va + vb + vc
    v_in, w_in = _ratio(vb, total), _ratio(vc, total)
    t_ab = _ratio(d1, d1 - d3)
    t_ac = _ratio(d2, d2 - d6)
    t_bc = _ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    conditions = [
        (d1 <= 0) & (d2 <= 0),
        (d3 >= 0) & (d4 <= d3),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),
        (d6 >= 0) & (d5 <= d6),
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
    ]
    one, zero = np.ones_like(d1), np.zeros_like(d1)
    bv = np.select(conditions, [zero, one, t_ab, zero, zero, 1 - t_bc], default=v_in)
    bw = np.select(conditions, [zero, zero, zero, one, t_ac, t_bc], default=w_in)
    bary = np.stack([1.0 - bv - bw, bv, bw], axis=1)
    points = a + bv[:, None] * ab + bw[:, None] * ac
    flat = np.linalg.norm(np.cross(ab, ac), axis=1) == 0
    if flat.any():
        # The region tests divide by the (zero) area there: take the best of the three edges instead.
        points[flat], bary[flat] = _closest_on_edges(p[flat], a[flat], b[flat], c[flat])
    return points, bary


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    return np.divide(num, den, out=np.zeros_like(num), where=den != 0)


def _closest_on_edges(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on the edges ab, bc, ca and its barycentrics (the degenerate-triangle case)."""
    points, barys = [], []
    for k, (s, e) in enumerate(((a, b), (b, c), (c, a))):
        se = e - s
        t = np.clip(_ratio(np.einsum("ij,ij->i", p - s, se), np.einsum("ij,ij->i", se, se)), 0.0, 1.0)
        bary = np.zeros((len(p), 3))
        bary[:, k], bary[:, (k + 1) % 3] = 1.0 - t, t
        points.append(s + t[:, None] * se)
        barys.append(bary)
    points, barys = np.stack(points), np.stack(barys)
    best = np.argmin(np.linalg.norm(points - p[None], axis=2), axis=0)
    rows = np.arange(len(p))
    return points[best, rows], barys[best, rows]


def closest_points(index: MeshIndex, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest mesh points to `points`, exact (see the module docstring).

    Parameters
    ----------
    index : MeshIndex
        The mesh.
    points : (n, 3) array_like of float
        Query points in mm, the mesh's frame.

    Returns
    -------
    closest : (n, 3) float64
        Closest points on the mesh in mm.
    distance : (n,) float64
        Distances to them in mm.
    triangle : (n,) int64
        The triangle each lies on.
    barycentric : (n, 3) float64
        Its barycentric coordinates in that triangle.
    """
    P = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    if not np.isfinite(P).all():
        raise ValueError("closest_points needs finite query points")
    n = len(P)
    out = (np.empty((n, 3)), np.empty(n), np.empty(n, dtype=np.int64), np.empty((n, 3)))
    closest_queries(P, index.piece_corners, index.piece_bary, index.piece_face, index.centroids, *index.tree,
                    TIE_MM, *out)
    return out
