"""How much of a triangle mesh's creases a quad mesh's edges follow.

Segment puts patch borders on sharp quad edges, and a bicubic patch cannot bend
round a crease that runs through it: a crease of the input that no quad edge
follows ends up inside a patch, and the fit misses it there by up to the quad
size times the crease's turn. QuadriFlow's ``-sharp`` follows most creases, but
how many depends on its seed (on Fandisk ×10 at 3,000 quads, seeds 0, 1 and 2
miss 193, 27 and 110 mm of its 669 mm), so :func:`cam.remesh.quadriflow.remesh_quads` measures each layout
with :func:`measure_crease_following` and keeps the one that misses least.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cam.mesh.creases import mesh_creases

__all__ = ["CreaseFollowing", "measure_crease_following"]

# Points per crease edge: each stands for a quarter of the edge, so a crease half followed counts half.
_SAMPLES = 4
# Quad edges searched around a crease point; a vertex of a quad mesh has about four edges, so
# sixteen midpoints reach well past the ones that can pass near it.
_NEIGHBOURS = 16


@dataclass(frozen=True)
class CreaseFollowing:
    """Crease length of the input and how much of it no quad edge follows, mm; `tolerance_mm` is the
    distance within which a quad edge counts as following."""

    crease_length_mm: float
    missed_length_mm: float
    tolerance_mm: float

    def as_dict(self) -> dict:
        return {"crease_length_mm": self.crease_length_mm, "missed_crease_mm": self.missed_length_mm,
                "crease_tolerance_mm": self.tolerance_mm}


def measure_crease_following(
    quad_vertices: np.ndarray,
    quads: np.ndarray,
    vertices: np.ndarray,
    triangles: np.ndarray,
    *,
    crease_angle_deg: float = 60.0,
    tolerance_ratio: float = 0.1,
    max_turn_deg: float = 30.0,
) -> CreaseFollowing:
    """Length of the triangle mesh's creases that no quad edge follows.

    Parameters
    ----------
    quad_vertices, quads
        float (n, 3) mm and int (m, 4): the quad mesh.
    vertices, triangles
        float (p, 3) mm and int (q, 3): the triangle mesh it was made from.
    crease_angle_deg
        A triangle-mesh edge is a crease when its two faces' normals differ by
        more than this; 60° is the angle QuadriFlow's ``-sharp`` looks for.
    tolerance_ratio
        A point of a crease is followed when a quad edge passes within this
        fraction of the median quad edge length of it...
    max_turn_deg
        ...and runs within this angle of the crease's direction (a quad edge
        that crosses a crease does not follow it).

    Returns
    -------
    CreaseFollowing
        Lengths in mm, measured at four points per crease edge.
    """
    qv = np.asarray(quad_vertices, dtype=np.float64)
    qf = np.asarray(quads)
    tv = np.asarray(vertices, dtype=np.float64)
    tf = np.asarray(triangles)
    if qv.ndim != 2 or qv.shape[1] != 3 or qf.ndim != 2 or qf.shape[1] != 4 or len(qf) == 0:
        raise ValueError(f"need quad vertices (n, 3) and quads (m, 4), got {qv.shape} and {qf.shape}")
    if tv.ndim != 2 or tv.shape[1] != 3 or tf.ndim != 2 or tf.shape[1] != 3 or len(tf) == 0:
        raise ValueError(f"need vertices (p, 3) and triangles (q, 3), got {tv.shape} and {tf.shape}")
    if not 0 < crease_angle_deg < 180 or not 0 < max_turn_deg < 90 or tolerance_ratio <= 0:
        raise ValueError(f"need 0 < crease_angle_deg < 180, 0 < max_turn_deg < 90 and tolerance_ratio > 0; got "
                         f"{crease_angle_deg}, {max_turn_deg}, {tolerance_ratio}")
    creases = mesh_creases(tv, tf, angle_deg=crease_angle_deg)
    a, b = creases.a, creases.b
    qe = np.sort(np.stack([qf, np.roll(qf, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1)
    qe = np.unique(qe, axis=0)
    p, q = qv[qe[:, 0]], qv[qe[:, 1]]
    lengths = np.linalg.norm(q - p, axis=1)
    tolerance = float(tolerance_ratio * np.median(lengths))
    if not len(a):
        return CreaseFollowing(0.0, 0.0, tolerance)
    seg = np.linalg.norm(b - a, axis=1)
    t = (np.arange(_SAMPLES) + 0.5) / _SAMPLES
    points = (a[:, None] + t[None, :, None] * (b - a)[:, None]).reshape(-1, 3)
    weight = np.repeat(seg / _SAMPLES, _SAMPLES)
    crease_dir = np.repeat((b - a) / np.maximum(seg, 1e-300)[:, None], _SAMPLES, axis=0)
    quad_dir = (q - p) / np.maximum(lengths, 1e-300)[:, None]
    k = min(_NEIGHBOURS, len(qe))
    _, near = cKDTree(0.5 * (p + q)).query(points, k=k)
    near = near.reshape(len(points), k)
    # Distance from each crease point to each nearby quad edge (a segment, not its line).
    pp, dd, ll = p[near], quad_dir[near], lengths[near]
    s = np.clip(np.einsum("nkj,nkj->nk", points[:, None] - pp, dd), 0.0, ll)
    dist = np.linalg.norm(points[:, None] - (pp + s[..., None] * dd), axis=2)
    aligned = np.abs(np.einsum("nkj,nj->nk", dd, crease_dir)) >= np.cos(np.radians(max_turn_deg))
    followed = ((dist <= tolerance) & aligned).any(axis=1)
    return CreaseFollowing(float(seg.sum()), float(weight[~followed].sum()), tolerance)

