"""One patch's passes: Algorithm 1 rings on the reachable rectangle, chord-checked cutter positions,
gouge checks against the whole part, and the bound they are certified to (see `plan_patch`).

The certificate of a patch is the largest predicted scallop of any gap between its rings (exact
relation, checked on the real next line), of the material the first ring leaves on the edges of the
claimed rectangle, or of any corner pocket, plus the largest chord error of its moves and the effect
of the lifts kept; by construction it does not exceed the target.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from cam import CheckCancel
from cam.params import ToolParams, ToolpathParams
from cam.plan.chord import discretize, lattices
from cam.plan.errors import NotPlannable, TooConcave, Unreachable, concave_message
from cam.plan.gouge import (
    GOUGE_TOL_MM,
    SurfaceIndex,
    clearance,
    lift_to_clear,
    move_clearance,
    shank_clear,
)
from cam.plan.grid import RingGrid, ring_grid
from cam.plan.reach import reachable_domain
from cam.plan.rings import RingPath, ring_path
from cam.spline.geometry import Patch, SubSurface, frame

__all__ = ["CORNER_SHARE", "MAX_REPLANS", "ROUNDING_MM", "PatchPlan", "exclude_points", "plan_patch",
           "restrict_patch"]

ROUNDING_MM = 0.5e-4 * 3 ** 0.5  # 4 decimals per axis move a ball centre by at most this
CORNER_SHARE = 0.97  # corner pockets are held a little under the side gaps, which then set the maximum
MAX_REPLANS = 6


@dataclass
class PatchPlan:
    """One machined patch.

    Attributes
    ----------
    patch : int
        The patch id.
    region : tuple of 4 float
        The parameter rectangle (u0, u1, v0, v1) planned.
    passes : list of (n_i, 3) float64
        Tool tips per pass in cutting order, mm (machine frame).
    centres : list of (n_i, 3) float64
        The matching ball centres, mm (tool tip + r·Z).
    certified_scallop_mm : float
        The bound the planner certifies on `region`, mm.
    side_scallop_mm : float
        Largest predicted scallop of the side gaps and of the first ring's edge material, mm.
    corner_scallop_mm : float
        Largest bound of a corner pocket, mm.
    chord_error_mm : float
        Largest chord error of a move, mm.
    lift_mm : float
        The largest lift kept, mm (its effect is in the bound).
    spacing_mm : tuple of 2 float
        Smallest and largest pass interval, mm, from the side steps at the side midpoints.
    rings : int
        Number of rings.
    excursions : int
        Number of corner excursions.
    path_length_mm : float
        Summed length of the passes, mm (links between them not counted).
    reach_fraction : float
        The share of the patch the caller found reachable, as given.
    replans : int
        How often the rectangle was shrunk because the ball had to be lifted off the patch or left out
        or a hollow tighter than the ball turned up.
    excluded_points : int
        Such lifted or left-out positions, in all.
    strategy : str
        'adaptive' or 'paper'.
    time_s : float
        Planning time, s.
    hollows : tuple of str
        The hollows found, as `TooConcave` words them.
    touched : bool
        Whether the reach check or lifted and left-out positions took part of the patch.
    """

    patch: int
    region: tuple[float, float, float, float]
    passes: list[np.ndarray]
    centres: list[np.ndarray]
    certified_scallop_mm: float
    side_scallop_mm: float
    corner_scallop_mm: float
    chord_error_mm: float
    lift_mm: float
    spacing_mm: tuple[float, float]
    rings: int
    excursions: int
    path_length_mm: float
    reach_fraction: float
    replans: int
    excluded_points: int
    strategy: str
    time_s: float
    hollows: tuple[str, ...] = ()
    touched: bool = True



def _spacing(patch: Patch, rects: np.ndarray, steps: np.ndarray) -> tuple[float, float]:
    """Smallest and largest pass interval in mm, from the side steps at the side midpoints."""
    if not len(steps):
        return 0.0, 0.0
    a, b, c, d = rects[:-1].T
    mu, mv = 0.5 * (a + b), 0.5 * (c + d)
    uv = [(mu, c), (b, mv), (mu, d), (a, mv)]
    out = []
    for side, (u, v) in enumerate(uv):
        fr = frame(patch, u, v)
        root = np.sqrt(np.maximum(fr.e * fr.g - fr.f ** 2, 0))
        speed = root / np.sqrt(fr.e) if side % 2 == 0 else root / np.sqrt(fr.g)
        out.append(steps[:, side] * speed)
    vals = np.concatenate(out)
    vals = vals[vals > 1e-9]
    return (float(vals.min()), float(vals.max())) if len(vals) else (0.0, 0.0)


def _pieces(keep: np.ndarray) -> list[slice]:
    """The maximal runs of True in a bool (n,) array, as slices."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    return [slice(a, b) for a, b in zip(edges[::2], edges[1::2])]


def _clear_path(index: SurfaceIndex, centres: np.ndarray, uv: np.ndarray, r: float, step: float):
    """Lift gouging positions, split moves that gouge, drop what the tool cannot reach.

    centres: ball centres float (n, 3); uv: their contact parameters (n, 2). Returns the centre runs
    (each float (n_i, 3)), the lift of every lifted position (k,) mm with its parameters (k, 2), and the
    parameters of every dropped position (j, 2): there the ball does not touch the patch as planned.
    """
    cl = clearance(index, centres, r)
    bad = cl < -GOUGE_TOL_MM
    centres = centres.copy()
    lifts, lift_uv, drop_uv = [np.zeros(0)], [np.zeros((0, 2))], []
    if bad.any():
        fixed, lift = lift_to_clear(index, centres[bad], r, tol=GOUGE_TOL_MM / 10)
        centres[bad] = fixed
        centres[np.flatnonzero(bad)[np.isnan(lift)]] = np.nan
        lifts.append(lift[np.isfinite(lift)])
        lift_uv.append(uv[bad][np.isfinite(lift)])
    ok = np.all(np.isfinite(centres), axis=1)
    ok[ok] = shank_clear(index, centres[ok], r)
    drop_uv.append(uv[~ok])
    out = []
    for piece in _pieces(ok):
        run, ruv = centres[piece], uv[piece]
        for _ in range(4):  # moves whose middle gouges get a lifted point where it is worst
            if len(run) < 2:
                break
            worst, at = move_clearance(index, run[:-1], run[1:], r, step_mm=step)
            bad = np.flatnonzero(worst < -GOUGE_TOL_MM)
            if not len(bad):
                break
            fix, lift = lift_to_clear(index, at[bad], r, tol=GOUGE_TOL_MM / 10)
            fix[np.isnan(lift)] = np.nan
            mid = 0.5 * (ruv[bad] + ruv[bad + 1])
            lifts.append(lift[np.isfinite(lift)])
            lift_uv.append(mid[np.isfinite(lift)])
            run = np.insert(run, bad + 1, fix, axis=0)
            ruv = np.insert(ruv, bad + 1, mid, axis=0)
        else:
            worst, _ = move_clearance(index, run[:-1], run[1:], r, step_mm=step)
            run[np.flatnonzero(worst < -GOUGE_TOL_MM) + 1] = np.nan
        good = np.all(np.isfinite(run), axis=1)
        drop_uv.append(ruv[~good])
        out += [run[piece] for piece in _pieces(good)]
    return out, np.concatenate(lifts), np.concatenate(lift_uv), np.concatenate(drop_uv).reshape(-1, 2)


def exclude_points(box: tuple[float, float, float, float], uv: np.ndarray, *,
                   margin: float = 1 / 64) -> tuple[float, float, float, float]:
    """The largest of a few boxes inside `box` free of the points (float (k, 2)): every side moved inward
    past the points nearest to it, or one side moved past all of them (for trouble in the middle), each
    `margin` of the width beyond; may come back empty (u0 >= u1 or v0 >= v1).

    Parameters
    ----------
    box : tuple of 4 float
        The rectangle (u0, u1, v0, v1), parameters.
    uv : (k, 2) float
        The points to exclude, parameters; those outside `box` are ignored.
    margin : float
        How far beyond a point a side moves, as a fraction of the box's width in that direction.

    Returns
    -------
    tuple of 4 float
        The box (u0, u1, v0, v1) of largest parameter area among the candidates; `box` itself when no
        point lies in it.
    """
    u0, u1, v0, v1 = box
    wu, wv = u1 - u0, v1 - v0
    q = uv[(uv[:, 0] >= u0) & (uv[:, 0] <= u1) & (uv[:, 1] >= v0) & (uv[:, 1] <= v1)]
    if not len(q):
        return box
    depth = np.stack([(q[:, 0] - u0) / wu, (u1 - q[:, 0]) / wu, (q[:, 1] - v0) / wv, (v1 - q[:, 1]) / wv])
    nearest = np.argmin(depth, axis=0)

    def moved(side: int, d: float, b: list) -> list:
        b = list(b)
        step = (d + margin) * (wu if side < 2 else wv)
        b[side] = b[side] + step if side % 2 == 0 else b[side] - step
        return b

    each = [u0, u1, v0, v1]
    for side in range(4):
        if np.any(nearest == side):
            each = moved(side, float(depth[side, nearest == side].max()), each)
    candidates = [each] + [moved(side, float(depth[side].max()), [u0, u1, v0, v1]) for side in range(4)]
    return tuple(max(candidates, key=lambda b: max(b[1] - b[0], 0.0) * max(b[3] - b[2], 0.0)))


@dataclass(frozen=True)
class _Passes:
    """One try of a rectangle: its rings and path, the ball centres in runs (float (n_i, 3) each), the
    lifts kept (k,) mm with their parameters (k, 2), the dropped positions' parameters (j, 2), the
    predicted side, corner and chord errors (mm), their bound, and 1 / cos φ (how much a lift grows)."""

    grid: RingGrid
    path: RingPath
    spacing: tuple[float, float]
    runs: list[np.ndarray]
    lifts: np.ndarray
    lift_uv: np.ndarray
    drop_uv: np.ndarray
    side: float
    corner: float
    chord: float
    bound: float
    grow: float


def _plan_passes(patch: Patch, index: SurfaceIndex, *, r: float, h_s: float, tol: float, samples_per_line: int,
                 strategy: str, check_cancel: CheckCancel) -> _Passes:
    """Rings at scallop share h_s and chord tolerance tol, discretised and cleared against the part;
    raises `TooConcave` when a hollow tighter than the ball turns up."""
    grid = ring_grid(patch, tool_radius_mm=r, scallop_mm=h_s, samples_per_line=samples_per_line,
                     strategy=strategy, corner_mm=CORNER_SHARE * h_s)
    path = ring_path(patch, grid.rects, r=r, corner_mm=CORNER_SHARE * h_s, excursions=strategy == "adaptive",
                     spiral=strategy == "adaptive", claim=grid.claim, check_cancel=check_cancel)
    spacing = _spacing(patch, grid.rects, grid.side_steps)
    # A ball moved by δ moves the surface it cuts by at most δ; a normal line between passes meets
    # a ball at φ from its radius, sin φ ≤ (farthest point from a contact) / r, which is half the
    # largest interval beside a side and up to 0.586 of it in a corner pocket (0.6 taken). So a
    # ball raised by δ leaves at most δ / cos φ more and one moved sideways at most δ·tan φ.
    sin_phi = min(0.6 * spacing[1] / r, 1.0)
    grow = 1 / np.sqrt(1 - sin_phi ** 2) if sin_phi < 0.95 else np.inf
    # The lattice leaves a fifth of the chord share to sideways deviation, which splitting then removes
    # (splitting a move does not lower the lifts its ends share with their other moves).
    lat_u, lat_v = lattices(patch, r=r, tol=0.8 * tol)
    pts = discretize(patch, path.uv, path.kind, r=r, tol=tol, lat_u=lat_u, lat_v=lat_v,
                     lateral_weight=sin_phi * grow if np.isfinite(grow) else 3.0)
    runs, lifts, lift_uv, drop_uv = _clear_path(index, pts.centre, pts.uv, r, step=max(r / 4, 0.1))
    side = float(max(grid.side_scallop.max(initial=0.0), grid.edge_scallop.max()))
    corner = float(path.corner_scallop.max()) if path.corner_scallop.size else 0.0
    chord = float(pts.chord_error.max()) if pts.chord_error.size else 0.0
    bound = max(side, corner) + chord + ROUNDING_MM
    return _Passes(grid, path, spacing, runs, lifts, lift_uv, drop_uv, side, corner, chord, bound, grow)


def _box(patch: Patch) -> tuple[float, float, float, float]:
    (u0, u1), (v0, v1) = patch.domain
    return (u0, u1, v0, v1)


def restrict_patch(patch: Patch, region: tuple[float, float, float, float]) -> Patch:
    """The same patch on a parameter sub-rectangle (no knot insertion: a reparameterising wrapper).

    Parameters
    ----------
    patch : Patch
        The patch.
    region : tuple of 4 float
        The sub-rectangle (u0, u1, v0, v1), in the patch's parameters.

    Returns
    -------
    Patch
        Same id and sign; its surface a `SubSurface` with the same parameters on `region`.
    """
    return Patch(patch.id, SubSurface(patch.surface, region), patch.sign)


def _unreachable(region: tuple[float, float, float, float], excluded: int) -> None:
    if region[0] >= region[1] or region[2] >= region[3]:
        raise Unreachable("the ball cannot follow this patch without touching a neighbouring surface or "
                          "the shank meeting the part" if excluded else
                          "no rectangle of this patch can be reached: the ball would touch a neighbouring "
                          "surface, its shank the part, or the surface faces away from the tool")


def _named_in_part(exc: TooConcave, r: float, to_part) -> TooConcave:
    """The same hollow, its point named in the part's frame when `to_part` is given."""
    if to_part is None:
        return exc
    where = to_part(exc.point)
    return TooConcave(concave_message(exc.radius_mm, r, where), radius_mm=exc.radius_mm, point=where, uv=exc.uv)


def plan_patch(patch: Patch, index: SurfaceIndex, tool: ToolParams, toolpath: ToolpathParams, *,
               reach_fraction: float = 1.0, check_cancel: CheckCancel | None = None, to_part=None) -> PatchPlan:
    """Plan one patch in its setup's machine frame.

    The rectangle starts as the reachable domain and is shrunk (at most `MAX_REPLANS` times) past a
    hollow tighter than the ball, or past positions where the ball had to be lifted more than the
    target leaves over or could not be placed at all; rings are tightened (at most three times) where a
    corner pocket leaves more than the target. Raises `TooConcave`, `Unreachable` or `NotPlannable`
    when no rectangle keeps the bound. `to_part` maps machine-frame points (float (3,)) to the part
    frame the user's files are in, for the points the messages name; default: named as they are.

    The rings are planned at the scallop share h_s = (1 − chord_fraction)·h − `ROUNDING_MM` and the
    moves at the chord tolerance chord_fraction·h; lifts that fit in what the bound leaves of h are
    kept and added to it (times 1 / cos φ).

    Parameters
    ----------
    patch : Patch
        The patch in its setup's machine frame (tool axis +Z), sign outward.
    index : SurfaceIndex
        The whole part in the same frame (`cam.plan.gouge.build_index`).
    tool : ToolParams
        The ball (``radius_mm``).
    toolpath : ToolpathParams
        ``scallop_height_mm`` (the target h), ``chord_fraction``, ``samples_per_line`` and ``strategy``.
    reach_fraction : float
        The share of the patch the caller found reachable; recorded in the plan.
    check_cancel : callable or None
        Called between rings and replans; it stops the work by raising.
    to_part : callable or None
        Machine-frame point (3,) float mm → part-frame point (3,) float mm.

    Returns
    -------
    PatchPlan
        The passes on the planned rectangle and the bound certified there (≤ h).

    Raises
    ------
    TooConcave
        When a hollow tighter than the ball cannot be cut out of the rectangle.
    Unreachable
        When no rectangle can be reached, or after `MAX_REPLANS` smaller rectangles the ball still
        touches a neighbouring surface or the shank the part.
    NotPlannable
        When the corner pockets leave more than h even on tighter rings, or the fitted surface is
        degenerate.
    """
    t0 = time.perf_counter()
    r, h, chord_fraction = float(tool.radius_mm), float(toolpath.scallop_height_mm), float(toolpath.chord_fraction)
    check_cancel = check_cancel or (lambda: None)
    h_s, tol = (1 - chord_fraction) * h - ROUNDING_MM, chord_fraction * h
    region = reachable_domain(patch, index, tool_radius_mm=r, samples=toolpath.samples_per_line)
    whole, excluded, tightened, shrinks, hollows = patch, 0, 0, 0, []
    touched = region != _box(patch)  # the reach check already took some of it
    while True:
        _unreachable(region, excluded)
        patch = restrict_patch(whole, region) if region != _box(whole) else whole
        try:
            tried = _plan_passes(patch, index, r=r, h_s=h_s, tol=tol, samples_per_line=toolpath.samples_per_line,
                                 strategy=toolpath.strategy, check_cancel=check_cancel)
        except TooConcave as exc:
            # A hollow between the samples `finishable_region` looked at: the rectangle gives it up
            # like a lifted position; a hollow it cannot get rid of is reported as it was found.
            shrinks += 1
            exc = _named_in_part(exc, r, to_part)
            smaller = exclude_points(region, exc.uv) if len(exc.uv) else region
            if shrinks > MAX_REPLANS or smaller[0] >= smaller[1] or smaller[2] >= smaller[3] or smaller == region:
                raise exc
            region = smaller
            hollows.append(str(exc))
            continue
        if tried.bound > h:
            # A corner the excursion cannot bring under the scallop share (a full excursion still
            # leaves more than the side gaps): plan the whole patch a little tighter.
            if tightened == 3:
                raise NotPlannable(f"its corner pockets leave {tried.bound:.4g} mm even on tighter rings; "
                                   f"the target is {h:.4g} mm")
            h_s, tightened = h_s - (tried.bound - h) - 1e-3 * h, tightened + 1
            continue
        # Lifts that fit in what the target leaves over are kept and added to the bound (times 1 / cos φ);
        # larger ones, and dropped positions, are cut out of the rectangle.
        big = tried.lifts * tried.grow > h - tried.bound
        off = np.concatenate([tried.lift_uv[big], tried.drop_uv])
        if not len(off):
            bound = tried.bound + tried.grow * float(tried.lifts.max(initial=0.0))
            break
        # Where the ball was lifted more or left out, it does not touch the patch as planned: the
        # rectangle gives up the strip holding those positions and is planned again, so the claim holds.
        excluded += len(off)
        shrinks += 1
        if shrinks > MAX_REPLANS:
            raise Unreachable(f"the ball touches a neighbouring surface or the shank meets the part inside this "
                              f"patch; after {MAX_REPLANS} smaller rectangles it still does")
        check_cancel()
        region = exclude_points(region, off)
    passes = [run - np.array([0.0, 0.0, r]) for run in tried.runs]
    length = float(sum(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in passes))
    return PatchPlan(patch=patch.id, passes=passes, centres=tried.runs, certified_scallop_mm=bound, region=region,
                     side_scallop_mm=tried.side, corner_scallop_mm=tried.corner, chord_error_mm=tried.chord,
                     lift_mm=float(tried.lifts.max(initial=0.0)), spacing_mm=tried.spacing,
                     rings=len(tried.grid.rects), excursions=tried.path.excursions, path_length_mm=length,
                     reach_fraction=reach_fraction, replans=shrinks, excluded_points=excluded,
                     strategy=toolpath.strategy, time_s=time.perf_counter() - t0,
                     hollows=tuple(dict.fromkeys(hollows)), touched=touched or excluded > 0)
