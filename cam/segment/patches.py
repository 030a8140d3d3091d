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
        bool (ne,): clipping edges (the patch's boundary).
    sharp
        bool (ne,): sharp edges (none may lie inside a patch).
    faces
        int (k,): the patch's faces.
    """
    faces = np.asarray(faces, dtype=np.int64)
    edge_of = topo.edge_of.reshape(-1, 4)
    twin = topo.twin
    in_patch = set(faces.tolist())

    def fail(msg: str) -> PatchGrid:
        return PatchGrid(faces=faces, problems=(msg,))

    corner = None
    for f in faces.tolist():
        c = cut[edge_of[f]]
        for i in range(4):
            if c[i] and c[(i + 3) % 4]:
                corner = (f, i)
                break
        if corner:
            break
    if corner is None:
        return fail("it has no corner: not a disk (a band around a cylinder or a closed surface)")

    def step_u(state: tuple[int, int]) -> tuple[int, int] | None:
        f, i = state
        h = 4 * f + (i + 1) % 4
        if cut[edge_of[f, (i + 1) % 4]]:
            return None
        g = int(twin[h])
        return (g // 4, (g % 4 + 1) % 4)

    def step_v(state: tuple[int, int]) -> tuple[int, int] | None:
        f, i = state
        h = 4 * f + (i + 2) % 4
        if cut[edge_of[f, (i + 2) % 4]]:
            return None
        g = int(twin[h])
        return (g // 4, g % 4)

    limit = len(faces) + 1
    first_col = [corner]
    while len(first_col) <= limit:
        nxt = step_v(first_col[-1])
        if nxt is None:
            break
        first_col.append(nxt)
    rows = len(first_col)
    states: list[list[tuple[int, int]]] = []
    for r, s in enumerate(first_col):
        row = [s]
        while len(row) <= limit:
            nxt = step_u(row[-1])
            if nxt is None:
                break
            row.append(nxt)
        if r and len(row) != len(states[0]):
            return fail(f"row {r} has {len(row)} quads but row 0 has {len(states[0])}: not a rectangle "
                        "(an L-shape or a corner where the boundary turns inward)")
        states.append(row)
    cols = len(states[0])
    if rows * cols != len(faces):
        return fail(f"its {rows} × {cols} grid covers {rows * cols} of its {len(faces)} quads "
                    "(a hole, a slit or an extraordinary vertex inside)")
    quads = topo.faces
    grid = np.full((rows + 1, cols + 1), -1, dtype=np.int64)
    face_grid = np.empty((rows, cols), dtype=np.int64)
    seen: set[int] = set()
    for r in range(rows):
        for c in range(cols):
            f, i = states[r][c]
            if f in seen or f not in in_patch:
                return fail(f"the grid walk reaches quad {f} twice or leaves the patch: not a disk")
            seen.add(f)
            face_grid[r, c] = f
            e = cut[edge_of[f]]
            expect = {(i) % 4: r == 0, (i + 1) % 4: c == cols - 1, (i + 2) % 4: r == rows - 1, (i + 3) % 4: c == 0}
            for k, want in expect.items():
                if bool(e[k]) != want:
                    where = "inside" if not want else "missing on its boundary"
                    return fail(f"a clipping edge is {where} at quad {f}: not a rectangle")
            if sharp[edge_of[f]][[k for k, want in expect.items() if not want]].any():
                return fail(f"a sharp edge lies inside it at quad {f}")
            if r + 1 < rows and step_v((f, i)) != states[r + 1][c]:
                return fail(f"rows {r} and {r + 1} do not line up at quad {f}: an extraordinary vertex inside")
            corners_v = (quads[f, i], quads[f, (i + 1) % 4], quads[f, (i + 2) % 4], quads[f, (i + 3) % 4])
            for (dr, dc), v in zip(((0, 0), (0, 1), (1, 1), (1, 0)), corners_v):
                if grid[r + dr, c + dc] == -1:
                    grid[r + dr, c + dc] = v
                elif grid[r + dr, c + dc] != v:
                    return fail(f"grid vertex ({r + dr}, {c + dc}) is both {grid[r + dr, c + dc]} and {v}: "
                                "an extraordinary vertex inside")
    inner = grid[1:-1, 1:-1].reshape(-1)
    if len(inner):
        bad = inner[(topo.valence[inner] != 4) | topo.boundary_vertex[inner]]
        if len(bad):
            return fail(f"extraordinary vertex {int(bad[0])} lies inside it")
        if len(np.unique(inner)) != len(inner):
            return fail("a vertex appears twice inside its grid: not a disk")
    corners = (int(grid[0, 0]), int(grid[0, cols]), int(grid[rows, cols]), int(grid[rows, 0]))
    return PatchGrid(faces=faces, rows=rows, cols=cols, grid=grid, face_grid=face_grid, corners=corners)
