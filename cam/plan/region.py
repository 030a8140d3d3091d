"""Where on a patch the ball can finish it: the parameter rectangle free of folds and of tight hollows.

A fitted patch may fold over itself in a thin strip along a border (its boundary curve sits on a
crease that the reconstructed mesh rounded), or hold a hollow whose radius of curvature is not
larger than the tool radius. On neither is a scallop bound meaningful: the first has no outward
normal, the second no tangent ball. The planner machines the parameter rectangle of largest area
that holds none of such samples (exactly, over the sample grid's rectangles), and reports what it
left out (verify then counts it as never reached). When no rectangle of three by three samples is
clear, the whole patch is reported, with the reason, never cut.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.plan.errors import concave_message
from cam.plan.scallop import fits_concave
from cam.spline.folds import FOLD_CHECK_SAMPLES, fold_mask
from cam.spline.geometry import Patch, frame, principal_curvatures

__all__ = ["Region", "finishable_region", "largest_clear_rectangle"]


@dataclass(frozen=True)
class Region:
    """The part of a patch the ball can finish.

    Attributes
    ----------
    box : tuple of 4 float or None
        (u0, u1, v0, v1) kept, parameters, or None when nothing is.
    kept : float
        Its share of the patch's area (0..1).
    reason : str
        Why samples were left out ("" when the whole patch is kept).
    """

    box: tuple[float, float, float, float] | None
    kept: float
    reason: str


def finishable_region(patch: Patch, tool_radius_mm: float, *, samples: int = FOLD_CHECK_SAMPLES) -> Region:
    """The parameter rectangle of `patch` of largest area without folds or hollows of radius ≤ `tool_radius_mm`.

    Checked on a samples x samples grid: the rectangle's sides lie on grid lines and no sample on
    or inside it is bad; of all such rectangles the one of largest surface area is kept. Samples
    where S_u × S_v vanishes (no normal, no curvature) are left out too.

    Parameters
    ----------
    patch : Patch
        The patch (part frame in `plan_job`), sign outward.
    tool_radius_mm : float
        Ball radius, mm.
    samples : int
        Grid size per parameter direction.

    Returns
    -------
    Region
        The whole domain with kept 1.0 and reason "" when no sample is bad; else the rectangle (at
        least three by three samples), its share of the area (sums of √(EG − F²) over the grid) and
        the reason; box None and kept 0.0 when no such rectangle is clear.
    """
    r = float(tool_radius_mm)
    folded, uu, vv = fold_mask(patch.surface, samples=samples)
    fr = frame(patch, uu, vv)
    with np.errstate(divide="ignore", invalid="ignore"):
        kmin, _ = principal_curvatures(fr)
    # Where S_u x S_v vanishes (a collapsed corner) there is no normal to offset along and no curvature:
    # such a sample is left out for that, and neither it nor a fold counts as a hollow.
    degenerate = ~np.isfinite(kmin) & ~folded
    hollow = ~fits_concave(kmin, r) & ~folded & ~degenerate
    bad = folded | hollow | degenerate
    area = np.sqrt(np.maximum(fr.e * fr.g - fr.f ** 2, 0.0))
    total = float(area.sum()) or 1.0
    if not bad.any():
        (u0, u1), (v0, v1) = patch.domain
        return Region((u0, u1, v0, v1), 1.0, "")
    best = largest_clear_rectangle(bad, area)
    if best is None:
        return Region(None, 0.0, _reason(patch, folded, hollow, degenerate, kmin, fr, r))
    i0, i1, j0, j1 = best
    kept = float(area[i0:i1 + 1, j0:j1 + 1].sum()) / total
    box = (float(uu[i0, 0]), float(uu[i1, 0]), float(vv[0, j0]), float(vv[0, j1]))
    return Region(box, kept, _reason(patch, folded, hollow, degenerate, kmin, fr, r))


def largest_clear_rectangle(bad: np.ndarray, weight: np.ndarray, *, min_span: int = 2
                            ) -> tuple[int, int, int, int] | None:
    """The rectangle of grid indices (i0, i1, j0, j1), inclusive, that holds no `bad` cell and has the
    largest sum of `weight` (float >= 0, same shape (n, m) as bad), with i1 - i0 and j1 - j0 at least
    `min_span`; None when there is none.

    For each top row i0 and bottom row i1 a column is clear when no row between them is bad there;
    with weights >= 0 the best rectangle on those rows is a whole run of clear columns. O(n² m).

    Parameters
    ----------
    bad : (n, m) bool
        Cells no rectangle may hold.
    weight : (n, m) float
        Weight of each cell, ≥ 0 (e.g. its area, mm²).
    min_span : int
        Least i1 − i0 and j1 − j0.

    Returns
    -------
    tuple of 4 int or None
        (i0, i1, j0, j1), inclusive, or None.

    Raises
    ------
    ValueError
        When `bad` and `weight` are not 2-D arrays of one shape.
    """
    bad = np.asarray(bad, dtype=bool)
    weight = np.asarray(weight, dtype=np.float64)
    if bad.shape != weight.shape or bad.ndim != 2:
        raise ValueError(f"bad and weight must be 2-D arrays of one shape, got {bad.shape} and {weight.shape}")
    n, m = bad.shape
    rows_sum = np.vstack([np.zeros((1, m)), np.cumsum(weight, axis=0)])
    best, out = -np.inf, None
    for i0 in range(n - min_span):
        blocked = np.logical_or.accumulate(bad[i0:], axis=0)[min_span:]  # bottom rows i0 + min_span ...
        w = rows_sum[i0 + min_span + 1:] - rows_sum[i0]
        tall = blocked.shape[0]
        run = np.cumsum(blocked, axis=1)  # clear columns of one run share their count of blocked ones
        key = (np.arange(tall)[:, None] * (m + 1) + run)[~blocked]
        sums = np.bincount(key, weights=w[~blocked], minlength=tall * (m + 1)).astype(np.float64)  # int when empty
        lengths = np.bincount(key, minlength=tall * (m + 1))
        sums[lengths < min_span + 1] = -np.inf
        k = int(np.argmax(sums))
        if sums[k] > best:
            best = float(sums[k])
            t, r = divmod(k, m + 1)
            cols = np.flatnonzero(~blocked[t] & (run[t] == r))
            out = (i0, i0 + min_span + t, int(cols[0]), int(cols[-1]))
    return out


def _reason(patch: Patch, folded, hollow, degenerate, kmin, fr, r: float) -> str:
    parts = []
    if degenerate.any():
        i = np.unravel_index(np.argmax(degenerate), degenerate.shape)
        parts.append(f"its fitted surface is degenerate (S_u x S_v vanishes, so there is no normal) near "
                     f"{np.round(fr.p[i], 3).tolist()}: that point is left out")
    if folded.any():
        i = np.unravel_index(np.argmax(folded), folded.shape)
        parts.append(f"its fitted surface folds over itself ({folded.mean():.1%} of it, near "
                     f"{np.round(fr.p[i], 3).tolist()}): no scallop bound can be certified there; refit "
                     "the patch (fit lists it under 'folded') or change remesh.target_faces")
    if hollow.any():
        i = np.unravel_index(np.argmin(np.where(hollow, kmin, np.inf)), kmin.shape)
        parts.append(concave_message(-1.0 / kmin[i], r, fr.p[i]))
    return "; ".join(parts)
