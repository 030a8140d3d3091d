"""Evenly spread samples of a triangle mesh's surface, each standing for a known piece of its area.

Every triangle is halved across its longest edge until no edge is longer than the spacing, and sampled
at the centroids of the pieces: deterministic, a long thin triangle gets samples along its length only,
and the weights (the pieces' areas) sum to the mesh's area exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SurfaceSamples", "sample_surface"]


@dataclass(frozen=True, eq=False)
class SurfaceSamples:
    """Points on a mesh's surface.

    Attributes
    ----------
    points : (k, 3) float64
        Sample positions, mm.
    normals : (k, 3) float64
        Unit normals of the triangles they lie on (outward where the mesh is oriented outward).
    area : (k,) float64
        The area each sample stands for, mm²; sums to the mesh's area.
    face : (k,) int64
        The triangle each sample lies on.
    """

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    face: np.ndarray

    def subset(self, keep: np.ndarray) -> SurfaceSamples:
        """The samples where `keep` (bool (k,) or indices) selects them."""
        return SurfaceSamples(self.points[keep], self.normals[keep], self.area[keep], self.face[keep])


def _halve(tri: np.ndarray, owner: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Split triangles (k, 3, 3) across their longest edge until every edge is at most `spacing` long."""
    done_tri, done_owner = [], []
    while len(tri):
        edge = np.linalg.norm(tri - np.roll(tri, -1, axis=1), axis=2)  # edge i runs from corner i to i + 1
        longest = np.argmax(edge, axis=1)
        short = edge[np.arange(len(tri)), longest] <= spacing
        done_tri.append(tri[short])
        done_owner.append(owner[short])
        tri, owner, longest = tri[~short], owner[~short], longest[~short]
        rows = np.arange(len(tri))
        a, b, c = tri[rows, longest], tri[rows, (longest + 1) % 3], tri[rows, (longest + 2) % 3]
        m = 0.5 * (a + b)
        tri = np.concatenate([np.stack([a, m, c], axis=1), np.stack([m, b, c], axis=1)])
        owner = np.concatenate([owner, owner])
    return np.concatenate(done_tri), np.concatenate(done_owner)


def sample_surface(vertices: np.ndarray, faces: np.ndarray, *, spacing_mm: float) -> SurfaceSamples:
    """Samples about `spacing_mm` apart over every triangle of a mesh.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex coordinates, mm.
    faces : (m, 3) int
        Triangles.
    spacing_mm : float
        Largest edge of the pieces each sample stands for, > 0.

    Returns
    -------
    SurfaceSamples
        Degenerate triangles (zero area) get no sample.
    """
    if not spacing_mm > 0:
        raise ValueError(f"spacing_mm must be positive, got {spacing_mm}")
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    tri = V[F]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    good = np.flatnonzero(double_area > 0)
    pieces, owner = _halve(tri[good], good, float(spacing_mm))
    piece_area = 0.5 * np.linalg.norm(np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0]), axis=1)
    normals = cross[owner] / double_area[owner, None]
    return SurfaceSamples(points=pieces.mean(axis=1), normals=normals, area=piece_area, face=owner)
