"""Patches between clipping edges, each checked as a sharp height field: a rectangular rows × cols quad grid.

:func:`grid_of_patch` walks the patch from one corner, row by row, the way a
B-spline fit will read it, and reports the first condition that fails: no
corner, a row that ends early or late, a clipping or sharp edge inside, a face
reached twice or not at all, an extraordinary vertex inside. Success gives the
vertex grid (rows + 1) × (cols + 1), its four corners and four sides.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam.mesh.quads import QuadTopology

__all__ = ["PatchGrid", "grid_of_patch"]


@dataclass(frozen=True, eq=False)
class PatchGrid:
    """One patch of the domain topology.

    Attributes
    ----------
    faces
        int64 (k,): face ids (of the topology the patch was found in).
    rows, cols
        Grid size in quads (0 when invalid).
    grid
        int64 (rows + 1, cols + 1): vertex ids; row 0 starts at ``corners[0]``.
    face_grid
        int64 (rows, cols): face ids in grid order.
    corners
        The four corner vertices, in order around the patch (grid [0,0],
        [0,cols], [rows,cols], [rows,0]).
    problems
        Empty for a valid patch, else what failed (first failure only).
    """

    faces: np.ndarray
    rows: int = 0
    cols: int = 0
    grid: np.ndarray = field(default_factory=lambda: np.empty((0, 0), dtype=np.int64))
    face_grid: np.ndarray = field(default_factory=lambda: np.empty((0, 0), dtype=np.int64))
    corners: tuple[int, ...] = ()
    problems: tuple[str, ...] = ()

    @property
    def valid(self) -> bool:
        return not self.problems

    def sides(self) -> list[list[int]]:
        """The four boundary polylines as vertex ids, corner to corner, counter-clockwise ([] when invalid)."""
        g = self.grid
        if g.size == 0:
            return []
        return [g[0, :].tolist(), g[:, -1].tolist(), g[-1, ::-1].tolist(), g[::-1, 0].tolist()]


def grid_of_patch(topo: QuadTopology, cut: np.ndarray, sharp: np.ndarray, faces: np.ndarray) -> PatchGrid:
    """Check one patch and read its grid.

    Parameters
    ----------
    topo
        Connectivity of the domain.
    cut
        bool (ne,): clipping edges (the patch's boundary), indexed like ``topo.edges``.
    sharp
        bool (ne,): sharp edges (none may lie inside a patch), indexed like ``topo.edges``.
    faces
        int (k,): the patch's face ids in ``topo``.

    Returns
    -------
    PatchGrid
        The grid read from the patch; when it is not a rectangular grid, a patch with only ``faces``
        (int64 (k,)) and ``problems`` naming the first condition that failed.
    """
    faces = np.asarray(faces, dtype=np.int64)
    try:
        corner = _find_corner(topo, cut, faces)
        states = _walk_rows(topo, cut, corner, len(faces))
        grid, face_grid = _read_grid(topo, cut, sharp, states, set(faces.tolist()))
        _check_inside(topo, grid)
    except _NotAGrid as exc:
        return PatchGrid(faces=faces, problems=(str(exc),))
    rows, cols = face_grid.shape
    corners = (int(grid[0, 0]), int(grid[0, cols]), int(grid[rows, cols]), int(grid[rows, 0]))
    return PatchGrid(faces=faces, rows=rows, cols=cols, grid=grid, face_grid=face_grid, corners=corners)


class _NotAGrid(Exception):
    """The patch is no rectangular grid; the message says why (it becomes the patch's problem)."""


#: A face and the corner of it that plays the grid cell's corner [0, 0].
_Cell = tuple[int, int]


def _find_corner(topo: QuadTopology, cut: np.ndarray, faces: np.ndarray) -> _Cell:
    """The first face (in ``faces`` order) with two consecutive clipping edges, and the corner between them."""
    edge_of = topo.edge_of.reshape(-1, 4)
    for f in faces.tolist():
        c = cut[edge_of[f]]
        for i in range(4):
            if c[i] and c[(i + 3) % 4]:
                return (f, i)
    raise _NotAGrid("it has no corner: not a disk (a band around a cylinder or a closed surface)")


def _step_u(topo: QuadTopology, cut: np.ndarray, cell: _Cell) -> _Cell | None:
    """The next cell along the row, or None at a clipping edge."""
    f, i = cell
    if cut[topo.edge_of[4 * f + (i + 1) % 4]]:
        return None
    g = int(topo.twin[4 * f + (i + 1) % 4])
    return (g // 4, (g % 4 + 1) % 4)


def _step_v(topo: QuadTopology, cut: np.ndarray, cell: _Cell) -> _Cell | None:
    """The next cell down the column, or None at a clipping edge."""
    f, i = cell
    if cut[topo.edge_of[4 * f + (i + 2) % 4]]:
        return None
    g = int(topo.twin[4 * f + (i + 2) % 4])
    return (g // 4, g % 4)


def _walk_rows(topo: QuadTopology, cut: np.ndarray, corner: _Cell, n_faces: int) -> list[list[_Cell]]:
    """The cells row by row from ``corner``: down its column, then along each row to a clipping edge.

    Raises _NotAGrid when a row's length differs from the first's or the rows miss faces.
    """
    limit = n_faces + 1  # a walk longer than the patch has faces is going round in circles
    first_col = [corner]
    while len(first_col) <= limit:
        nxt = _step_v(topo, cut, first_col[-1])
        if nxt is None:
            break
        first_col.append(nxt)
    states: list[list[_Cell]] = []
    for r, s in enumerate(first_col):
        row = [s]
        while len(row) <= limit:
            nxt = _step_u(topo, cut, row[-1])
            if nxt is None:
                break
            row.append(nxt)
        if r and len(row) != len(states[0]):
            raise _NotAGrid(f"row {r} has {len(row)} quads but row 0 has {len(states[0])}: not a rectangle "
                            "(an L-shape or a corner where the boundary turns inward)")
        states.append(row)
    rows, cols = len(states), len(states[0])
    if rows * cols != n_faces:
        raise _NotAGrid(f"its {rows} × {cols} grid covers {rows * cols} of its {n_faces} quads "
                        "(a hole, a slit or an extraordinary vertex inside)")
    return states


def _read_grid(topo: QuadTopology, cut: np.ndarray, sharp: np.ndarray, states: list[list[_Cell]],
               in_patch: set[int]) -> tuple[np.ndarray, np.ndarray]:
    """The vertex grid int64 (rows + 1, cols + 1) and face grid int64 (rows, cols) of the walked cells.

    Raises _NotAGrid where a cell is reached twice or lies outside the patch, where clipping edges are not
    exactly on the rectangle's sides, where a sharp edge is inside, or where rows or vertices disagree.
    """
    edge_of = topo.edge_of.reshape(-1, 4)
    quads = topo.faces
    rows, cols = len(states), len(states[0])
    grid = np.full((rows + 1, cols + 1), -1, dtype=np.int64)
    face_grid = np.empty((rows, cols), dtype=np.int64)
    seen: set[int] = set()
    for r in range(rows):
        for c in range(cols):
            f, i = states[r][c]
            if f in seen or f not in in_patch:
                raise _NotAGrid(f"the grid walk reaches quad {f} twice or leaves the patch: not a disk")
            seen.add(f)
            face_grid[r, c] = f
            _check_cell_edges(cut[edge_of[f]], sharp[edge_of[f]], f, i, on_side=(r == 0, c == cols - 1,
                                                                                   r == rows - 1, c == 0))
            if r + 1 < rows and _step_v(topo, cut, (f, i)) != states[r + 1][c]:
                raise _NotAGrid(f"rows {r} and {r + 1} do not line up at quad {f}: an extraordinary vertex inside")
            corners_v = (quads[f, i], quads[f, (i + 1) % 4], quads[f, (i + 2) % 4], quads[f, (i + 3) % 4])
            for (dr, dc), v in zip(((0, 0), (0, 1), (1, 1), (1, 0)), corners_v):
                if grid[r + dr, c + dc] == -1:
                    grid[r + dr, c + dc] = v
                elif grid[r + dr, c + dc] != v:
                    raise _NotAGrid(f"grid vertex ({r + dr}, {c + dc}) is both {grid[r + dr, c + dc]} and {v}: "
                                    "an extraordinary vertex inside")
    return grid, face_grid


def _check_cell_edges(cut_edges: np.ndarray, sharp_edges: np.ndarray, f: int, i: int,
                      on_side: tuple[bool, bool, bool, bool]) -> None:
    """Raise _NotAGrid unless face ``f``'s edges are clipping exactly on the patch's sides and none inside is sharp.

    ``cut_edges``, ``sharp_edges``: bool (4,) per edge of the face; ``on_side``: the cell lies on the bottom,
    right, top, left side of the grid, whose edges are the face's edges i, i + 1, i + 2, i + 3.
    """
    expect = {(i + k) % 4: want for k, want in enumerate(on_side)}
    for k, want in expect.items():
        if bool(cut_edges[k]) != want:
            where = "inside" if not want else "missing on its boundary"
            raise _NotAGrid(f"a clipping edge is {where} at quad {f}: not a rectangle")
    if sharp_edges[[k for k, want in expect.items() if not want]].any():
        raise _NotAGrid(f"a sharp edge lies inside it at quad {f}")


def _check_inside(topo: QuadTopology, grid: np.ndarray) -> None:
    """Raise _NotAGrid when a vertex inside the grid is irregular or appears twice."""
    inner = grid[1:-1, 1:-1].reshape(-1)
    if not len(inner):
        return
    bad = inner[(topo.valence[inner] != 4) | topo.boundary_vertex[inner]]
    if len(bad):
        raise _NotAGrid(f"extraordinary vertex {int(bad[0])} lies inside it")
    if len(np.unique(inner)) != len(inner):
        raise _NotAGrid("a vertex appears twice inside its grid: not a disk")
