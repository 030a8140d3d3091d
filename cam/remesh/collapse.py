"""Diagonal collapses of a quad mesh: a quad removed by merging two of its opposite corners.

A crease that runs across a quad from corner to corner has no quad-edge path along it: any path turns
inside that quad. Merging the quad's other two corners into one vertex on the crease removes the quad and
joins the quads on either side along the crease (`cam.remesh.snap` decides where; this module changes the
arrays). The merged vertex takes both corners' other quads, so its valence is the sum of theirs less two,
and the two corners on the crease each lose one.
"""

from __future__ import annotations

import numpy as np

__all__ = ["collapse_diagonals"]


def collapse_diagonals(vertices: np.ndarray, quads: np.ndarray, collapses: list[tuple[int, int, int]]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Remove quads by merging opposite corners, and drop the merged-away vertices.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        The quad mesh's vertices, mm; a kept corner stays where it is here.
    quads : (m, 4) array_like of int
        Its quads.
    collapses : list of (quad, keep, drop)
        Each removes quad ``quad`` and puts vertex ``keep`` wherever vertex ``drop`` was used; ``keep`` and
        ``drop`` are opposite corners of that quad. A vertex is dropped by one collapse at most and is then
        kept by none; a quad is collapsed once at most.

    Returns
    -------
    vertices : (n - k, 3) ndarray of float64
        Without the k dropped vertices, the others in their order.
    quads : (m - k, 4) ndarray of int64
        Without the collapsed quads, the others in their order, renumbered.

    Raises
    ------
    ValueError
        When a collapse names a quad out of range or collapsed twice, corners that are not opposite in that
        quad, or a vertex that another collapse drops, or drops one that another keeps.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(quads, dtype=np.int64)
    dropped: dict[int, int] = {}
    removed: set[int] = set()
    kept_by: set[int] = set()
    for q, keep, drop in collapses:
        if not (0 <= q < len(faces)) or q in removed:
            raise ValueError(f"collapse of quad {q}: out of range 0..{len(faces) - 1} or collapsed twice")
        corners = faces[q].tolist()
        if keep not in corners or drop not in corners or (corners.index(keep) - corners.index(drop)) % 4 != 2:
            raise ValueError(f"collapse of quad {q} {corners}: {keep} and {drop} are not opposite corners")
        if drop in dropped or keep in dropped or drop in kept_by:
            raise ValueError(f"collapse of quad {q}: vertex {drop if drop in dropped or drop in kept_by else keep} "
                             "is dropped or kept by another collapse")
        dropped[drop] = keep
        kept_by.add(keep)
        removed.add(q)
    target = np.arange(len(verts))
    for drop, keep in dropped.items():
        target[drop] = keep
    kept = np.ones(len(verts), dtype=bool)
    kept[list(dropped)] = False
    number = np.cumsum(kept) - 1
    faces_kept = np.ones(len(faces), dtype=bool)
    faces_kept[list(removed)] = False
    return verts[kept], number[target[faces[faces_kept]]]
