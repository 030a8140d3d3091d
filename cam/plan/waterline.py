"""Waterline passes on the steep part of a setup: the ball at constant heights, touching the walls.

At a height z, the ball touches the part exactly where the drop-cutter height equals z: the passes are
the contours of the drop-cutter height, found on a grid (marching squares) and then put on the exact
level by bisection between the grid nodes around them, each move checked at its middle (a move that
would cut the wall, or pass farther from it than the chord share, gets the true contour point there).
Levels start one flat pass interval apart; between two levels the scallop is measured where the walls
are (`cusps.cusp_heights`), and a level half way is added near the stretches over the share, down to a
sixteenth of the first interval. A level runs only where the part is steep (its contact normal at least
`min_slope_deg` from the tool axis) and where the caller wants the part finished.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy.spatial import cKDTree
from skimage.measure import find_contours

from cam import CheckCancel, Progress, map_forked, progress_labelled
from cam.plan.cusps import cusp_heights
from cam.plan.lines import GOUGE_TOL_MM, merge_straight, split_runs
from cam.plan.part import SetupPart
from cam.plan.scallop import flat_spacing

__all__ = ["WaterlinePasses", "waterline_passes"]

#: A contour point whose ball at the level is this much farther than r from the part touches nothing there
#: (a contour across the ball's own drop onto the table, not along a wall).
TOUCH_TOL_MM = 0.02
#: Halvings that put a contour point on its level: it lies at most spacing / 2**BISECT_ROUNDS off the level
#: set, on the clear side, and that offset is part of the chord share.
BISECT_ROUNDS = 16


@dataclass(frozen=True)
class WaterlinePasses:
    """Waterline passes of one setup.

    Attributes
    ----------
    passes : list of (n_i, 3) float64
        Ball centres of each pass, mm, machine frame, each at one height.
    scallop_mm : float
        Largest cusp height measured between neighbouring levels.
    chord_mm : float
        Largest distance a move leaves from the wall beyond its ends.
    levels : int
    """

    passes: list[np.ndarray]
    scallop_mm: float
    chord_mm: float
    levels: int


@dataclass(frozen=True)
class _Grid:
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray  # (nx, ny) drop-cutter heights (the table's where the ball misses the part)


def _grid(part: SetupPart, bounds, spacing: float) -> _Grid:
    x0, x1, y0, y1 = bounds
    x, y = np.arange(x0, x1 + 0.5 * spacing, spacing), np.arange(y0, y1 + 0.5 * spacing, spacing)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    return _Grid(x, y, part.drop(np.column_stack([xx.ravel(), yy.ravel()])).reshape(xx.shape))


def _on_level(part: SetupPart, a: np.ndarray, b: np.ndarray, level: float, rounds: int = BISECT_ROUNDS) -> np.ndarray:
    """Bisect between xy points a (k, 2) and b (k, 2) whose drop-cutter heights bracket `level`; returns the
    end on the side where the ball at `level` clears the part (drop ≤ level)."""
    out_a = part.clears(a, level)  # a is outside (clear) where its drop is not above the level
    lo, hi = np.where(out_a[:, None], a, b), np.where(out_a[:, None], b, a)  # lo: clear, hi: inside
    for _ in range(rounds):
        mid = 0.5 * (lo + hi)
        inside = ~part.clears(mid, level)
        lo = np.where(inside[:, None], lo, mid)
        hi = np.where(inside[:, None], mid, hi)
    return lo


def _contour_points(grid: _Grid, part: SetupPart, level: float) -> list[np.ndarray]:
    """The level's contours as xy polylines on the exact level (clear side), all bisected in one batch."""
    contours = find_contours(grid.z, level)
    if not contours:
        return []
    c = np.concatenate(contours)
    i0, j0 = np.floor(c[:, 0]).astype(int), np.floor(c[:, 1]).astype(int)
    i1 = np.minimum(i0 + (c[:, 0] > i0), len(grid.x) - 1)
    j1 = np.minimum(j0 + (c[:, 1] > j0), len(grid.y) - 1)
    a = np.column_stack([grid.x[i0], grid.y[j0]])
    b = np.column_stack([grid.x[i1], grid.y[j1]])
    same = np.all(a == b, axis=1)  # a contour point on a node: nothing to bisect
    xy = a.copy()
    if (~same).any():
        xy[~same] = _on_level(part, a[~same], b[~same], level)
    return np.split(xy, np.cumsum([len(k) for k in contours])[:-1])


def _push_out(part: SetupPart, xy: np.ndarray, level: float, lift_mm: float) -> np.ndarray:
    """Contour points (k, 2) moved `lift_mm` away from the wall, level, where that cuts nothing."""
    if not len(xy) or lift_mm <= 0:
        return xy
    _, normal = part.nearest(np.column_stack([xy, np.full(len(xy), level)]))
    away = normal[:, :2]
    length = np.linalg.norm(away, axis=1, keepdims=True)
    pushed = xy + lift_mm * np.where(length > 1e-6, away / np.maximum(length, 1e-300), 0.0)
    # In a tight inner corner the push from one wall can bring the ball to the other: keep the point there.
    clear = part.clears(pushed, level + GOUGE_TOL_MM)
    return np.where(clear[:, None], pushed, xy)


def _follow_walls(part: SetupPart, runs: list[np.ndarray], level: float, *, chord_mm: float, spacing: float,
                  lift_mm: float, max_depth: int = 8) -> tuple[list[np.ndarray], float]:
    """Push waterline polylines (xy (n_i, 2) each) `lift_mm` off the walls, then insert true contour points
    (pushed alike) where a move's middle would cut the part or pass more than `chord_mm` from the contour;
    all polylines of a level in one batch. Like a raster's lift, the push lets a move round a convex
    corner sag that far before it cuts."""
    runs = [_push_out(part, r, level, lift_mm) for r in runs if len(r)]
    worst = lift_mm
    for depth in range(max_depth + 1):
        moves = [(k, j) for k, r in enumerate(runs) for j in range(len(r) - 1)]
        if not moves:
            return runs, 0.0
        a = np.concatenate([r[:-1] for r in runs if len(r) > 1])
        b = np.concatenate([r[1:] for r in runs if len(r) > 1])
        mid, d = 0.5 * (a + b), b - a
        across = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
        # Which of the middle and the points a spacing to either side the ball at the level would cut.
        inside_mid = ~part.clears(mid, level)
        inside_p, inside_n = ~part.clears(mid + spacing * across, level), ~part.clears(mid - spacing * across, level)
        # The true contour near the middle: between the middle and the side whose height is across the level.
        side = np.where(inside_p != inside_mid, 1.0, np.where(inside_n != inside_mid, -1.0, 0.0))
        ok = side != 0
        true = mid.copy()
        if ok.any():
            true[ok] = _on_level(part, mid[ok], mid[ok] + side[ok, None] * spacing * across[ok], level)
        off = np.linalg.norm(true - mid, axis=1)
        bad = ok & ((off > chord_mm) | ~part.clears(mid, level + GOUGE_TOL_MM))
        worst = max(lift_mm, float(np.max(np.where(ok, off, 0.0), initial=0.0)))
        if not bad.any() or depth == max_depth:
            return runs, worst
        owner = np.array([k for k, _ in moves])
        at = np.array([j for _, j in moves])
        for k in np.unique(owner[bad]):
            mine = bad & (owner == k)
            runs[k] = np.insert(runs[k], at[mine] + 1, _push_out(part, true[mine], level, lift_mm), axis=0)
    return runs, worst


def _level_runs(grid: _Grid, part: SetupPart, level: float, *, steep_cos: float,
                region: Callable[[np.ndarray], np.ndarray], near: cKDTree | None, near_mm: float) -> list[np.ndarray]:
    """The level's contour stretches where the ball at that height touches a steep wall and is wanted (and
    near `near`'s points, if given)."""
    contours = _contour_points(grid, part, level)
    if not contours:
        return []
    xy = np.concatenate(contours)
    # The contact normal of the ball at this height, not of the ball dropped there: beside a wall that
    # stands on the table the dropped ball rests on the table, while at the level it touches the wall.
    distance, normal = part.nearest(np.column_stack([xy, np.full(len(xy), level)]))
    touches = distance <= part.radius_mm + TOUCH_TOL_MM
    keep = touches & (normal[:, 2] < steep_cos) & region(xy)
    if near is not None:
        keep &= near.query(xy, distance_upper_bound=near_mm)[0] <= near_mm
    runs = []
    for c, k in zip(contours, np.split(keep, np.cumsum([len(c) for c in contours])[:-1])):
        runs += [c[run] for run in split_runs(k)]
    return runs


def waterline_passes(part: SetupPart, *, bounds: tuple[float, float, float, float],
                     scallop_mm: float, chord_mm: float, region: Callable[[np.ndarray], np.ndarray],
                     min_slope_deg: float = 45.0, max_splits: int = 2, grid_mm: float | None = None,
                     processes: int = 1, check_cancel: CheckCancel | None = None,
                     progress: Progress | None = None) -> WaterlinePasses:
    """Waterline passes over the part's steep area inside `bounds` (machine xy).

    Parameters
    ----------
    part : SetupPart
        The part in the setup's machine frame, for the ball.
    bounds : (x0, x1, y0, y1)
        Where passes may run, mm.
    scallop_mm, chord_mm : float
        The scallop and chord shares of the target.
    region : callable
        region(xy (n, 2)) -> bool (n,): where passes are wanted.
    min_slope_deg : float
        Shallower contacts are left to the raster.
    max_splits : int
        Times a level interval may be halved.
    grid_mm : float, optional
        Spacing of the drop-cutter grid the contours are found on; default a quarter of the flat pass
        interval, at most 0.5 mm.
    processes : int
        Levels worked on at once, in forked processes (`cam.map_forked`): each level's contours, and each
        level's passes, are the same computed alone.
    check_cancel : callable, optional
    progress : callable, optional
        progress(fraction, message) level by level as the levels are found and as they become passes,
        and round by round as they are split.

    Returns
    -------
    WaterlinePasses
    """
    r = part.radius_mm
    check_cancel = check_cancel or (lambda: None)
    report = progress or (lambda fraction, message=None: None)
    step = float(flat_spacing(scallop_mm, r))
    spacing = grid_mm or min(0.25 * step, 0.5)
    report(0.0, "waterline: the drop-cutter grid")
    grid = _grid(part, bounds, spacing)
    steep_cos = float(np.cos(np.radians(min_slope_deg)))
    table = part.floor_z + r
    # From half an interval under the highest ball position down to the lowest above the table.
    z_top = float(grid.z.max())
    zs = [float(z) for z in np.arange(z_top - 0.5 * step, table, -step)]

    def level_runs(k: int, _cc) -> list[np.ndarray]:
        return _level_runs(grid, part, zs[k], steep_cos=steep_cos, region=region, near=None, near_mm=0)

    found = map_forked(level_runs, len(zs), processes=processes, check_cancel=check_cancel,
                       progress=progress_labelled(report, 0.1, 0.5, "waterline level", sep=" "))
    levels = dict(zip(zs, found))
    resolution = spacing / 2**BISECT_ROUNDS
    for split in range(max_splits + 1):
        check_cancel()
        report(0.5 + 0.2 * split / (max_splits + 1), f"waterline: the cusps between {len(levels)} levels, "
                                                      f"round {split + 1}")
        over = list(_over(levels, part, scallop_mm + resolution, steep_cos))
        worst = max((h for *_, h in over), default=0.0)  # the largest finite cusp between the levels as they stand
        between = [(0.5 * (za + zb), bad_xy) for za, zb, bad_xy, _ in (over if split < max_splits else [])
                   if len(bad_xy)]
        if not between:
            break

        def added_runs(k: int, _cc, between=between) -> list[np.ndarray]:
            zm, bad_xy = between[k]
            return _level_runs(grid, part, zm, steep_cos=steep_cos, region=region, near=cKDTree(bad_xy),
                               near_mm=step)

        levels.update(zip([zm for zm, _ in between],
                          map_forked(added_runs, len(between), processes=processes, check_cancel=check_cancel)))
    ordered = sorted(levels.items(), reverse=True)

    def followed(k: int, _cc) -> tuple[list[np.ndarray], float]:
        z, runs = ordered[k]
        return _follow_walls(part, runs, z, chord_mm=chord_mm, spacing=spacing, lift_mm=0.5 * chord_mm)

    passes, chord = [], resolution
    done = map_forked(followed, len(ordered), processes=processes, check_cancel=check_cancel,
                      progress=progress_labelled(report, 0.7, 1.0, "waterline passes along the walls: level", sep=" "))
    for (z, _), (runs, dev) in zip(ordered, done):
        chord = max(chord, dev)
        passes += [merge_straight(np.column_stack([xy, np.full(len(xy), z)])) for xy in runs]
    return WaterlinePasses(passes=passes, scallop_mm=float(worst), chord_mm=chord, levels=len(levels))


def _over(levels: dict[float, list[np.ndarray]], part: SetupPart, scallop_mm: float, steep_cos: float):
    """For each pair of neighbouring levels (upper, lower): the upper level's points whose cusp with the
    nearest point of the lower one is over the share (xy (k, 2)), and the largest finite cusp height."""
    zs = sorted((z for z, runs in levels.items() if runs), reverse=True)
    for za, zb in pairwise(zs):
        # Every third point: a cusp changes slowly along a level, and a new level is laid a whole interval
        # around each point found over the share.
        a = np.concatenate(levels[za])[::3]
        b = np.concatenate(levels[zb])
        _, nearest = cKDTree(b).query(a)
        c1 = np.column_stack([a, np.full(len(a), za)])
        c2 = np.column_stack([b[nearest], np.full(len(a), zb)])
        toward = -part.wall_normals(c1)
        toward[:, 2] = 0.0  # into the wall, level
        h, foot, normal, between = cusp_heights(c1, c2, toward, part.mesh, tool_radius_mm=part.radius_mm,
                                                over_mm=scallop_mm)
        # Material on a shallow foot is the raster's; in a hollow the ball cannot reach, the rest tool's.
        # Balls that do not meet (+inf) are no neighbours: the wall ends between them, and the next
        # strategy or the clean-up takes what is there.
        counted = between & part.reaches(foot, normal) & (np.nan_to_num(normal[:, 2], nan=1.0) < steep_cos)
        h = np.where(counted, h, 0.0)
        yield za, zb, a[h > scallop_mm * (1 + 1e-6) + 1e-9], float(np.max(h[np.isfinite(h)], initial=0.0))
