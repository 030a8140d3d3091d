"""Whole-part finishing of one setup on the mesh: raster on the shallow area, waterlines on the steep one,
clean-up passes for what is left, aimed at the samples of the part the setup is to finish.

The strategies overlap by a band of slopes (the raster runs up to 60°, waterlines from 45°), and each is
limited to the xy area around the target samples' balls. After them the planner measures what the
passes leave on every target sample (`coverage.left_on_samples`); samples still over the target get
clean-up passes, and are measured again.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import binary_dilation

from cam import CheckCancel, Progress, progress_between
from cam.plan.cleanup import cleanup_passes
from cam.plan.coverage import left_on_samples
from cam.plan.part import SetupPart
from cam.plan.raster import raster_passes
from cam.plan.scallop import flat_spacing
from cam.plan.waterline import waterline_passes

__all__ = ["FinishedSetup", "finish_setup", "target_region"]

RASTER_MAX_SLOPE_DEG = 60.0
WATERLINE_MIN_SLOPE_DEG = 45.0


@dataclass
class FinishedSetup:
    """What whole-part finishing planned for one setup and one ball.

    Attributes
    ----------
    passes : list of (n_i, 3) float64
        Ball centres, mm, machine frame, in planning order.
    strategy : list of str
        "raster", "waterline" or "cleanup", one per pass.
    certified_mm : dict of str to float
        Per strategy, the largest scallop measured between its neighbouring passes plus its chord error.
    left : (k,) float64
        Material the passes leave on each target sample, mm (+inf: not reached within the measured range).
    stats : dict
    """

    passes: list[np.ndarray] = field(default_factory=list)
    strategy: list[str] = field(default_factory=list)
    certified_mm: dict[str, float] = field(default_factory=dict)
    left: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stats: dict = field(default_factory=dict)

    def add(self, name: str, passes: list[np.ndarray]) -> None:
        self.passes += passes
        self.strategy += [name] * len(passes)


def target_region(centres_xy: np.ndarray, bounds: tuple[float, float, float, float], *, cell_mm: float,
                  grow_mm: float) -> Callable[[np.ndarray], np.ndarray]:
    """region(xy (n, 2)) -> bool (n,): within about `grow_mm` of any of the ball centres (k, 2) given."""
    x0, x1, y0, y1 = bounds
    shape = (int(np.ceil((x1 - x0) / cell_mm)) + 1, int(np.ceil((y1 - y0) / cell_mm)) + 1)
    grid = np.zeros(shape, dtype=bool)
    ij = np.floor((centres_xy - [x0, y0]) / cell_mm).astype(np.int64)
    ok = (ij >= 0).all(axis=1) & (ij[:, 0] < shape[0]) & (ij[:, 1] < shape[1])
    grid[ij[ok, 0], ij[ok, 1]] = True
    grid = binary_dilation(grid, iterations=max(int(np.ceil(grow_mm / cell_mm)), 1))

    def region(xy: np.ndarray) -> np.ndarray:
        q = np.floor((np.asarray(xy) - [x0, y0]) / cell_mm).astype(np.int64)
        inside = (q >= 0).all(axis=1) & (q[:, 0] < shape[0]) & (q[:, 1] < shape[1])
        out = np.zeros(len(q), dtype=bool)
        out[inside] = grid[q[inside, 0], q[inside, 1]]
        return out

    return region


def finish_setup(part: SetupPart, points: np.ndarray, normals: np.ndarray, *, scallop_mm: float, chord_mm: float,
                 target_mm: float, cleanup_rounds: int = 2, processes: int = 1,
                 check_cancel: CheckCancel | None = None, progress: Progress | None = None) -> FinishedSetup:
    """Plan raster, waterline and clean-up passes that finish the given samples of the part.

    Parameters
    ----------
    part : SetupPart
        The part in the setup's machine frame, for the ball.
    points, normals : (k, 3) float
        The samples to finish (reachable in this setup), machine frame, outward unit normals.
    scallop_mm, chord_mm : float
        The scallop and chord shares the strategies plan with.
    target_mm : float
        The scallop height a sample counts as finished within.
    cleanup_rounds : int
        Times the leftover samples get clean-up passes and are measured again.
    processes : int
        Waterline levels worked on at once, in forked processes (the passes are the same).
    check_cancel : callable, optional
    progress : callable, optional
        progress(fraction, message) through the raster's lines, the waterline's levels and the clean-up
        rounds.

    Returns
    -------
    FinishedSetup
    """
    out = FinishedSetup(left=np.full(len(points), np.inf))
    if not len(points):
        return out
    report = progress or (lambda fraction, message=None: None)
    r = part.radius_mm
    step = float(flat_spacing(scallop_mm, r))
    centres = points + r * normals
    lo, hi = centres[:, :2].min(axis=0) - step, centres[:, :2].max(axis=0) + step
    bounds = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
    region = target_region(centres[:, :2], bounds, cell_mm=0.5 * step, grow_mm=step)
    raster = raster_passes(part, bounds=bounds, scallop_mm=scallop_mm, chord_mm=chord_mm, region=region,
                           max_slope_deg=RASTER_MAX_SLOPE_DEG, check_cancel=check_cancel,
                           progress=progress_between(report, 0.0, 0.4))
    out.add("raster", raster.passes)
    out.certified_mm["raster"] = raster.scallop_mm + raster.chord_mm
    waterline = waterline_passes(part, bounds=bounds, scallop_mm=scallop_mm, chord_mm=chord_mm, region=region,
                                 min_slope_deg=WATERLINE_MIN_SLOPE_DEG, processes=processes, check_cancel=check_cancel,
                                 progress=progress_between(report, 0.4, 0.8))
    out.add("waterline", waterline.passes)
    out.certified_mm["waterline"] = waterline.scallop_mm + waterline.chord_mm
    report(0.8, f"measuring what {len(out.passes)} passes leave on {len(points)} samples")
    out.left = left_on_samples(out.passes, points, normals, tool_radius_mm=r, reach_mm=target_mm)
    out.stats = {"raster_lines": raster.lines, "waterline_levels": waterline.levels}
    for k in range(cleanup_rounds):
        if check_cancel is not None:
            check_cancel()
        over = ~(out.left <= target_mm)
        if not over.any():
            break
        report(0.85 + 0.15 * k / cleanup_rounds, f"clean-up round {k + 1} of {cleanup_rounds} at most: "
                                                 f"{int(over.sum())} samples left over")
        more = cleanup_passes(part, points[over], normals[over], chord_mm=chord_mm, link_mm=0.5 * step)
        out.add("cleanup", more)
        left_more = left_on_samples(more, points[over], normals[over], tool_radius_mm=r, reach_mm=target_mm)
        out.left[over] = np.minimum(out.left[over], left_more)
        out.stats[f"cleanup_round_{k + 1}"] = int(over.sum())
    out.certified_mm["cleanup"] = 0.0  # each sample it is aimed at is touched; what is left is measured
    return out
