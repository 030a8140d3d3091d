"""The motorcycle-graph partition, the baseline the MST segmentation is measured against.

Every grid line leaving an extraordinary point, an inward boundary corner or a
vertex where a sharp curve turns (and every loose end of a sharp curve,
continued straight on) is a motorcycle; all move one edge per
step, and each stops on reaching any vertex already on a track, on a sharp
edge or on the boundary (the walls), or where straight-on is undefined.
"""

from __future__ import annotations

import numpy as np

from cam.mesh.quads import QuadTopology, vertex_fans

__all__ = ["motorcycle_cuts"]


def motorcycle_cuts(topo: QuadTopology, straight: np.ndarray, extraordinary: np.ndarray,
                    sharp: np.ndarray) -> np.ndarray:
    """Clipping edges of the motorcycle graph.

    Parameters
    ----------
    topo
        Connectivity of the domain.
    straight
        int64 (4m,): its :func:`cam.segment.traces.straight_continuation`.
    extraordinary
        bool (n,): vertices whose lines are traced (EPs).
    sharp
        bool (ne,): sharp edges (walls, and their loose ends start motorcycles), indexed like ``topo.edges``.

    Returns
    -------
    ndarray
        bool (ne,): the clipping edges, sharp and boundary edges included, indexed like ``topo.edges``.
    """
    cut = sharp | topo.boundary_edge
    edge_of, dest = topo.edge_of, topo.dest
    occupied = np.zeros(topo.n_vertices, dtype=bool)
    occupied[topo.edges[cut].reshape(-1)] = True
    occupied |= extraordinary
    riders: list[int] = []
    # Boundary vertices with 3+ faces (inward corners) need lines too, like EPs.
    concave = topo.boundary_vertex & (topo.face_count >= 3)
    for v in np.flatnonzero(extraordinary | concave).tolist():
        riders += [h for h in topo.outgoing(v).tolist() if not cut[edge_of[h]]]
    sharp_degree = np.bincount(topo.edges[sharp].reshape(-1), minlength=topo.n_vertices)
    regular = topo.regular_interior()
    # Where a sharp curve turns or branches at a regular vertex, that vertex is singular for the
    # partition (a patch there would have an inward corner): its other lines ride too.
    for v in np.flatnonzero(regular & (sharp_degree >= 2)).tolist():
        out = topo.outgoing(v).tolist()
        s_out = [h for h in out if sharp[edge_of[h]]]
        straight_through = len(s_out) == 2 and straight[int(topo.twin[s_out[0]])] == s_out[1]
        if not straight_through:
            riders += [h for h in out if not cut[edge_of[h]]]
    for v in np.flatnonzero((sharp_degree == 1) & regular).tolist():
        # The loose end of a sharp curve: continue the curve's own line straight on.
        for fan, _ in vertex_fans(topo, v):
            for h in fan:
                if sharp[edge_of[h]]:
                    twin = int(topo.twin[h])
                    if twin >= 0 and straight[twin] >= 0:
                        riders.append(int(straight[twin]))
    active = riders
    while active:
        moving = []
        for h in active:
            e = edge_of[h]
            if cut[e]:
                continue
            cut[e] = True
            w = int(dest[h])
            if occupied[w] or straight[h] < 0:
                occupied[w] = True
                continue
            occupied[w] = True
            moving.append(int(straight[h]))
        active = moving
    return cut
