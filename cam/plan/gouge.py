"""Cutter positions and straight moves checked against the whole part: every patch, not only the one cut.

The clearance of a ball centre is its distance to the nearest surface minus r (negative = gouge).
Distances are exact up to the Newton tolerance: a dense sample of each patch gives the start, then
projected Newton steps on |S(u, v) − x|² settle on the foot point inside the parameter box. A ball
that gouges a neighbouring patch (at a hollow edge between two patches) is lifted along the tool axis
until it clears, as a drop cutter would; the shank (a cylinder of radius r above the ball centre) must
not meet any patch either — where it would, the position cannot be reached from this side at all.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cam.spline._compiled import project_in_boxes
from cam.spline.geometry import Patch
from cam.spline.pieces import c0_pieces, foot_in_pieces, make_piece_boxes
from cam.spline.surface import BSplineSurface

__all__ = [
    "GOUGE_TOL_MM",
    "SurfaceIndex",
    "build_index",
    "clearance",
    "closest_points",
    "lift_to_clear",
    "move_clearance",
    "shank_clear",
]

#: How far a ball may reach into a surface and still count as clear of it (Newton's tolerance is finer).
GOUGE_TOL_MM = 1e-5


@dataclass(frozen=True, eq=False)
class SurfaceIndex:
    """Dense samples of every patch (machine frame) for start points and shank tests.

    Attributes
    ----------
    patches : tuple of Patch
        The indexed patches, machine frame.
    trees : tuple of cKDTree
        ``trees[i]``: KD-tree over patch i's samples, (n_i, 3) points, mm.
    uv : tuple of (n_i, 2) float64
        ``uv[i]``: the parameters of patch i's samples.
    points : (N, 3) float64
        All samples, mm.
    tree_xy : cKDTree
        KD-tree of their (x, y).
    spacing : float
        Sample spacing, mm.
    """

    patches: tuple[Patch, ...]
    trees: tuple[cKDTree, ...]
    uv: tuple[np.ndarray, ...]
    points: np.ndarray
    tree_xy: cKDTree
    spacing: float


def _grid(patch: Patch, spacing: float, max_side: int = 400) -> np.ndarray:
    (u0, u1), (v0, v1) = patch.domain
    probe = np.linspace(0, 1, 9)
    uu, vv = np.meshgrid(u0 + probe * (u1 - u0), v0 + probe * (v1 - v0), indexing="ij")
    lu = np.max(np.linalg.norm(patch.surface.evaluate(uu, vv, du=1), axis=-1)) * (u1 - u0)
    lv = np.max(np.linalg.norm(patch.surface.evaluate(uu, vv, dv=1), axis=-1)) * (v1 - v0)
    nu = int(np.clip(np.ceil(lu / spacing), 2, max_side)) + 1
    nv = int(np.clip(np.ceil(lv / spacing), 2, max_side)) + 1
    uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv), indexing="ij")
    return np.stack([uu.ravel(), vv.ravel()], -1)


def build_index(patches: list[Patch], *, spacing_mm: float) -> SurfaceIndex:
    """Sample every patch about `spacing_mm` apart (capped at 400 per side) and index the samples.

    Parameters
    ----------
    patches : list of Patch
        The patches, machine frame.
    spacing_mm : float
        Sample spacing, mm (> 0); each parameter direction gets at least 2 intervals.

    Returns
    -------
    SurfaceIndex
        The samples and their KD-trees.

    Raises
    ------
    ValueError
        When `spacing_mm` is not positive.
    """
    if spacing_mm <= 0:
        raise ValueError(f"spacing_mm must be positive, got {spacing_mm}")
    trees, uvs, pts = [], [], []
    for p in patches:
        uv = _grid(p, spacing_mm)
        x = p.surface.evaluate(uv[:, 0], uv[:, 1])
        trees.append(cKDTree(x))
        uvs.append(uv)
        pts.append(x)
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    return SurfaceIndex(tuple(patches), tuple(trees), tuple(uvs), points, cKDTree(points[:, :2]), float(spacing_mm))


def _project(patch: Patch, x: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The foot point of x (n, 3) on the patch from uv (n, 2): (uv, foot); across C0 knot lines see
    `cam.spline.surface.foot_in_pieces`."""
    s = patch.surface
    (u0, u1), (v0, v1) = patch.domain
    base = getattr(s, "base", s)

    def newton(rows, start, lo, hi):
        q, f = _project_box(s, x[rows], start, lo, hi)
        return q, np.linalg.norm(f - x[rows], axis=1)

    pieces_u, pieces_v, boxes = _pieces(base, u0, u1, v0, v1)
    bound = None if boxes is None else (lambda rows, iu, iv: boxes.distance_bound(x[rows], iu, iv))
    uv, _ = foot_in_pieces(newton, pieces_u, pieces_v, uv, lower_bound=bound)
    return uv, s.evaluate(uv[:, 0], uv[:, 1])


@functools.lru_cache(maxsize=256)
def _pieces(base: BSplineSurface, u0: float, u1: float, v0: float, v1: float):
    """The pieces between C0 lines of base's domain part u0..u1 x v0..v1 and their boxes (None
    for one piece); cached because the planner projects a few points at a time, thousands of times."""
    pieces_u = c0_pieces(base.knots_u, base.degree[0], u0, u1)
    pieces_v = c0_pieces(base.knots_v, base.degree[1], v0, v1)
    if pieces_u.size == 2 and pieces_v.size == 2:
        return pieces_u, pieces_v, None
    return pieces_u, pieces_v, make_piece_boxes(base.knots_u, base.knots_v, base.control_points, pieces_u,
                                                pieces_v, degree=base.degree)


def _project_box(s, x: np.ndarray, uv: np.ndarray, lo: np.ndarray, hi: np.ndarray, iterations: int = 12
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Projected Newton for the foot point of x (n, 3) on surface s from uv (n, 2), inside the boxes
    lo..hi (n, 2): (uv, foot). Compiled (`cam.spline._compiled.project_in_boxes`), point by point."""
    base = getattr(s, "base", s)
    uv = project_in_boxes(base.knots_u, base.knots_v, base.control_points, x, uv, lo, hi, base.degree, iterations)
    return uv, s.evaluate(uv[:, 0], uv[:, 1])


def closest_points(index: SurfaceIndex, x: np.ndarray, *, max_distance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest surface point of every x (float (n, 3) mm) among all patches, within max_distance.

    Parameters
    ----------
    index : SurfaceIndex
        The patches and their samples.
    x : (n, 3) float
        Query points, mm, same frame as `index`.
    max_distance : float
        Search radius, mm; patches whose samples lie farther than max_distance + ``index.spacing`` are
        not projected on.

    Returns
    -------
    distance : (n,) float64
        Distance to the nearest foot point, mm; inf beyond max_distance.
    patch : (n,) int
        Index into ``index.patches`` of the nearest patch (not its id), −1 when none was projected on.
    uv : (n, 2) float64
        Parameters of the foot point (0 where none).
    foot : (n, 3) float64
        The foot point, mm (NaN where none).
    """
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    n = len(x)
    best = np.full(n, np.inf)
    which = np.full(n, -1)
    best_uv = np.zeros((n, 2))
    foot = np.full((n, 3), np.nan)
    for i, (patch, tree, uvs) in enumerate(zip(index.patches, index.trees, index.uv)):
        d0, j = tree.query(x, distance_upper_bound=max_distance + index.spacing)
        near = np.isfinite(d0)
        if not np.any(near):
            continue
        uv, f = _project(patch, x[near], uvs[j[near]])
        d = np.linalg.norm(f - x[near], axis=1)
        idx = np.flatnonzero(near)
        better = d < best[idx]
        idx = idx[better]
        best[idx], which[idx], best_uv[idx], foot[idx] = d[better], i, uv[better], f[better]
    best[best > max_distance] = np.inf
    return best, which, best_uv, foot


def clearance(index: SurfaceIndex, centres: np.ndarray, r: float) -> np.ndarray:
    """Distance of each ball centre (float (n, 3)) to the part minus r, mm; negative where it gouges.

    Parameters
    ----------
    index : SurfaceIndex
        The whole part.
    centres : (n, 3) float
        Ball centres, mm, same frame as `index`.
    r : float
        Ball radius, mm.

    Returns
    -------
    clearance : (n,) float64
        Distance to the nearest surface minus r, mm; r where no surface lies within 2r.
    """
    d, *_ = closest_points(index, centres, max_distance=2 * r)
    return np.where(np.isfinite(d), d - r, r)


def lift_to_clear(index: SurfaceIndex, centres: np.ndarray, r: float, *, tol: float = 1e-6,
                  max_lift: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Raise gouging balls along +Z until they clear every patch: (lifted centres (n, 3), lift (n,) mm).

    Newton on the clearance with d(distance)/dz = the z part of the unit vector from foot to centre.
    Lifts beyond max_lift (default r) are returned as NaN: such a position is left out, not forced.
    The slope is clamped to [0.2, 1]; at most 40 Newton steps.

    Parameters
    ----------
    index : SurfaceIndex
        The whole part.
    centres : (n, 3) float
        Ball centres, mm, same frame as `index`.
    r : float
        Ball radius, mm.
    tol : float
        A ball counts as clear at distance ≥ r − tol; each step also adds tol to the lift, mm.
    max_lift : float or None
        Largest lift allowed, mm; default r.

    Returns
    -------
    centres : (n, 3) float64
        The lifted centres, mm (rows whose lift is NaN hold no usable position).
    lift : (n,) float64
        The lift of each, mm along +Z: 0 where the ball already cleared, NaN beyond max_lift.
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3).copy()
    lift = np.zeros(len(c))
    limit = r if max_lift is None else max_lift
    active = np.arange(len(c))
    for _ in range(40):
        d, _, _, foot = closest_points(index, c[active], max_distance=2 * r)
        short = np.isfinite(d) & (d < r - tol)
        if not np.any(short):
            break
        active, d, foot = active[short], d[short], foot[short]
        slope = np.clip((c[active, 2] - foot[:, 2]) / np.maximum(d, 1e-12), 0.2, 1.0)
        dz = (r - d) / slope + tol
        lift[active] += dz
        c[active, 2] += dz
        over = lift[active] > limit
        lift[active[over]] = np.nan
        active = active[~over]
        if not len(active):
            break
    return c, lift


def shank_clear(index: SurfaceIndex, centres: np.ndarray, r: float, *, tol: float = 1e-3) -> np.ndarray:
    """True where no patch sample lies inside the shank (radius r − tol, above centre z + tol). bool (n,).

    The shank is the vertical cylinder above the ball centre; it is tested against the samples of
    `index` (``index.points``), not the exact surfaces.

    Parameters
    ----------
    index : SurfaceIndex
        The whole part, machine frame (tool axis +Z).
    centres : (n, 3) float
        Ball centres, mm.
    r : float
        Ball (and shank) radius, mm.
    tol : float
        Margin, mm: the cylinder's radius is r − tol and it starts tol above the centre.

    Returns
    -------
    clear : (n,) bool
        True where no sample lies inside the shank.
    """
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    ok = np.ones(len(c), dtype=bool)
    if not len(index.points):
        return ok
    hits = index.tree_xy.query_ball_point(c[:, :2], r - tol, return_sorted=False)
    for i, h in enumerate(hits):
        if h and np.any(index.points[h, 2] > c[i, 2] + tol):
            ok[i] = False
    return ok


def move_clearance(index: SurfaceIndex, a: np.ndarray, b: np.ndarray, r: float, *, step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Smallest clearance along each straight move a → b (float (m, 3) ball centres).

    Sampled ≤ step_mm apart, then refined (parabolic steps) between the neighbours of each move's
    lowest sample: a move over a convex surface dips between samples by about step² / 8ρ, which at
    the usual steps is more than the gouge tolerance. Returns (clearance (m,) mm, the centre where it
    occurs (m, 3)).

    Parameters
    ----------
    index : SurfaceIndex
        The whole part.
    a, b : (m, 3) float
        Start and end ball centres of each move, mm, same frame as `index`.
    r : float
        Ball radius, mm.
    step_mm : float
        Largest sample spacing along a move, mm.

    Returns
    -------
    clearance : (m,) float64
        Smallest clearance along each move (`clearance`), mm; negative where it gouges.
    at : (m, 3) float64
        The ball centre where it occurs, mm.
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 3)
    n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / step_mm).astype(int), 1)
    seg = np.repeat(np.arange(len(a)), n + 1)
    t = np.concatenate([np.linspace(0, 1, k + 1) for k in n]) if len(a) else np.zeros(0)
    x = a[seg] + t[:, None] * (b - a)[seg]
    cl = clearance(index, x, r)
    worst = np.full(len(a), np.inf)
    np.minimum.at(worst, seg, cl)
    at = np.zeros((len(a), 3))
    first = np.flatnonzero(cl == worst[seg])
    at[seg[first]] = x[first]
    if not len(a):
        return worst, at
    # Successive parabolic steps inside the bracket (lowest sample and its neighbours), halving the wider
    # half where the parabola is flat or points outside: the clearance along a move is smooth there.
    i_best = np.zeros(len(a), dtype=np.int64)
    i_best[seg[first]] = first
    start = np.concatenate([[0], np.cumsum(n + 1)[:-1]])
    i_lo, i_hi = np.maximum(i_best - 1, start), np.minimum(i_best + 1, start + n)
    lo, mid, hi = t[i_lo], t[i_best], t[i_hi]
    f_lo, f_mid, f_hi = cl[i_lo], cl[i_best], cl[i_hi]
    for _ in range(5):
        p_, q_ = (mid - lo) * (f_mid - f_hi), (mid - hi) * (f_mid - f_lo)
        den = 2 * (p_ - q_)
        with np.errstate(invalid="ignore", divide="ignore"):
            x = mid - ((mid - lo) * p_ - (mid - hi) * q_) / den
        wide = np.where(mid - lo > hi - mid, 0.5 * (lo + mid), 0.5 * (mid + hi))
        x = np.where(np.isfinite(x) & (x > lo) & (x < hi) & (np.abs(x - mid) > 1e-12), x, wide)
        fx = clearance(index, a + x[:, None] * (b - a), r)
        better = fx < worst
        worst = np.where(better, fx, worst)
        at[better] = (a + x[:, None] * (b - a))[better]
        right = x > mid
        take = fx < f_mid  # x becomes the middle, the old middle a bracket end
        lo, f_lo = np.where(take & right, mid, np.where(~take & ~right, x, lo)), \
            np.where(take & right, f_mid, np.where(~take & ~right, fx, f_lo))
        hi, f_hi = np.where(take & ~right, mid, np.where(~take & right, x, hi)), \
            np.where(take & ~right, f_mid, np.where(~take & right, fx, f_hi))
        mid, f_mid = np.where(take, x, mid), np.where(take, fx, f_mid)
    return worst, at
