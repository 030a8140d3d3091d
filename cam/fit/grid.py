"""A patch's quads as a rectangular vertex grid: the initial control net and parameterisation seed.

The segment stage lists a patch as a set of quad faces, its row and column counts
and its four corners; `patch_grid` walks the faces from the first corner and
returns the (rows + 1) x (cols + 1) grid of vertex ids. The walk follows each
quad's own vertex order, so S_u x S_v of a surface fitted on the grid points the
way the quads' normals point.

A patch whose faces are no such grid raises `PatchGridError`: the patch layout (segment's output)
is what to change, not the fit.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from cam import GeometryError

__all__ = ["PatchGridError", "patch_grid", "orient_grid"]


class PatchGridError(GeometryError):
    """A patch's faces (or its listed grid) are not one rectangular grid of quads of the quad mesh."""


def patch_grid(quads: np.ndarray, faces: np.ndarray, *, corner: int | None = None,
               rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """Vertex ids of a patch as a grid, index [i, j] with i along u.

    Parameters
    ----------
    quads : ndarray, shape (m, 4), int
        Faces of the quad mesh (counter-clockwise seen from outside), vertex ids.
    faces : ndarray, shape (k,), int
        The patch's face indices into `quads`.
    corner : int or None
        Vertex id to put at [0, 0] (a patch corner); None: the corner with the smallest id.
    rows, cols : int or None
        The expected quad counts (R x C or C x R is accepted, the grid keeps the orientation that
        puts `corner` first); None: not checked.

    Returns
    -------
    ndarray, shape (R + 1, C + 1), int64
        The grid's vertex ids; [i + 1, j] follows [i, j] in the quads' own vertex order, so
        S_u x S_v of a surface fitted on it points the way the quads' normals point.

    Raises
    ------
    PatchGridError
        When the faces do not form one rectangular grid, or not of rows x cols quads.
    ValueError
        When `quads` is not (m, 4).
    """
    Q = np.asarray(quads, dtype=np.int64)
    if Q.ndim != 2 or Q.shape[1] != 4:
        raise ValueError(f"quads must have shape (m, 4), got {Q.shape}")
    fids = _face_ids(faces, len(Q))
    edge_faces = _edge_faces(Q, fids)
    incident: dict[int, list[int]] = {}
    for f in fids:
        for vtx in Q[f]:
            incident.setdefault(int(vtx), []).append(f)
    corner = _first_corner(Q, incident, edge_faces, corner)
    pos, grid = _walk_faces(Q, incident[int(corner)][0], int(corner), edge_faces)
    return _grid_array(pos, grid, len(fids), rows=rows, cols=cols)


def _face_ids(faces: np.ndarray, count: int) -> list[int]:
    """The patch's face ids as a list, each once and among the `count` quads."""
    fids = [int(f) for f in np.asarray(faces, dtype=np.int64).ravel()]
    if not fids:
        raise PatchGridError("a patch needs at least one face")
    if min(fids) < 0 or max(fids) >= count:
        raise PatchGridError(f"patch face ids must lie in 0..{count - 1}")
    if len(set(fids)) != len(fids):
        raise PatchGridError("patch lists a face twice")
    return fids


def _edge_faces(Q: np.ndarray, fids: list[int]) -> dict[tuple[int, int], list[int]]:
    """The patch's faces along each of its edges (sorted vertex pair): one on its border, two inside."""
    edge_faces: dict[tuple[int, int], list[int]] = {}
    for f in fids:
        for a in range(4):
            e = _key(Q[f, a], Q[f, (a + 1) % 4])
            edge_faces.setdefault(e, []).append(f)
    if any(len(v) > 2 for v in edge_faces.values()):
        raise PatchGridError("patch faces share an edge more than twice (non-manifold)")
    return edge_faces


def _first_corner(Q: np.ndarray, incident: dict[int, list[int]], edge_faces: dict, corner: int | None) -> int:
    """The vertex to put at [0, 0]: `corner`, checked, or the corner of the patch with the smallest id."""
    if corner is None:
        corners = [v for v, fs in incident.items() if len(fs) == 1 and _is_corner(Q[fs[0]], v, edge_faces)]
        if not corners:
            raise PatchGridError("patch has no corner (a vertex in one face with two boundary edges)")
        corner = min(corners)
    if len(incident.get(int(corner), [])) != 1:
        raise PatchGridError(f"vertex {corner} is not a corner of the patch (it is in "
                         f"{len(incident.get(int(corner), []))} of its faces)")
    return corner


def _walk_faces(Q: np.ndarray, start: int, corner: int, edge_faces: dict
                ) -> tuple[dict[int, tuple[int, int]], dict[tuple[int, int], int]]:
    """Each face's cell (i, j) and each grid point's vertex id, reached breadth first from `start`,
    the face at `corner`."""
    cyc = list(Q[start])
    a = cyc.index(corner)
    # [i + 1, j] follows the corner in the face's own order, [i, j + 1] precedes it: S_u x S_v = quad normal.
    pos: dict[int, tuple[int, int]] = {start: (0, 0)}
    grid: dict[tuple[int, int], int] = {(0, 0): cyc[a], (1, 0): cyc[(a + 1) % 4], (1, 1): cyc[(a + 2) % 4],
                                        (0, 1): cyc[(a + 3) % 4]}
    queue = deque([start])
    while queue:
        f = queue.popleft()
        i, j = pos[f]
        corners4 = {(0, 0): grid[(i, j)], (1, 0): grid[(i + 1, j)], (1, 1): grid[(i + 1, j + 1)],
                    (0, 1): grid[(i, j + 1)]}
        # Each side of the cell: the two shared corners, and the offset of the neighbouring cell.
        for (s0, s1), (di, dj) in ((((1, 0), (1, 1)), (1, 0)), (((0, 1), (1, 1)), (0, 1)),
                                   (((0, 0), (0, 1)), (-1, 0)), (((0, 0), (1, 0)), (0, -1))):
            va, vb = corners4[s0], corners4[s1]
            others = [g for g in edge_faces[_key(va, vb)] if g != f]
            if not others:
                continue
            g = others[0]
            ni, nj = i + di, j + dj
            if g in pos:
                if pos[g] != (ni, nj):
                    raise PatchGridError("patch faces do not form a rectangular grid (a face is reached twice)")
                continue
            cg = list(Q[g])
            if va not in cg or vb not in cg:
                raise PatchGridError("inconsistent quad connectivity")
            # Across side (va, vb) the far corners are the neighbours of va and vb in g not on the side.
            far_a = _other_neighbour(cg, va, vb)
            far_b = _other_neighbour(cg, vb, va)
            for (ci, cj), vid in _far_slots(s0, s1, i, j, di, dj, far_a, far_b).items():
                if grid.setdefault((ci, cj), vid) != vid:
                    raise PatchGridError("patch faces do not form a rectangular grid (a grid point is claimed twice)")
            pos[g] = (ni, nj)
            queue.append(g)
    return pos, grid


def _grid_array(pos: dict[int, tuple[int, int]], grid: dict[tuple[int, int], int], faces: int, *,
                rows: int | None, cols: int | None) -> np.ndarray:
    """The walk's grid as an int64 (R + 1, C + 1) array, once it is checked to be one rectangle of all
    the `faces` (of rows x cols where given) without a repeated vertex."""
    if len(pos) != faces:
        raise PatchGridError(f"patch faces are not connected: reached {len(pos)} of {faces}")
    ij = np.array(list(pos.values()))
    if ij.min() < 0:
        raise PatchGridError("patch faces do not form a rectangular grid (the corner is not a grid corner)")
    R, C = ij[:, 0].max() + 1, ij[:, 1].max() + 1
    if R * C != faces:
        raise PatchGridError(f"patch faces do not form a rectangular grid: {faces} faces in a {R} x {C} box")
    if rows is not None and cols is not None and sorted((R, C)) != sorted((int(rows), int(cols))):
        raise PatchGridError(f"patch says {rows} x {cols} quads but its faces form {R} x {C}")
    out = np.empty((R + 1, C + 1), dtype=np.int64)
    for i in range(R + 1):
        for j in range(C + 1):
            out[i, j] = grid[(i, j)]
    if len(np.unique(out)) != out.size:
        raise PatchGridError("patch grid repeats a vertex (a closed or pinched patch)")
    return out


def _key(a: int, b: int) -> tuple[int, int]:
    a, b = int(a), int(b)
    return (a, b) if a < b else (b, a)


def _is_corner(face: np.ndarray, v: int, edge_faces: dict) -> bool:
    cyc = [int(x) for x in face]
    k = cyc.index(v)
    return len(edge_faces[_key(v, cyc[(k + 1) % 4])]) == 1 and len(edge_faces[_key(v, cyc[(k - 1) % 4])]) == 1


def _other_neighbour(cyc: list[int], v: int, exclude: int) -> int:
    k = cyc.index(v)
    a, b = cyc[(k + 1) % 4], cyc[(k - 1) % 4]
    return b if a == exclude else a


def _far_slots(s0, s1, i, j, di, dj, far_a, far_b) -> dict[tuple[int, int], int]:
    """Grid slots of the two far corners of the neighbouring cell across side (s0, s1)."""
    (a0, a1), (b0, b1) = s0, s1
    return {(i + a0 + di, j + a1 + dj): far_a, (i + b0 + di, j + b1 + dj): far_b}


def orient_grid(quads: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """A patch's grid, transposed if needed so that S_u x S_v follows the quads' normals.

    The quad holding grid[0, 0], grid[1, 0], grid[1, 1], grid[0, 1] must list them in that cyclic
    order; listed the other way round the grid is transposed.

    Parameters
    ----------
    quads : ndarray, shape (m, 4), int
        Faces of the quad mesh, vertex ids.
    grid : ndarray, shape (R + 1, C + 1), int
        The patch's vertex ids (as patches.json lists them).

    Returns
    -------
    ndarray, shape (R + 1, C + 1) or (C + 1, R + 1), int64
        `grid`, or a transposed copy of it.

    Raises
    ------
    PatchGridError
        When the grid is not (R + 1, C + 1) with R, C >= 1, names a vertex that is in no quad of
        `quads`, or no quad has the four corners of its first cell.
    """
    g = np.asarray(grid, dtype=np.int64)
    # The grid comes from patches.json as it is: its shape and ids are the file's, not a program's.
    if g.ndim != 2 or min(g.shape) < 2:
        raise PatchGridError(f"the patch's grid must be (R + 1, C + 1) vertex ids with R, C >= 1, "
                             f"got shape {g.shape}")
    Q = np.asarray(quads, dtype=np.int64)
    if not np.isin(g, Q).all():
        raise PatchGridError(f"the patch's grid names vertices in no quad of the quad mesh: "
                             f"{np.unique(g[~np.isin(g, Q)])[:5].tolist()}")
    cell = {int(g[0, 0]), int(g[1, 0]), int(g[1, 1]), int(g[0, 1])}
    hits = np.flatnonzero(np.isin(Q, list(cell)).all(axis=1))
    for f in hits:
        cyc = [int(x) for x in Q[f]]
        if set(cyc) != cell:
            continue
        a = cyc.index(int(g[0, 0]))
        if cyc[(a + 1) % 4] == int(g[1, 0]):
            return g
        if cyc[(a + 1) % 4] == int(g[0, 1]):
            return g.T.copy()
    raise PatchGridError("no quad has the grid's first cell as its corners")
