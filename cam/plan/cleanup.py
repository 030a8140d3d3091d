"""Clean-up passes: the ball taken to every sample the other passes left over the target.

Each such sample gets the ball that touches it (centre r along its normal, lifted to the drop-cutter
height where that ball would cut the part elsewhere: in a concave corner it then rides on both faces,
a pencil pass). Neighbouring samples are chained into passes: a leftover band along a corner or the
foot of a wall becomes one pass along it, a patch a zig-zag over it.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from cam.plan.lines import follow_part, merge_straight
from cam.plan.part import REACH_TOL_MM, SetupPart

__all__ = ["cleanup_passes"]


def _chains(points: np.ndarray, link_mm: float) -> list[np.ndarray]:
    """Index chains over ball centres (k, 3): per connected group (neighbours within link_mm), a zig-zag
    along its longest direction in strips link_mm wide across its second, split where two consecutive
    points are far apart. In 3-D, not in xy: a leftover band up a wall is zig-zagged over the wall, not
    up and down it."""
    if not len(points):
        return []
    pairs = cKDTree(points).query_pairs(link_mm, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
    _, label = connected_components(graph, directed=False)
    chains = []
    for group in np.unique(label):
        idx = np.flatnonzero(label == group)
        p = points[idx] - points[idx].mean(axis=0)
        if len(idx) > 1:
            _, _, vt = np.linalg.svd(p, full_matrices=False)
            along, across = p @ vt[0], p @ vt[1] if len(vt) > 1 else np.zeros(len(p))
        else:
            along, across = np.zeros(1), np.zeros(1)
        strip = np.floor((across - across.min()) / link_mm).astype(np.int64)
        order = np.lexsort((np.where(strip % 2, -along, along), strip))
        chain = idx[order]
        gaps = np.linalg.norm(np.diff(points[chain], axis=0), axis=1) > 2 * link_mm
        chains += np.split(chain, np.flatnonzero(gaps) + 1)
    return chains


def cleanup_passes(part: SetupPart, points: np.ndarray, normals: np.ndarray, *, chord_mm: float,
                   link_mm: float) -> list[np.ndarray]:
    """Passes of ball centres through the balls touching each sample.

    Parameters
    ----------
    part : SetupPart
        The part in the setup's machine frame, for the ball.
    points, normals : (k, 3) float
        Samples left over the target, machine frame, and their outward unit normals.
    chord_mm : float
        The chord share (moves between samples are refined like any pass).
    link_mm : float
        Samples this close belong to one group; the zig-zag's strip width.

    Returns
    -------
    list of (n_i, 3) float64
        Ball centres, mm, machine frame.
    """
    r = part.radius_mm
    centre = np.asarray(points, dtype=np.float64) + (r + REACH_TOL_MM) * np.asarray(normals, dtype=np.float64)
    ok = np.all(np.isfinite(centre), axis=1)
    centre = centre[ok]
    if not len(centre):
        return []
    centre[:, 2] = np.maximum(centre[:, 2], part.drop(centre[:, :2]))
    passes = []
    for chain in _chains(centre, link_mm):
        pts, _ = follow_part(part, centre[chain], chord_mm=chord_mm, lift_mm=0.5 * chord_mm)
        passes.append(merge_straight(pts))
    return passes
