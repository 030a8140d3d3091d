"""Moving quad-grid points onto the creases of the triangle mesh (found by `cam.mesh.creases`).

Patches meet along sharp edges of the quad mesh, but the remesher puts those a
little beside the real crease of the denoised mesh (often a few tenths of a mm).
A patch border left there cuts the corner off one face and adds a sliver to the
other, an error of the offset times the sine of the crease angle. So quad vertices
on sharp borders are moved onto the mesh's own crease lines (edges whose dihedral
angle exceeds a threshold), and onto a crease corner (three or more crease lines
meeting) where the quad vertex is a corner of the sharp-edge network too.
"""

from __future__ import annotations

import numpy as np

from cam.mesh.creases import Creases, closest_on_creases

__all__ = ["snap_points", "edge_keys", "vertex_positions"]


def snap_points(creases: Creases, points: np.ndarray, radius: np.ndarray, *, corner: np.ndarray | None = None,
                first: np.ndarray | None = None,
                directions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Move points (n, 3) onto the creases where one lies within `radius` (n,) mm.

    corner bool (n,): these may go to a crease corner within their radius first, one point per
    crease corner: the nearest, except that points flagged in `first` (bool (n,)) choose before
    the others do.
    directions float64 (n, 3): the direction of the sharp edge each point lies on (zero: any);
    only a crease running within 30 degrees of it takes the point (see `closest_on_creases`).
    Returns the points float64 (n, 3) and bool (n,) which of them moved.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3).copy()
    radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(P),))
    moved = np.zeros(len(P), dtype=bool)
    if corner is not None and creases.corner_tree is not None:
        sel = np.flatnonzero(np.asarray(corner, dtype=bool))
        if sel.size:
            d, i = creases.corner_tree.query(P[sel])
            ok = d <= radius[sel]
            # One point per crease corner, the nearest: two quad vertices on one corner would
            # collapse the edge between them.
            ahead = np.zeros(sel.size, dtype=bool) if first is None else np.asarray(first, dtype=bool)[sel]
            order = np.lexsort((d, ~ahead))
            taken: set[int] = set()
            for o in order[ok[order]].tolist():
                if int(i[o]) in taken:
                    ok[o] = False
                taken.add(int(i[o]))
            P[sel[ok]] = creases.corners[i[ok]]
            moved[sel[ok]] = True
    rest = np.flatnonzero(~moved)
    q, d = closest_on_creases(creases, P[rest],
                              directions=None if directions is None else np.asarray(directions)[rest])
    ok = d <= radius[rest]
    P[rest[ok]] = q[ok]
    moved[rest[ok]] = True
    return P, moved


def edge_keys(edges: np.ndarray | None) -> set[tuple[int, int]]:
    """Undirected vertex pairs (int (k, 2)) as a set of sorted tuples."""
    if edges is None:
        return set()
    E = np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1)
    return set(map(tuple, E.tolist()))


def vertex_positions(vertices: np.ndarray, grids: list[np.ndarray], index, *, sharp: set[tuple[int, int]],
                     creases: Creases | None, snap_radius_quads: float = 1.0) -> np.ndarray:
    """Where each quad-mesh vertex of the grids sits on the mesh: float64 (k, 3), NaN for vertices in no grid.

    Vertices on a sharp patch border (an edge of the grid's outline in `sharp`) move onto the
    mesh's creases if one is within `snap_radius_quads` times their mean edge length; a vertex where
    sharp edges meet at an angle (or three or more meet) may go to a crease corner instead, one
    nearer to it than to its sharp neighbours.
    Every other vertex goes to its closest mesh point.
    """
    from cam.mesh.closest import closest_points

    V = np.asarray(vertices, dtype=np.float64)
    used = np.unique(np.concatenate([np.asarray(g).ravel() for g in grids]))
    out = np.full(V.shape, np.nan)
    out[used] = closest_points(index, V[used])[0]
    if creases is None or creases.tree is None or not sharp:
        return out
    border_sharp: dict[int, list[int]] = {}
    length: dict[int, list[float]] = {}
    for g in grids:
        g = np.asarray(g)
        for a, b in zip(*np.broadcast_arrays(g[:, :-1], g[:, 1:])):
            for x, y in zip(a.tolist(), b.tolist()):
                d = float(np.linalg.norm(V[x] - V[y]))
                length.setdefault(x, []).append(d)
                length.setdefault(y, []).append(d)
        for a, b in zip(*np.broadcast_arrays(g[:-1, :], g[1:, :])):
            for x, y in zip(a.tolist(), b.tolist()):
                d = float(np.linalg.norm(V[x] - V[y]))
                length.setdefault(x, []).append(d)
                length.setdefault(y, []).append(d)
        outline = np.concatenate([g[0, :], g[1:, -1], g[-1, -2::-1], g[-2:0:-1, 0]])
        for x, y in zip(outline.tolist(), np.roll(outline, -1).tolist()):
            if (min(x, y), max(x, y)) in sharp:
                border_sharp.setdefault(x, []).append(y)
                border_sharp.setdefault(y, []).append(x)
    ids = np.array(sorted(border_sharp), dtype=np.int64)
    if not ids.size:
        return out
    corner = np.zeros(ids.size, dtype=bool)
    # The way the sharp edges run through a vertex; a corner may take a crease of any direction.
    direction = np.zeros((ids.size, 3))
    for n, vid in enumerate(ids.tolist()):
        others = sorted(set(border_sharp[vid]))
        if len(others) >= 3:
            corner[n] = True
        elif len(others) == 2:
            d1, d2 = V[others[0]] - V[vid], V[others[1]] - V[vid]
            cos = d1 @ d2 / max(np.linalg.norm(d1) * np.linalg.norm(d2), 1e-300)
            corner[n] = cos > -np.cos(np.radians(30.0))  # not a straight continuation
            direction[n] = 0.0 if corner[n] else V[others[1]] - V[others[0]]
        else:
            direction[n] = V[others[0]] - V[vid]
    radius = snap_radius_quads * np.array([np.mean(length[v]) for v in ids.tolist()])
    start = out[ids].copy()
    # A junction of three or more sharp edges goes to a crease corner where as many creases meet
    # before a vertex where the sharp row only bends may take it: the bend can sit nearer the
    # corner (the remesher's junction a quad edge off it), but only the junction has the corner's
    # creases for its sides.
    junction = np.array([len(set(border_sharp[v])) >= 3 for v in ids.tolist()])
    snapped = snap_points(creases, start, radius, corner=corner, first=junction, directions=direction)[0]
    # A corner takes no crease corner that lies nearer one of its sharp neighbours than itself:
    # that is the neighbour's place (a crease that bends just before it ends on the part's
    # border has a crease corner at its end, and the vertex before the end would take it);
    # except a junction on a junction of creases.
    row = {v: n for n, v in enumerate(ids.tolist())}
    meets = _on_crease_junction(creases, snapped) & junction
    gone = [n for n in np.flatnonzero(corner & ~meets).tolist()
            if any(np.linalg.norm(snapped[n] - start[row[o]]) < np.linalg.norm(snapped[n] - start[n])
                   for o in border_sharp[int(ids[n])])]
    if gone:
        snapped[gone] = snap_points(creases, start[gone], radius[gone])[0]
    out[ids] = snapped
    return out


def _on_crease_junction(creases: Creases, points: np.ndarray) -> np.ndarray:
    """bool (n,): which points (n, 3) sit on a crease corner where three or more creases meet."""
    if creases.corner_tree is None or not len(points):
        return np.zeros(len(points), dtype=bool)
    d, i = creases.corner_tree.query(points)
    return (d <= 1e-12) & (creases.corner_degree[i] >= 3)
