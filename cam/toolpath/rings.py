"""Contour-parallel rings from the grid, their corner pockets, and the patch's one continuous parameter path.

Order: outermost ring first. The first ring runs along the patch boundary — where the patch meets
its neighbours at sharp edges — so the tool enters at the boundary, where an entry mark is hidden by
the edge, and every later ring is reached by a short cutting link inward instead of a retract; the
path ends in the middle of the patch, from where the retract leaves no mark on an edge.

Between ring k and ring k + 1 the sides are covered by the grid's checked steps; what is left is the
pocket at each corner, between the outer corner P and the inner corner Q. There the farthest point
from every path is found numerically (a sampled max–min of 3D distances, refined twice) and turned
into a scallop with the exact relation at the normal curvature towards the nearest contact. The link from ring k to
ring k + 1 runs through the pocket of the start corner; at the three other corners a short excursion
from Q towards P (and back) is added when the pocket would exceed its bound — the paper instead
shrinks the whole side step (`shrink_for_corners`, used by its baseline).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.toolpath.geometry import Patch, frame, normal_curvature, principal_curvatures
from cam.toolpath.scallop import scallop_from_arc_gap

__all__ = ["RingPath", "corner_scallop", "ring_path", "shrink_for_corners"]

# (u side, v side) of the four corners in the order a ring visits them from its start corner.
CORNERS = ((0, 0), (1, 0), (1, 1), (0, 1))


def _corner_point(rect, corner) -> np.ndarray:
    a, b, c, d = rect
    return np.array([(a, b)[corner[0]], (c, d)[corner[1]]], dtype=np.float64)


def _segment_points(q0, q1, n) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)[:, None]
    return q0[None] * (1 - t) + q1[None] * t


def _dist_to_segments(x: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray) -> np.ndarray:
    ab = seg_b - seg_a
    t = np.einsum("nmk,mk->nm", x[:, None, :] - seg_a[None], ab) / np.maximum(np.einsum("mk,mk->m", ab, ab), 1e-300)
    t = np.clip(t, 0.0, 1.0)
    return np.min(np.linalg.norm(seg_a[None] + t[..., None] * ab[None] - x[:, None, :], axis=-1), axis=1)


def _paths_near_corner(patch, outer, inner, corner, extra):
    """3D segments (a, b) of the contact paths around one corner: both rings' legs plus extra param segments."""
    P, Q = _corner_point(outer, corner), _corner_point(inner, corner)
    du, dv = abs(Q[0] - P[0]), abs(Q[1] - P[1])
    sign = np.array([1.0 if corner[0] == 0 else -1.0, 1.0 if corner[1] == 0 else -1.0])
    pieces = []
    for rect, base in ((outer, P), (inner, Q)):
        width, height = rect[1] - rect[0], rect[3] - rect[2]
        pieces.append((base, base + [sign[0] * min(3 * du + 1e-12, width), 0.0]))
        pieces.append((base, base + [0.0, sign[1] * min(3 * dv + 1e-12, height)]))
    pieces.extend(extra)
    a_list, b_list = [], []
    for q0, q1 in pieces:
        uv = _segment_points(np.asarray(q0, float), np.asarray(q1, float), 25)
        p = patch.surface.evaluate(uv[:, 0], uv[:, 1])
        a_list.append(p[:-1])
        b_list.append(p[1:])
    return np.concatenate(a_list), np.concatenate(b_list), P, Q


def corner_scallop(patch: Patch, outer, inner, corner: tuple[int, int], *, r: float,
                   extra: list = (), grid: int = 12) -> tuple[float, np.ndarray]:
    """Scallop bound (mm) in the pocket between ring `outer` and ring `inner` at `corner`, and its point (u, v).

    outer, inner: (u0, u1, v0, v1) ring rectangles; corner: (0|1, 0|1) = (u side, v side);
    extra: further contact segments [(uv0, uv1), ...] in parameters (the link, an excursion).
    """
    seg_a, seg_b, P, Q = _paths_near_corner(patch, outer, inner, corner, list(extra))
    lo, hi = np.minimum(P, Q), np.maximum(P, Q)
    if np.any(hi - lo <= 0):
        return 0.0, Q
    span = hi - lo
    centre, half = 0.5 * (lo + hi), 0.5 * span
    best_rho, best_uv = -1.0, Q
    for _ in range(3):  # coarse grid, then two finer grids around the farthest point
        g = np.linspace(-1.0, 1.0, grid)
        uu, vv = np.meshgrid(centre[0] + g * half[0], centre[1] + g * half[1], indexing="ij")
        uv = np.clip(np.stack([uu.ravel(), vv.ravel()], -1), lo, hi)
        x = patch.surface.evaluate(uv[:, 0], uv[:, 1])
        rho = _dist_to_segments(x, seg_a, seg_b)
        i = int(np.argmax(rho))
        if rho[i] > best_rho:
            best_rho, best_uv = float(rho[i]), uv[i]
        centre, half = best_uv, half * 2.5 / grid
    # The material a ball leaves at surface distance ρ depends on the normal curvature towards its contact.
    fr = frame(patch, best_uv[:1], best_uv[1:])
    x = fr.p[0]
    ab = seg_b - seg_a
    t = np.clip(np.einsum("mk,mk->m", x - seg_a, ab) / np.maximum(np.einsum("mk,mk->m", ab, ab), 1e-300), 0, 1)
    foot = seg_a + t[:, None] * ab
    d = foot[np.argmin(np.linalg.norm(foot - x, axis=1))] - x
    basis = np.stack([fr.su[0], fr.sv[0]], axis=1)
    duv, *_ = np.linalg.lstsq(basis, d, rcond=None)
    kappa = normal_curvature(fr, np.array([duv[0]]), np.array([duv[1]]))
    if not np.all(np.isfinite(kappa)):
        _, kappa = principal_curvatures(fr)
    return float(scallop_from_arc_gap(2 * best_rho, r, kappa)[0]), best_uv


def excursion(patch: Patch, outer, inner, corner, *, r: float, h: float, extra: list = ()) -> tuple[float, float]:
    """Smallest fraction λ of the way from Q to P that an in-and-out excursion needs so the pocket holds h.

    Returns (λ, scallop bound with it); λ = 0 when the pocket already holds. The search runs on a
    fixed sample grid of the pocket (distances to the fixed paths computed once); the λ it finds is
    then confirmed with the refined `corner_scallop` and lengthened until that holds too.
    """
    base, _ = corner_scallop(patch, outer, inner, corner, r=r, extra=extra)
    if base <= h:
        return 0.0, base
    seg_a, seg_b, P, Q = _paths_near_corner(patch, outer, inner, corner, list(extra))
    lo_uv, hi_uv = np.minimum(P, Q), np.maximum(P, Q)
    g = np.linspace(0.0, 1.0, 33)
    uu, vv = np.meshgrid(lo_uv[0] + g * (hi_uv[0] - lo_uv[0]), lo_uv[1] + g * (hi_uv[1] - lo_uv[1]), indexing="ij")
    x = patch.surface.evaluate(uu.ravel(), vv.ravel())
    rho_base = _dist_to_segments(x, seg_a, seg_b)
    _, kmax = principal_curvatures(frame(patch, uu.ravel(), vv.ravel()))
    kmax = float(np.max(kmax))

    def pocket(lam: float) -> float:
        e = patch.surface.evaluate(*_segment_points(Q, Q + lam * (P - Q), 9).T)
        rho = np.minimum(rho_base, _dist_to_segments(x, e[:-1], e[1:]))
        return float(scallop_from_arc_gap(2 * rho.max(), r, kmax))

    lo, hi = 0.0, 1.0
    for _ in range(10):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if pocket(mid) <= h else (mid, hi)
    while True:
        val, _ = corner_scallop(patch, outer, inner, corner, r=r, extra=[*extra, (Q, Q + hi * (P - Q))])
        if val <= h or hi >= 1.0:
            return hi, val
        hi = min(1.0, hi * 1.1 + 0.02)


def shrink_for_corners(patch: Patch, outer, inner, *, r: float, h: float, samples: int = 32) -> tuple[float, float]:
    """The paper's corner rule: shrink the u steps (Δs) of `inner` until all four corner pockets hold h.

    The start corner counts its link. Returns the new (u0, u1) of the inner ring.
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

    uv: float64 (n, 2) corner points of straight parameter segments; kind: int8 (n − 1,) per segment
    (0 ring side, 1 link between rings, 2 corner excursion); corner_scallop: float64 (m,) the bound of
    every corner pocket; excursions: number added.
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


def ring_path(patch: Patch, rects: np.ndarray, *, r: float, corner_mm: float, excursions: bool = True,
              check_cancel=None) -> RingPath:
    """Link the rings (outermost first) into one parameter path with corner excursions where needed."""
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
        if k > 0:
            outer = tuple(rects[k - 1])
            for corner in CORNERS:
                P, Q = _corner_point(outer, corner), _corner_point(rect, corner)
                if corner == (0, 0) or not excursions:
                    extra = [(P, Q)] if corner == (0, 0) else []
                    val, _ = corner_scallop(patch, outer, rect, corner, r=r, extra=extra)
                else:
                    lam, val = excursion(patch, outer, rect, corner, r=r, h=corner_mm)
                    if lam > 0:
                        todo[corner] = Q + lam * (P - Q)
                corner_vals.append(val)
        for i, p in enumerate(_ring_loop(rect)):
            add(p, 1 if (i == 0 and k > 0) else 0)
            for corner in [c for c in todo if np.array_equal(_corner_point(rect, c), p)]:
                add(todo.pop(corner), 2)
                add(p, 2)
                n_exc += 1
    uv = np.array(points, dtype=np.float64).reshape(-1, 2)
    return RingPath(uv=uv, kind=np.array(kinds, dtype=np.int8), corner_scallop=np.array(corner_vals), excursions=n_exc)
