"""Raster passes on the shallow part of a setup: lines along machine x, the ball on the drop-cutter height.

Lines start at the flat pass interval for the scallop share. Between two neighbouring lines the
scallop is measured at every sample of x where both run (`cusps.cusp_heights`: the two balls' cusp and
its distance to the part); where it is over the share, a line is added half way between them, over
just those stretches and a margin, and checked again, down to a quarter of the first interval (what stays over after that, the clean-up takes). A line
runs only where the part is shallow enough for it (its contact normal within `max_slope_deg` of the
tool axis) and where the caller wants the part finished.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy.ndimage import binary_dilation

from cam import CheckCancel, Progress, progress_between
from cam.plan.cusps import cusp_heights
from cam.plan.lines import follow_part, merge_straight, split_runs
from cam.plan.part import SetupPart
from cam.plan.scallop import flat_spacing

__all__ = ["RasterPasses", "raster_passes"]


@dataclass(frozen=True)
class RasterPasses:
    """Raster passes of one setup.

    Attributes
    ----------
    passes : list of (n_i, 3) float64
        Ball centres of each pass in cutting order, mm, machine frame.
    scallop_mm : float
        Largest cusp height measured between neighbouring lines (0 with fewer than two lines).
    chord_mm : float
        Largest deviation of a move from the drop-cutter height.
    lines : int
        Lines (and partial lines) planned.
    """

    passes: list[np.ndarray]
    scallop_mm: float
    chord_mm: float
    lines: int


@dataclass
class _Line:
    y: float
    keep: np.ndarray  # bool (nx,) on the common x samples
    z: np.ndarray  # float (nx,) ball-centre heights


def _line(part: SetupPart, x: np.ndarray, y: float, wanted: np.ndarray, max_slope_cos: float,
          region: Callable[[np.ndarray], np.ndarray]) -> _Line:
    """A line at y over the x samples: its drop-cutter heights, and where it runs (`wanted`, on the part
    rather than the table, shallow, inside the region)."""
    xy = np.column_stack([x, np.full_like(x, y)])
    z, normal_z = part.contact(xy)
    keep = wanted & (np.nan_to_num(normal_z, nan=-1.0) >= max_slope_cos) & region(xy)
    return _Line(y=y, keep=keep, z=z)


def _pairs(lines: list[_Line]) -> list[tuple[int, int, np.ndarray]]:
    """Neighbouring lines (in y) at each x sample where both run: (lower, upper, bool mask of x)."""
    keep = np.array([ln.keep for ln in lines])
    out: dict[tuple[int, int], np.ndarray] = {}
    for j in range(keep.shape[1]):
        rows = np.flatnonzero(keep[:, j])
        for a, b in pairwise(rows):
            out.setdefault((int(a), int(b)), np.zeros(keep.shape[1], bool))[j] = True
    return [(a, b, m) for (a, b), m in out.items()]


def raster_passes(part: SetupPart, *, bounds: tuple[float, float, float, float],
                  scallop_mm: float, chord_mm: float, region: Callable[[np.ndarray], np.ndarray],
                  max_slope_deg: float = 60.0, max_splits: int = 2,
                  check_cancel: CheckCancel | None = None, progress: Progress | None = None) -> RasterPasses:
    """Raster passes over the part's shallow area inside `bounds` (machine xy).

    Parameters
    ----------
    part : SetupPart
        The part in the setup's machine frame, for the ball.
    bounds : (x0, x1, y0, y1)
        Where lines may run, mm.
    scallop_mm : float
        The scallop share of the target: the cusp height allowed between lines.
    chord_mm : float
        The chord share.
    region : callable
        region(xy (n, 2)) -> bool (n,): where passes are wanted (the area still to finish).
    max_slope_deg : float
        Steeper contacts are left to waterlines.
    max_splits : int
        Times a line interval may be halved.
    check_cancel : callable, optional
    progress : callable, optional
        progress(fraction, message) line by line as the lines are laid, round by round as they are
        split, and line by line as they become passes.

    Returns
    -------
    RasterPasses
    """
    r = part.radius_mm
    check_cancel = check_cancel or (lambda: None)
    report = progress or (lambda fraction, message=None: None)
    x0, x1, y0, y1 = bounds
    step = float(flat_spacing(scallop_mm, r))
    dx = min(0.25 * step, 0.5)
    x = np.arange(x0, x1 + 0.5 * dx, dx)
    ys = np.arange(y0 + 0.5 * step, y1, step) if y1 - y0 > step else np.array([0.5 * (y0 + y1)])
    cos_max = float(np.cos(np.radians(max_slope_deg)))
    everywhere = np.ones(len(x), dtype=bool)
    lines = []
    for k, y in enumerate(ys):
        report(0.4 * k / len(ys), f"raster line {k + 1} of {len(ys)}")
        lines.append(_line(part, x, float(y), everywhere, cos_max, region))
    margin = max(int(np.ceil(0.5 * step / dx)), 1)
    for split in range(max_splits + 1):
        check_cancel()
        report(0.4 + 0.4 * split / (max_splits + 1), f"raster: the cusps between {len(lines)} lines, round {split + 1}")
        cusps = list(_cusps(lines, x, part, scallop_mm, cos_max))
        # The largest cusp left between neighbouring lines as they stand. A gap (+inf: the balls do not
        # meet, or a hump between them) is no scallop: the coverage check sees it as material not cut.
        worst = max((float(np.max(h[np.isfinite(h)], initial=0.0)) for *_, h in cusps), default=0.0)
        added = [_line(part, x, 0.5 * (lines[a].y + lines[b].y), binary_dilation(over, iterations=margin),
                       cos_max, region) for a, b, over, _ in cusps if over.any()] if split < max_splits else []
        if not added:
            break
        lines += added
        worst = float("nan")  # the new lines are unchecked until the next round
    return _passes(part, lines, x, chord_mm=chord_mm, worst=worst, progress=progress_between(report, 0.8, 1.0))


def _cusps(lines: list[_Line], x: np.ndarray, part: SetupPart, scallop_mm: float, cos_max: float):
    """For each pair of neighbouring lines: (lower, upper, bool (nx,) where the cusp is over the share,
    the cusp heights where both run). Sorts `lines` by y."""
    lines.sort(key=lambda ln: ln.y)
    for a, b, at in _pairs(lines):
        c1 = np.column_stack([x[at], np.full(at.sum(), lines[a].y), lines[a].z[at]])
        c2 = np.column_stack([x[at], np.full(at.sum(), lines[b].y), lines[b].z[at]])
        h, foot, normal, between = cusp_heights(c1, c2, np.tile([0.0, 0.0, -1.0], (len(c1), 1)), part.mesh,
                                                tool_radius_mm=part.radius_mm, over_mm=scallop_mm)
        # Material in a hollow the ball cannot reach is no scallop more lines would lower (it is left to
        # the rest tool), and material on a wall steeper than the lines run on is the waterlines' to take.
        # Balls that do not meet (+inf: a cliff between the lines, the waterlines' to take) are no neighbours.
        h = np.where(between & part.reaches(foot, normal) & (np.nan_to_num(normal[:, 2], nan=1.0) >= cos_max), h, 0.0)
        over = np.zeros(len(x), bool)
        over[np.flatnonzero(at)] = h > scallop_mm * (1 + 1e-6) + 1e-9
        yield a, b, over, h


def _passes(part: SetupPart, lines: list[_Line], x: np.ndarray, *, chord_mm: float, worst: float,
            progress: Progress) -> RasterPasses:
    """Each line's runs as passes, alternating direction line by line, with their moves refined."""
    passes, chord = [], 0.0
    for k, ln in enumerate(sorted(lines, key=lambda ln: ln.y)):
        progress(k / len(lines), f"raster passes: line {k + 1} of {len(lines)} on the part")
        for run in split_runs(ln.keep):
            pts = np.column_stack([x[run], np.full(run.stop - run.start, ln.y), ln.z[run]])
            pts, dev = follow_part(part, pts[::-1] if k % 2 else pts, chord_mm=chord_mm, lift_mm=0.5 * chord_mm)
            passes.append(merge_straight(pts))
            chord = max(chord, dev)
    return RasterPasses(passes=passes, scallop_mm=worst, chord_mm=chord, lines=len(lines))
