"""Creases of a triangle mesh: edges whose dihedral angle exceeds a threshold, and the closest
points on them. `remesh` measures how many of them the quad edges follow; `fit` moves patch borders
onto them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["Creases", "closest_on_creases", "mesh_creases"]


@dataclass(frozen=True, eq=False)
class Creases:
    """Crease segments of a mesh and the corners of the crease graph (see `mesh_creases`).

    Attributes
    ----------
    a, b : (k, 3) float64
        Endpoints of the crease segments, mm.
    corners : (c, 3) float64
        Crease-graph vertices where three or more creases meet or a crease ends, mm.
    tree : scipy.spatial.cKDTree or None
        The segments' midpoints; None when there are no creases.
    corner_tree : scipy.spatial.cKDTree or None
        The corners; None when there are none.
    reach : float
        Half the longest segment, mm: a segment's points lie within it of its midpoint.
    corner_degree : (c,) int64
        The number of creases at each corner.
    """

    a: np.ndarray
    b: np.ndarray
    corners: np.ndarray
    tree: cKDTree | None
    corner_tree: cKDTree | None
    reach: float  # half the longest segment: a segment's points lie within it of its midpoint
    corner_degree: np.ndarray


def mesh_creases(vertices: np.ndarray, faces: np.ndarray, *, angle_deg: float = 40.0) -> Creases:
    """Edges of a triangle mesh whose two faces' normals differ by more than `angle_deg`.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex coordinates in mm.
    faces : (m, 3) array_like of int
        Triangles as vertex indices.
    angle_deg : float, optional
        Threshold on the angle between the normals in degrees, in (0, 180) (default 40).

    Returns
    -------
    creases : Creases
        The crease segments; empty (no trees, reach 0) when there are none.

    Raises
    ------
    ValueError
        When `angle_deg` is not in (0, 180).
    """
    import trimesh

    if not 0 < angle_deg < 180:
        raise ValueError(f"angle_deg must be in (0, 180), got {angle_deg}")
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64), process=False)
    sharp = mesh.face_adjacency_angles > np.radians(angle_deg)
    edges = mesh.face_adjacency_edges[sharp]
    V = mesh.vertices
    if not len(edges):
        return Creases(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), None, None, 0.0,
                       np.zeros(0, dtype=np.int64))
    degree = np.bincount(edges.ravel(), minlength=len(V))
    corner_ids = np.flatnonzero((degree >= 3) | (degree == 1))
    a, b = V[edges[:, 0]], V[edges[:, 1]]
    corners = V[corner_ids]
    return Creases(a=a, b=b, corners=corners, tree=cKDTree(0.5 * (a + b)),
                   corner_tree=cKDTree(corners) if len(corners) else None,
                   reach=float(0.5 * np.linalg.norm(b - a, axis=1).max()), corner_degree=degree[corner_ids])


def closest_on_creases(creases: Creases, points: np.ndarray, *, directions: np.ndarray | None = None,
                       max_angle_deg: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """Closest crease points to `points`.

    Candidates are the 16 segments with the nearest midpoints. Where a direction is given (a non-zero
    row), only crease segments within `max_angle_deg` of that direction (either sense) count, so a point
    on an edge that runs across a crease is not pulled onto it; nor does a point move more along the
    direction than across it (an edge that runs on past where a crease ends stays off the crease's end).

    Parameters
    ----------
    creases : Creases
        From `mesh_creases`.
    points : (n, 3) array_like of float
        Query points in mm.
    directions : (n, 3) array_like of float or None, optional
        Direction per point (any length; a zero row means none); None (default) for no direction test.
    max_angle_deg : float, optional
        Largest angle between a direction and a segment, degrees (default 30).

    Returns
    -------
    closest : (n, 3) float64
        Closest crease points in mm; not usable where the distance is inf.
    distance : (n,) float64
        Distances in mm; inf where no crease counts.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if creases.tree is None or not len(P):
        return P.copy(), np.full(len(P), np.inf)
    k = min(16, len(creases.a))
    _, idx = creases.tree.query(P, k=k)
    idx = idx.reshape(len(P), -1)
    a, b = creases.a[idx], creases.b[idx]
    ab = b - a
    ab2 = np.maximum(np.einsum("nkd,nkd->nk", ab, ab), 1e-300)
    t = np.clip(np.einsum("nkd,nkd->nk", P[:, None, :] - a, ab) / ab2, 0, 1)
    q = a + t[..., None] * ab
    d = np.linalg.norm(q - P[:, None, :], axis=2)
    if directions is not None:
        D = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        dn = np.linalg.norm(D, axis=1)
        cos = np.abs(np.einsum("nkd,nd->nk", ab, D)) / (np.sqrt(ab2) * np.maximum(dn, 1e-300)[:, None])
        unit = D / np.maximum(dn, 1e-300)[:, None]
        along = np.abs(np.einsum("nkd,nd->nk", q - P[:, None, :], unit))
        off = (cos < np.cos(np.radians(max_angle_deg))) | (along > 0.5 * d)
        d = np.where(off & (dn > 0)[:, None], np.inf, d)
    best = np.argmin(d, axis=1)
    rows = np.arange(len(P))
    return q[rows, best], d[rows, best]
