"""Moving a layout's vertices towards their neighbours' centre along the part's surface.

Both the coarse mesh (:mod:`cam.remesh.coarse`) and the finished grids (:mod:`cam.remesh.subdivide`) are evened
out the same way: each vertex free to move takes a share of the step to its edge neighbours' centre, with the
part of the step along the surface's normal removed, and is projected back onto its own region. A vertex stays
where the surface under it would turn by over 45° (rounding a bend its edges are too long to follow, it would
leave the bend uncovered), and a move that turns a face over (its normal by over about 80°) is taken back.
"""

from __future__ import annotations

import numpy as np

from cam.remesh.features import CreaseFeatures

__all__ = ["face_normals", "neighbour_centres", "slide_on_surface", "undo_turned"]

# A vertex whose surface normal would turn by more than this stays (degrees).
_MAX_SURFACE_TURN_DEG = 45.0
# A face whose normal turned so far that its cosine falls under this is turned over.
_TURNED_COS = 0.2


def neighbour_centres(points: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The mean of each vertex's edge neighbours (float64 (n, 3), mm; a vertex on no edge its own point)."""
    n = len(points)
    centre = np.zeros((n, 3))
    count = np.bincount(edges.ravel(), minlength=n).astype(float)
    np.add.at(centre, edges[:, 0], points[edges[:, 1]])
    np.add.at(centre, edges[:, 1], points[edges[:, 0]])
    return np.where(count[:, None] > 0, centre / np.maximum(count, 1)[:, None], points)


def slide_on_surface(features: CreaseFeatures, points: np.ndarray, regions: np.ndarray, centres: np.ndarray,
                     share: float) -> np.ndarray:
    """Points (float64 (k, 3), mm) moved ``share`` of the way to ``centres`` along the surface, on their regions.

    ``points`` and ``centres`` float (k, 3) mm, ``regions`` int (k,): each point's region. A point stays where the
    surface's normal under it would turn by over 45°.
    """
    _, normals = features.project(points, regions)
    step = share * (centres - points)
    step -= np.einsum("ij,ij->i", step, normals)[:, None] * normals
    moved, turned = features.project(points + step, regions)
    keep = np.einsum("ij,ij->i", normals, turned) > np.cos(np.radians(_MAX_SURFACE_TURN_DEG))
    return np.where(keep[:, None], moved, points)


def face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each triangle's or quad's normal, not unit (float64 (m, 3)): for a quad, the cross of its diagonals."""
    p = points[faces]
    if faces.shape[1] == 4:
        return np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def undo_turned(points: np.ndarray, faces: np.ndarray, before: np.ndarray, old: list[tuple[np.ndarray, np.ndarray]]
                ) -> None:
    """Take moves back (in place) until no face's normal turned over against ``before`` ((m, 3)): each pair of
    ``old`` is (an array changed by the moves, its values before them), ``points`` first; every corner of a
    turned face gets its old values in all of them."""
    for _ in range(20):
        after = face_normals(points, faces)
        turned = np.einsum("ij,ij->i", before, after) <= _TURNED_COS * np.linalg.norm(before, axis=1) * np.linalg.norm(
            after, axis=1)
        if not turned.any():
            return
        back = np.unique(faces[turned])
        for now, was in old:
            now[back] = was[back]
