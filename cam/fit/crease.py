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

from cam.mesh.closest import MeshIndex, closest_points
from cam.mesh.creases import Creases, closest_on_creases

__all__ = ["edge_keys", "is_sharp_polyline", "sharp_edge_mask", "snap_points", "vertex_positions"]


def snap_points(creases: Creases, points: np.ndarray, radius: np.ndarray, *, corner: np.ndarray | None = None,
                first: np.ndarray | None = None,
                directions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Move points onto the creases where one lies within their radius.

    Parameters
    ----------
    creases : Creases
        The mesh's creases (`cam.mesh.creases.mesh_creases`).
    points : ndarray, shape (n, 3), float64
        The points, mm.
    radius : ndarray, shape (n,), float64
        How far each may move, mm.
    corner : ndarray, shape (n,), bool, or None
        These may go to a crease corner within their radius first, one point per crease corner:
        the nearest, except that points flagged in `first` choose before the others do.
    first : ndarray, shape (n,), bool, or None
        See `corner`.
    directions : ndarray, shape (n, 3), float64, or None
        The direction of the sharp edge each point lies on (zero: any); only a crease running
        within 30 degrees of it takes the point (see `closest_on_creases`).

    Returns
    -------
    points : ndarray, shape (n, 3), float64
        The points, moved where they moved, mm.
    moved : ndarray, shape (n,), bool
        Which of them moved.
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
    """Undirected vertex pairs as a set of sorted tuples.

    Parameters
    ----------
    edges : ndarray, shape (k, 2), int, or None
        Vertex pairs; None: none.

    Returns
    -------
    set of tuple of int
        (a, b) with a <= b for each pair.
    """
    if edges is None:
        return set()
    E = np.sort(np.asarray(edges, dtype=np.int64).reshape(-1, 2), axis=1)
    return set(map(tuple, E.tolist()))


def vertex_positions(vertices: np.ndarray, grids: list[np.ndarray], index: MeshIndex, *, sharp: set[tuple[int, int]],
                     creases: Creases | None, snap_radius_quads: float = 1.0) -> np.ndarray:
    """Where each quad-mesh vertex of the grids sits on the mesh.

    Vertices on a sharp patch border (an edge of the grid's outline in `sharp`) move onto the
    mesh's creases if one is within `snap_radius_quads` times their mean edge length; a vertex where
    sharp edges meet at an angle (or three or more meet) may go to a crease corner instead, one
    nearer to it than to its sharp neighbours.
    Every other vertex goes to its closest mesh point.

    Parameters
    ----------
    vertices : ndarray, shape (k, 3), float64
        The quad mesh's vertices, mm.
    grids : list of ndarray, each shape (R + 1, C + 1), int
        The patches' vertex ids.
    index : MeshIndex
        The triangle mesh (`cam.mesh.closest.mesh_index`).
    sharp : set of tuple of int
        The sharp edges of the quad mesh (`edge_keys`).
    creases : Creases or None
        The triangle mesh's creases; None: no vertex moves onto one.
    snap_radius_quads : float
        How far a vertex may move onto a crease, in its mean edge lengths.

    Returns
    -------
    ndarray, shape (k, 3), float64
        Each vertex's position, mm; NaN for vertices in no grid.
    """
    V = np.asarray(vertices, dtype=np.float64)
    used = np.unique(np.concatenate([np.asarray(g).ravel() for g in grids]))
    out = np.full(V.shape, np.nan)
    out[used] = closest_points(index, V[used])[0]
    if creases is None or creases.tree is None or not sharp:
        return out
    border_sharp, length = _sharp_borders(V, grids, sharp)
    ids = np.array(sorted(border_sharp), dtype=np.int64)
    if not ids.size:
        return out
    corner, direction = _corners_and_directions(V, ids, border_sharp)
    radius = snap_radius_quads * np.array([np.mean(length[v]) for v in ids.tolist()])
    out[ids] = _snap_border_vertices(creases, ids, out[ids].copy(), radius, corner, direction, border_sharp)
    return out


def _sharp_borders(V: np.ndarray, grids: list[np.ndarray], sharp: set[tuple[int, int]]
                   ) -> tuple[dict[int, list[int]], dict[int, list[float]]]:
    """Per vertex on a sharp patch border, its neighbours along sharp border edges; per grid vertex, the
    lengths (mm) of its grid edges."""
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
    return border_sharp, length


def _corners_and_directions(V: np.ndarray, ids: np.ndarray, border_sharp: dict[int, list[int]]
                            ) -> tuple[np.ndarray, np.ndarray]:
    """For the vertices `ids` (m,) on sharp borders: which are corners of the sharp-edge network (bool
    (m,): three or more sharp edges, or two at an angle), and the direction (m, 3) their sharp edges
    run (zero at a corner)."""
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
    return corner, direction


def _snap_border_vertices(creases: Creases, ids: np.ndarray, start: np.ndarray, radius: np.ndarray,
                          corner: np.ndarray, direction: np.ndarray, border_sharp: dict[int, list[int]]
                          ) -> np.ndarray:
    """The vertices `ids` (m,), at `start` (m, 3) mm on the mesh, moved onto the creases within `radius`
    (m,) mm: corners onto a crease corner first, junctions before bends; (m, 3) mm."""
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
    return snapped


def sharp_edge_mask(vertices: np.ndarray, sharp: set[tuple[int, int]]) -> np.ndarray:
    """Which edges of a vertex polyline are sharp edges.

    Parameters
    ----------
    vertices : ndarray, shape (m,), int
        Vertex ids along the polyline.
    sharp : set of tuple of int
        The sharp edges (`edge_keys`).

    Returns
    -------
    ndarray, shape (m - 1,), bool
    """
    return np.array([(min(a, b), max(a, b)) in sharp
                     for a, b in zip(vertices[:-1].tolist(), vertices[1:].tolist())], dtype=bool)


def is_sharp_polyline(vertices: np.ndarray, sharp: set[tuple[int, int]]) -> bool:
    """Whether most edges of a vertex polyline are sharp edges.

    Parameters
    ----------
    vertices : ndarray, shape (m,), int
        Vertex ids along the polyline.
    sharp : set of tuple of int
        The sharp edges (`edge_keys`).

    Returns
    -------
    bool
        True where at least half its edges are sharp; False without sharp edges or edges.
    """
    if not sharp or len(vertices) < 2:
        return False
    return 2 * int(sharp_edge_mask(vertices, sharp).sum()) >= len(vertices) - 1


def _on_crease_junction(creases: Creases, points: np.ndarray) -> np.ndarray:
    """bool (n,): which points (n, 3) sit on a crease corner where three or more creases meet."""
    if creases.corner_tree is None or not len(points):
        return np.zeros(len(points), dtype=bool)
    d, i = creases.corner_tree.query(points)
    return (d <= 1e-12) & (creases.corner_degree[i] >= 3)
