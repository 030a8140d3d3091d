"""Which patch borders which: shared boundary segments, the curves that carry them, and each side's pieces.

Patches are rectangular grids of vertex ids of one quad mesh. Each side of a patch is
cut into segments where its neighbour changes (a side meeting two patches is a
T-junction). Every segment is carried by exactly one boundary curve, fitted once:
a side whose segments are all still free becomes one curve (so the long side of a
T-junction stays smooth and its neighbours take pieces of it, split off by knot
insertion), the remaining segments become curves of their own. A side is then a
list of pieces of curves, and both patches along a segment build their border rows
from the same curve: C0 by construction.

Parameters along a side are grid-index units: side "v0" is grid[:, 0] (u = t, v = 0),
"v1" grid[:, C] (u = t, v = C), "u0" grid[0, :] (u = 0, v = t), "u1" grid[R, :] (u = R, v = t).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam import GeometryError

__all__ = ["SIDES", "PatchLayoutError", "Piece", "CurveSpec", "SharedSegment", "Layout", "boundary_layout",
           "side_vertices", "side_params"]

SIDES = ("u0", "u1", "v0", "v1")


class PatchLayoutError(GeometryError):
    """The patches do not tile the part: an edge of the quad mesh borders more than two patch sides."""


def side_vertices(grid: np.ndarray, name: str) -> np.ndarray:
    """Vertex ids along one side of a grid, in increasing side parameter.

    Parameters
    ----------
    grid : ndarray, shape (R + 1, C + 1), int
        A patch's vertex ids.
    name : {"u0", "u1", "v0", "v1"}
        The side (see the module docstring).

    Returns
    -------
    ndarray, shape (C + 1,) for "u0", "u1", (R + 1,) for "v0", "v1", int64
    """
    g = np.asarray(grid)
    return {"u0": g[0, :], "u1": g[-1, :], "v0": g[:, 0], "v1": g[:, -1]}[name].astype(np.int64)


def side_params(name: str, t: np.ndarray, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Surface parameters of points along a side.

    Parameters
    ----------
    name : {"u0", "u1", "v0", "v1"}
        The side (see the module docstring).
    t : ndarray, shape (n,), float64
        Side parameters, grid-index units.
    rows, cols : int
        R and C, the patch's quad counts.

    Returns
    -------
    u, v : ndarray, shape (n,), float64
        Surface parameters, grid-index units.
    """
    t = np.asarray(t, dtype=np.float64)
    fixed = {"u0": 0.0, "u1": float(rows), "v0": 0.0, "v1": float(cols)}[name]
    if name in ("u0", "u1"):
        return np.full_like(t, fixed), t
    return t, np.full_like(t, fixed)


@dataclass(frozen=True)
class Piece:
    """Part of a side carried by one curve.

    Attributes
    ----------
    curve : int
        The curve's index in `Layout.curves`.
    host : tuple of int
        The curve's parameter range (increasing).
    side : tuple of int
        The side's parameter range (increasing).
    reversed : bool
        Whether the curve runs against the side there.
    """

    curve: int
    host: tuple[int, int]
    side: tuple[int, int]
    reversed: bool


@dataclass(frozen=True)
class CurveSpec:
    """A boundary curve, parameterised by the index along its host side over [start, end].

    Attributes
    ----------
    host_patch : int
        The patch whose side hosts the curve.
    host_side : str
        That side's name.
    start, end : int
        The curve's range of side parameters.
    vertices : tuple of int
        Vertex ids at host parameters start..end.
    """

    host_patch: int
    host_side: str
    start: int
    end: int
    vertices: tuple[int, ...]  # vertex ids at host parameters start..end


@dataclass(frozen=True)
class SharedSegment:
    """A stretch of boundary two patches share.

    Attributes
    ----------
    a, b : tuple of (int, str, int, int)
        (patch, side, t0, t1) on each patch, t0 < t1.
    reversed : bool
        Whether the two sides run against each other there.
    """

    a: tuple[int, str, int, int]
    b: tuple[int, str, int, int]
    reversed: bool


@dataclass(frozen=True, eq=False)
class Layout:
    """Which patch borders which, and the curves that carry their sides.

    Attributes
    ----------
    curves : list of CurveSpec
        The boundary curves, each fitted once.
    sides : dict of (int, str) to list of Piece
        Per (patch, side), the pieces of curves that make it up, in side order.
    shared : list of SharedSegment
        The stretches of boundary two patches share, each once.
    neighbours : list of tuple of int
        Per patch, the patches sharing a stretch of its boundary, sorted.
    side_neighbours : dict of (int, str) to tuple of int
        The same per (patch, side).
    """

    curves: list[CurveSpec]
    sides: dict[tuple[int, str], list[Piece]]
    shared: list[SharedSegment]
    neighbours: list[tuple[int, ...]]
    side_neighbours: dict[tuple[int, str], tuple[int, ...]] = field(default_factory=dict)


def _key(a: int, b: int) -> tuple[int, int]:
    return (int(a), int(b)) if a < b else (int(b), int(a))


def boundary_layout(grids: list[np.ndarray]) -> Layout:
    """Segments, curves and pieces of patches given as grids of vertex ids.

    Parameters
    ----------
    grids : list of ndarray, each shape (R + 1, C + 1), int
        The patches' vertex ids (`cam.fit.grid.patch_grid`), of one quad mesh.

    Returns
    -------
    Layout
        The boundary curves, each side's pieces of them, the shared segments and the neighbours.

    Raises
    ------
    PatchLayoutError
        When an edge lies on the border of more than two patch sides.
    """
    sides = {(k, name): side_vertices(g, name) for k, g in enumerate(grids) for name in SIDES}
    edges: dict[tuple[int, int], list[tuple[int, str, int]]] = {}
    for (k, name), vs in sides.items():
        for t in range(len(vs) - 1):
            edges.setdefault(_key(vs[t], vs[t + 1]), []).append((k, name, t))
    runs = {key: _runs(key, vs, sides, edges) for key, vs in sides.items()}

    def seg_key(k: int, name: str, run: tuple) -> tuple:
        t0, t1, partner = run
        if partner is None:
            return (k, name, t0, t1)
        k2, n2, s0, s1, _ = partner
        return tuple(sorted([(k, name, t0, t1), (k2, n2, min(s0, s1), max(s0, s1))]))

    curves: list[CurveSpec] = []
    claimed: dict[tuple, tuple[int, int, int, str]] = {}  # segment -> (curve, host t0, host t1, host side)

    def make_curve(k: int, name: str, t0: int, t1: int) -> int:
        vs = sides[(k, name)]
        curves.append(CurveSpec(k, name, t0, t1, tuple(int(x) for x in vs[t0:t1 + 1])))
        return len(curves) - 1

    # Whole sides first, longest-cut first: a T-junction side becomes one smooth curve.
    order = sorted(sides, key=lambda key: (-len(runs[key]), key[0], SIDES.index(key[1])))
    for k, name in order:
        keys = [seg_key(k, name, r) for r in runs[(k, name)]]
        if any(sk in claimed for sk in keys):
            continue
        m = len(sides[(k, name)]) - 1
        c = make_curve(k, name, 0, m)
        for sk, (t0, t1, _) in zip(keys, runs[(k, name)]):
            claimed[sk] = (c, t0, t1, f"{k}:{name}")
    pieces: dict[tuple[int, str], list[Piece]] = {}
    shared: list[SharedSegment] = []
    side_nb: dict[tuple[int, str], tuple[int, ...]] = {}
    neighbours: list[set[int]] = [set() for _ in grids]
    for (k, name), rs in runs.items():
        out = []
        for run in rs:
            t0, t1, partner = run
            sk = seg_key(k, name, run)
            if sk not in claimed:  # cannot happen after the whole-side pass, kept for safety
                claimed[sk] = (make_curve(k, name, t0, t1), t0, t1, f"{k}:{name}")
            c, h0, h1, host = claimed[sk]
            if host == f"{k}:{name}" and (h0, h1) == (t0, t1):
                out.append(Piece(c, (h0, h1), (t0, t1), False))
            else:
                out.append(Piece(c, (h0, h1), (t0, t1), bool(partner[4])))
            if partner is not None:
                neighbours[k].add(partner[0])
                if (k, name, t0) < (partner[0], partner[1], min(partner[2], partner[3])):
                    k2, n2, s0, s1, rev = partner
                    shared.append(SharedSegment((k, name, t0, t1), (k2, n2, min(s0, s1), max(s0, s1)), bool(rev)))
        pieces[(k, name)] = out
        side_nb[(k, name)] = tuple(sorted({r[2][0] for r in rs if r[2] is not None}))
    return Layout(curves=curves, sides=pieces, shared=shared, neighbours=[tuple(sorted(s)) for s in neighbours],
                  side_neighbours=side_nb)


def _runs(key, vs, sides, edges) -> list[tuple[int, int, tuple | None]]:
    """Maximal stretches of one side with one partner side running continuously: (t0, t1, partner)."""
    out: list[list] = []
    for t in range(len(vs) - 1):
        occ = [o for o in edges[_key(vs[t], vs[t + 1])] if o != (key[0], key[1], t)]
        if len(occ) > 1:
            raise PatchLayoutError(f"quad-mesh edge ({vs[t]}, {vs[t + 1]}) borders {len(occ) + 1} patch sides; a "
                                   "patch boundary edge must belong to at most two patches: rerun segment or change "
                                   "its parameters")
        if occ:
            k2, n2, t2 = occ[0]
            rev = int(sides[(k2, n2)][t2]) != int(vs[t])
            s_start, s_end = (t2 + 1, t2) if rev else (t2, t2 + 1)
            partner = (k2, n2, s_start, s_end, rev)
        else:
            partner = None
        if out:
            last = out[-1]
            lp = last[2]
            if partner is None and lp is None:
                last[1] = t + 1
                continue
            if (partner is not None and lp is not None and lp[:2] == partner[:2] and lp[4] == partner[4]
                    and lp[3] == partner[2]):
                last[1] = t + 1
                last[2] = (lp[0], lp[1], lp[2], partner[3], lp[4])
                continue
        out.append([t, t + 1, partner])
    return [(a, b, p) for a, b, p in out]
