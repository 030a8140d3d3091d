"""Contour-parallel rings from the grid, their corner pockets, and the patch's one continuous parameter path.

Order: outermost ring first. The first ring runs along the patch boundary — where the patch meets
its neighbours at sharp edges — on it (the paper's) or half an interval inside (ours, `edge.py`), so
the tool enters next to the edge and every later ring is reached by a short cutting move inward
instead of a retract (a spiral turn in our plan, a diagonal link in the paper's rings); the path ends
in the middle of the patch, from where the retract leaves no mark on an edge.

Between ring k and ring k + 1 the sides are covered by the grid's checked steps; what is left is the
pocket at each corner, between the outer corner P and the inner corner Q. There the highest material
is found numerically: at each sample the material the balls swept along both rings' legs leave (the
first entry of the normal ray into them, exact for those paths) is maximised on a grid refined twice
(maximising the distance instead misses pockets whose near side is convex). With concentric
rings (the paper's, `spiral=False`) the link from ring k to ring k + 1 runs through the pocket of the
start corner; our spiral turns instead (see `ring_path`). At the other corners a short excursion from
Q towards P (and back) is added when the pocket would exceed its bound — the paper instead shrinks the
whole side step (`shrink_for_corners`, used by its baseline). A first ring inside the edges has such
pockets too, between the claim's corner P, which no pass runs through, and its own corner Q.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.plan.edge import ray_capsule_entry
from cam.spline.geometry import Patch, frame

__all__ = ["RingPath", "corner_scallop", "ring_path", "shrink_for_corners"]

# (u side, v side) of the four corners in the order a ring visits them from its start corner.
CORNERS = ((0, 0), (1, 0), (1, 1), (0, 1))


def _corner_point(rect, corner) -> np.ndarray:
    a, b, c, d = rect
    return np.array([(a, b)[corner[0]], (c, d)[corner[1]]], dtype=np.float64)


def _segment_points(q0, q1, n) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return q0[None] * (1 - t) + q1[None] * t


def _paths_near_corner(patch, outer, inner, corner, extra, outer_cut=True, r=0.0):
    """Segments (a, b) of the ball-centre paths (contact + r n) around one corner: both rings' legs (the inner
    ring's alone when outer_cut is False: the outer rectangle is then the claim's edge, not a pass) plus extra
    parameter segments."""
    P, Q = _corner_point(outer, corner), _corner_point(inner, corner)
    du, dv = abs(Q[0] - P[0]), abs(Q[1] - P[1])
    sign = np.array([1.0 if corner[0] == 0 else -1.0, 1.0 if corner[1] == 0 else -1.0])
    pieces = []
    for rect, base in ((outer, P), (inner, Q))[0 if outer_cut else 1:]:
        width, height = rect[1] - rect[0], rect[3] - rect[2]
        pieces.append((base, base + [sign[0] * min(3 * du + 1e-12, width), 0.0]))
        pieces.append((base, base + [0.0, sign[1] * min(3 * dv + 1e-12, height)]))
    pieces.extend(extra)
    a_list, b_list = [], []
    for q0, q1 in pieces:
        uv = _segment_points(np.asarray(q0, float), np.asarray(q1, float), 25)
        fr = frame(patch, uv[:, 0], uv[:, 1])
        c = fr.p + r * fr.n
        a_list.append(c[:-1])
        b_list.append(c[1:])
    return np.concatenate(a_list), np.concatenate(b_list), P, Q


def corner_scallop(patch: Patch, outer, inner, corner: tuple[int, int], *, r: float,
                   extra: list = (), grid: int = 12, outer_cut: bool = True) -> tuple[float, np.ndarray]:
    """Scallop bound (mm) in the pocket between ring `outer` and ring `inner` at `corner`, and its point (u, v).

    outer, inner: (u0, u1, v0, v1) ring rectangles; corner: (0|1, 0|1) = (u side, v side);
    extra: further contact segments [(uv0, uv1), ...] in parameters (the link, an excursion);
    outer_cut=False: `outer` is the claim's edge, which no pass runs along.

    The pocket is the parameter box between the outer corner P and the inner corner Q; the material
    the swept balls leave there is maximised on a grid × grid grid, then on two finer grids around
    the highest point.

    Parameters
    ----------
    patch : Patch
        The patch.
    outer, inner : tuple of 4 float
        The ring rectangles (u0, u1, v0, v1), parameters.
    corner : tuple of 2 int
        (u side, v side), each 0 (low) or 1 (high).
    r : float
        Ball radius, mm.
    extra : list of ((2,) float, (2,) float)
        Further contact segments (uv0, uv1) in parameters (the link, an excursion).
    grid : int
        Samples per direction of each search grid.
    outer_cut : bool
        False when `outer` is the claim's edge, which no pass runs along.

    Returns
    -------
    scallop : float
        The highest material found in the pocket, mm; 0.0 where the pocket has no width in u or v.
    uv : (2,) float64
        Where it is, (u, v) parameters (Q where the pocket has no width).
    """
    seg_a, seg_b, P, Q = _paths_near_corner(patch, outer, inner, corner, list(extra), outer_cut, r)
    lo, hi = np.minimum(P, Q), np.maximum(P, Q)
    if np.any(hi - lo <= 0):
        return 0.0, Q
    span = hi - lo
    centre, half = 0.5 * (lo + hi), 0.5 * span
    best_h, best_uv = -1.0, Q
    for _ in range(3):  # coarse grid, then two finer grids around the highest point
        g = np.linspace(-1.0, 1.0, grid)
        uu, vv = np.meshgrid(centre[0] + g * half[0], centre[1] + g * half[1], indexing="ij")
        uv = np.clip(np.stack([uu.ravel(), vv.ravel()], -1), lo, hi)
        h = _material(patch, uv, seg_a, seg_b, r)
        i = int(np.argmax(h))
        if h[i] > best_h:
            best_h, best_uv = float(h[i]), uv[i]
        centre, half = best_uv, half * 2.5 / grid
    return best_h, best_uv


def _material(patch: Patch, uv: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray, r: float) -> np.ndarray:
    """Material (mm) the balls swept along the centre segments (m, 3) leave at each point uv (n, 2): the first
    entry of the point's normal ray into them (`edge.ray_capsule_entry`), exact for those paths.

    Before, one ball at the nearest contact stood in, by the exact relation at twice the distance with the
    normal curvature towards it: on a small patch curved one way between the point and the contact and
    another way at the point, that said 0.0096 mm where 0.0253 mm was left."""
    fr = frame(patch, uv[:, 0], uv[:, 1])
    return ray_capsule_entry(fr.p, fr.n, seg_a, seg_b, r)


def excursion(patch: Patch, outer, inner, corner, *, r: float, h: float, extra: list = (),
              outer_cut: bool = True) -> tuple[float, float]:
    """Smallest fraction λ of the way from Q to P that an in-and-out excursion needs so the pocket holds h.

    Returns (λ, scallop bound with it); λ = 0 when the pocket already holds. The search runs on a
    fixed sample grid of the pocket (distances to the fixed paths computed once); the λ it finds is
    then confirmed with the refined `corner_scallop` and lengthened until that holds too.
    """
    base, _ = corner_scallop(patch, outer, inner, corner, r=r, extra=extra, outer_cut=outer_cut)
    if base <= h:
        return 0.0, base
    seg_a, seg_b, P, Q = _paths_near_corner(patch, outer, inner, corner, list(extra), outer_cut, r)
    lo_uv, hi_uv = np.minimum(P, Q), np.maximum(P, Q)
    g = np.linspace(0.0, 1.0, 33)
    uu, vv = np.meshgrid(lo_uv[0] + g * (hi_uv[0] - lo_uv[0]), lo_uv[1] + g * (hi_uv[1] - lo_uv[1]), indexing="ij")
    fx = frame(patch, uu.ravel(), vv.ravel())
    left_base = ray_capsule_entry(fx.p, fx.n, seg_a, seg_b, r)

    def pocket(lam: float) -> float:
        fe = frame(patch, *_segment_points(Q, Q + lam * (P - Q), 9).T)
        e = fe.p + r * fe.n
        return float(np.minimum(left_base, ray_capsule_entry(fx.p, fx.n, e[:-1], e[1:], r)).max())

    lo, hi = 0.0, 1.0
    for _ in range(10):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if pocket(mid) <= h else (mid, hi)
    while True:
        val, _ = corner_scallop(patch, outer, inner, corner, r=r, extra=[*extra, (Q, Q + hi * (P - Q))],
                                outer_cut=outer_cut)
        if val <= h or hi >= 1.0:
            return hi, val
        hi = min(1.0, hi * 1.1 + 0.02)


def shrink_for_corners(patch: Patch, outer, inner, *, r: float, h: float, samples: int = 32) -> tuple[float, float]:
    """The paper's corner rule: shrink the u steps (Δs) of `inner` until all four corner pockets hold h.

    The start corner counts its link. Returns the new (u0, u1) of the inner ring.
    Each round keeps 95 % of both u steps; after 60 rounds the last one is returned as it is.

    Parameters
    ----------
    patch : Patch
        The patch.
    outer, inner : tuple of 4 float
        Ring k and ring k + 1 as (u0, u1, v0, v1), parameters.
    r : float
        Ball radius, mm.
    h : float
        Bound each corner pocket must hold, mm.
    samples : int
        Not used.

    Returns
    -------
    u0, u1 : float
        The new u range of the inner ring, parameters.
    """
    a, b, c, d = outer
    na, nb, nc, nd = inner
    for _ in range(60):
        worst = 0.0
        for corner in CORNERS:
            extra = [(_corner_point(outer, corner), _corner_point((na, nb, nc, nd), corner))] if corner == (0, 0) else []
            val, _ = corner_scallop(patch, outer, (na, nb, nc, nd), corner, r=r, extra=extra)
            worst = max(worst, val)
        if worst <= h:
            break
        na, nb = a + 0.95 * (na - a), b - 0.95 * (b - nb)
    return na, nb


@dataclass(frozen=True)
class RingPath:
    """One patch's contact path in parameters, in cutting order.

    Attributes
    ----------
    uv : (n, 2) float64
        Corner points of straight parameter segments.
    kind : (n − 1,) int8
        Per segment: 0 ring side, 1 link between rings, 2 corner excursion.
    corner_scallop : (m,) float64
        The bound of every corner pocket, mm.
    excursions : int
        Number of excursions added.
    """

    uv: np.ndarray
    kind: np.ndarray
    corner_scallop: np.ndarray
    excursions: int


def _ring_loop(rect) -> list[np.ndarray]:
    a, b, c, d = rect
    if a == b and c == d:
        return [np.array([a, c])]
    if a == b:
        return [np.array([a, c]), np.array([a, d])]
    if c == d:
        return [np.array([a, c]), np.array([b, c])]
    return [np.array(p, dtype=np.float64) for p in ((a, c), (b, c), (b, d), (a, d), (a, c))]


def _spiral_turn(patch: Patch, prev, rect, nxt, *, r: float, corner_mm: float, excursions: bool):
    """The pocket where the spiral turns from ring `rect`'s shortened u0 side onto the next ring's v0 line.

    It lies between P = (u0 of prev, v0 of rect), where the previous turn ran, and Q = (u0 of rect, v0 of
    nxt): from P the paths run up the previous ring's u0 side and along rect's v0 line, from Q up rect's
    u0 side and along nxt's v0 line, so it is a corner pocket of those two L's. Returns (excursion end
    point or None, the pocket's scallop bound).
    """
    outer = (prev[0], rect[1], rect[2], prev[3])
    inner = (rect[0], nxt[1], nxt[2], rect[3])
    if not excursions:
        return None, corner_scallop(patch, outer, inner, (0, 0), r=r)[0]
    lam, val = excursion(patch, outer, inner, (0, 0), r=r, h=corner_mm)
    P, Q = _corner_point(outer, (0, 0)), _corner_point(inner, (0, 0))
    return (Q + lam * (P - Q) if lam > 0 else None), val


def ring_path(patch: Patch, rects: np.ndarray, *, r: float, corner_mm: float, excursions: bool = True,
              spiral: bool = False, claim=None, check_cancel=None) -> RingPath:
    """Link the rings (outermost first) into one parameter path with corner excursions where needed.

    spiral=False closes every ring at its start corner and links it to the next along the diagonal of
    that corner (the paper's concentric rings). spiral=True stops the closing side of ring k at the
    next ring's v0 line and steps along that line to its start, so ring k + 1's first side simply
    reaches back to u0: the start corner then has no pocket (the square there lies between the v0 lines
    of ring k and k + 1, whose gap the side check already holds over all of [u0, u1]) and each ring
    saves the diagonal link. The turn leaves a pocket of its own (`_spiral_turn`), bounded and given an
    excursion like the other corners.

    claim: the rectangle (u0, u1, v0, v1) the rings finish (`RingGrid.claim`). When the first ring lies
    inside it, the first ring's four corner pockets against the claim's corners are bounded and given
    excursions too, and with spiral=True the first ring starts on its u0 side at the next ring's v0 line,
    so that side is cut whole.

    Parameters
    ----------
    patch : Patch
        The patch.
    rects : (K, 4) float64
        The rings (u0, u1, v0, v1), outermost first (`RingGrid.rects`).
    r : float
        Ball radius, mm.
    corner_mm : float
        The bound each corner pocket must hold with its excursion, mm.
    excursions : bool
        Add excursions where a pocket exceeds `corner_mm`; False only bounds the pockets.
    spiral : bool
        Join the rings into a spiral (see above) instead of concentric rings with diagonal links.
    claim : tuple of 4 float or None
        The rectangle the rings finish (see above); None: the first ring's own, no inset pockets.
    check_cancel : callable or None
        Called once per ring; it stops the work by raising.

    Returns
    -------
    RingPath
        The parameter path, its segment kinds, the bound of every corner pocket and the number of
        excursions.
    """
    inset = claim is not None and len(rects) > 0 and tuple(map(float, rects[0])) != tuple(map(float, claim))
    points: list[np.ndarray] = []
    kinds: list[int] = []
    corner_vals: list[float] = []

    def add(p: np.ndarray, kind: int) -> None:
        if points:
            kinds.append(kind)
        points.append(np.asarray(p, dtype=np.float64))

    n_exc = 0
    for k, rect in enumerate(map(tuple, rects)):
        if check_cancel is not None:
            check_cancel()
        todo: dict[tuple[int, int], np.ndarray] = {}
        if k > 0 or inset:
            cut = k > 0  # the outer rectangle is a ring, or else the claim's edge
            outer = tuple(rects[k - 1]) if cut else tuple(claim)
            for corner in CORNERS:
                P, Q = _corner_point(outer, corner), _corner_point(rect, corner)
                link = cut and corner == (0, 0)
                if link and spiral:
                    continue
                if link or not excursions:
                    val, _ = corner_scallop(patch, outer, rect, corner, r=r, extra=[(P, Q)] if link else [],
                                            outer_cut=cut)
                else:
                    lam, val = excursion(patch, outer, rect, corner, r=r, h=corner_mm, outer_cut=cut)
                    if lam > 0:
                        todo[corner] = Q + lam * (P - Q)
                corner_vals.append(val)
        loop = _ring_loop(rect)
        turn = None
        if spiral and k + 1 < len(rects) and len(loop) == 5:
            loop[-1] = np.array([rect[0], rects[k + 1][2]], dtype=np.float64)
            if k == 0 and inset:
                loop.insert(0, loop[-1])
            if k > 0:
                turn = _spiral_turn(patch, rects[k - 1], rect, rects[k + 1], r=r, corner_mm=corner_mm,
                                    excursions=excursions)
                corner_vals.append(turn[1])
        for i, p in enumerate(loop):
            add(p, 1 if (i == 0 and k > 0 and not spiral) else 0)
            for corner in [c for c in todo if np.array_equal(_corner_point(rect, c), p)]:
                add(todo.pop(corner), 2)
                add(p, 2)
                n_exc += 1
        if turn is not None and turn[0] is not None:
            add(turn[0], 2)
            add(loop[-1], 2)
            n_exc += 1
    uv = np.array(points, dtype=np.float64).reshape(-1, 2)
    return RingPath(uv=uv, kind=np.array(kinds, dtype=np.int8), corner_scallop=np.array(corner_vals), excursions=n_exc)
