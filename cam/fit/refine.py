"""Refinement: where a fit stays outside the tolerance, halve the knot spans there and fit again.

Knots live in grid-index units (quad counts along the side), so halving keeps them
dyadic fractions of the grid: neighbouring patches and both sides of one patch
produce bit-identical knot values wherever they mean the same place, and merging
their knot vectors never creates near-duplicates.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cam import CheckCancel, Progress
from cam.fit.measure import border_distance, surface_peaks
from cam.fit.solve import SurfaceFit, fit_surface
from cam.spline.basis import find_spans
from cam.spline.knots import refine_surface

__all__ = ["Refined", "split_spans", "refine_targets", "border_mask", "fit_refined"]


@dataclass(frozen=True, eq=False)
class Refined:
    """What `fit_refined` returns.

    Attributes
    ----------
    fit : SurfaceFit
        The best fit.
    rounds : int
        The rounds tried.
    unrefined : SurfaceFit
        The fit on the knots given, before any round (`fit` itself when no round was kept).
    peaks : tuple of three ndarray, each shape (k,), float64
        The best fit's `cam.fit.measure.surface_peaks`: u, v (grid-index units) and distance (mm);
        empty where they were not searched for.
    """

    fit: SurfaceFit
    rounds: int
    unrefined: SurfaceFit
    peaks: tuple[np.ndarray, np.ndarray, np.ndarray]


def split_spans(knots: np.ndarray, params: np.ndarray, *, degree: int = 3, min_span: float = 0.125) -> np.ndarray:
    """`knots` with a knot added in the middle of every span that holds one of `params`.

    Parameters
    ----------
    knots : ndarray, shape (k,), float64
        A clamped knot vector, parameter units.
    params : ndarray, shape (m,), float64
        Parameters whose spans are halved.
    degree : int
        The curve's degree.
    min_span : float
        Spans shorter than 2 * min_span are left alone (the refinement stops there).

    Returns
    -------
    ndarray, shape (k + s,), float64
        A new sorted knot vector with the s midpoints added (s = 0: a copy).
    """
    k = np.asarray(knots, dtype=np.float64)
    params = np.asarray(params, dtype=np.float64).ravel()
    if params.size == 0:
        return k.copy()
    spans = np.unique(find_spans(k, degree, params))
    lo, hi = k[spans], k[spans + 1]
    keep = (hi - lo) >= 2 * min_span
    mids = 0.5 * (lo[keep] + hi[keep])
    return np.sort(np.concatenate([k, mids]))


def refine_targets(knots_u: np.ndarray, knots_v: np.ndarray, u: np.ndarray, v: np.ndarray, bad: np.ndarray, *,
                   degree: tuple[int, int] = (3, 3), min_span: float = 0.125) -> tuple[np.ndarray, np.ndarray]:
    """Knot vectors with the u- and v-spans of the samples flagged `bad` halved.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's knot vectors, grid-index units.
    u, v : ndarray, shape (n,), float64
        The samples' parameters.
    bad : ndarray, shape (n,), bool
        The samples whose spans are halved.
    degree : tuple of int
        (p, q), the surface's degrees.
    min_span : float
        See `split_spans`.

    Returns
    -------
    knots_u, knots_v : ndarray, float64
        The new knot vectors (`split_spans` of each).
    """
    bad = np.asarray(bad, dtype=bool)
    return (split_spans(knots_u, np.asarray(u)[bad], degree=degree[0], min_span=min_span),
            split_spans(knots_v, np.asarray(v)[bad], degree=degree[1], min_span=min_span))


def border_mask(shape: tuple[int, int]) -> np.ndarray:
    """The outer ring of a control net (the four boundary curves).

    Parameters
    ----------
    shape : tuple of int
        (nu, nv), the net's size.

    Returns
    -------
    ndarray, shape (nu, nv), bool
        True on the first and last rows and columns.
    """
    m = np.zeros(shape, dtype=bool)
    m[0, :] = m[-1, :] = m[:, 0] = m[:, -1] = True
    return m


def fit_refined(points: np.ndarray, normals: np.ndarray, u: np.ndarray, v: np.ndarray, *, knots_u: np.ndarray,
                knots_v: np.ndarray, control_points: np.ndarray | None = None, fix_border: bool = False,
                tolerance_mm: float, max_refinements: int = 3, min_span: float = 0.125, min_gain: float = 0.1,
                min_drop: float = 0.01, border_band: float = 0.5, judge_band: float | None = None,
                check_cancel: CheckCancel | None = None, progress: Progress | None = None, **options) -> Refined:
    """`fit_surface`, then up to `max_refinements` rounds of halving the spans with samples beyond tolerance.

    Spans are halved where samples are beyond the tolerance, and where the surface is (with a `mesh`
    in the options: on the fit's lattice and, inside fixed borders, at the peaks
    `cam.fit.measure.surface_peaks` finds between its points, which then count in comparing rounds
    too, and are returned), except within `border_band` parameter units of a fixed border (at most a
    quarter of the domain's narrower side, so a patch one quad wide still refines in its middle)
    unless farther from the mesh than the border is. Two rounds in a row that each lower the error
    beyond the tolerance (`SurfaceFit.excess`) of the best fit so far by less than the fraction
    `min_gain` end the refinement; so does one round that lowers the largest distance by less than the
    fraction `min_drop`: new spans round the worst point took nothing off it, and the next round's four
    times as many control points would not either (a fold of the mesh, a crease through the patch, a
    fixed border's own error). Inside fixed borders with a `mesh`, no round is tried where the border
    itself lies farther from the mesh than the tolerance (`cam.fit.measure.border_distance`): the
    surface stays beyond it whatever the knots.

    Parameters
    ----------
    points, normals, u, v
        The samples (n, 3) mm, their unit mesh normals (n, 3) and starting parameters (n,), float64:
        see `cam.fit.solve.fit_surface`.
    knots_u, knots_v : ndarray, shape (nu + 4,), (nv + 4,), float64
        The knots to start with, grid-index units (quads).
    control_points : ndarray, shape (nu, nv, 3), float64, or None
        The start, mm (required with `fix_border`).
    fix_border : bool
        Keep the outer ring of control points (knot insertion moves no boundary curve, so the border
        stays the shared curves through every round); samples beyond a fixed border are ignored (they
        belong to the neighbour).
    tolerance_mm : float
        The distance the fit aims to stay within, mm.
    max_refinements : int
        Rounds of span halving at most.
    min_span : float
        Spans are never halved below this, grid-index units.
    min_gain : float
        See above: the fraction a round must gain.
    min_drop : float
        See above: the fraction a round must take off the largest distance.
    border_band : float
        See above, grid-index units.
    judge_band : float or None
        Only the samples and surface points within this many grid-index units of the domain's sides (at
        most a quarter of its narrower side, as `border_band`) are refined for and judged: a free fit
        only places the borders the boundary curves are fitted to. None: all of them.
    check_cancel : callable or None
        Called before every round and every step of `fit_surface`; it raises to stop the fit.
    progress : callable or None
        progress(fraction, message) before every step of `fit_surface`: each of the 1 + `max_refinements`
        fits at most takes an equal share (rounds not needed are skipped over at the end).
    **options
        Passed on to `cam.fit.solve.fit_surface` (mesh, anchors, weights...).

    Returns
    -------
    Refined
        The best fit, the rounds used, the unrefined fit and the best fit's peaks.
    """
    mode = "drop" if fix_border else "pull"
    cp = None if control_points is None else np.asarray(control_points, dtype=np.float64)
    fixed = None if cp is None or not fix_border else border_mask(cp.shape[:2])
    fit = fit_surface(points, normals, u, v, knots_u=knots_u, knots_v=knots_v, control_points=cp, fixed=fixed,
                      tolerance_mm=tolerance_mm, clamped_samples=mode, warm=False, check_cancel=check_cancel,
                      progress=_round_progress(progress, 0, max_refinements), **options)
    first, rounds, weak = fit, 0, 0
    # The peaks between the lattice's points count for the final surfaces only (inside fixed borders):
    # a free fit places its borders, which its lattice measures, and searching its inside too
    # changed its refinement and the curves fitted to its borders (Block's 5 and 6: 0.038 -> 0.074 mm).
    mesh = options.get("mesh") if fix_border else None
    peaks = _peaks(mesh, fit)
    # `best` is what is returned; `fit` what the next round refines (after a weak round, its refit).
    best, best_peaks = fit, peaks
    judged = (lambda f: f) if judge_band is None else (lambda f: _near_sides(f, judge_band))
    seen = judged(fit)  # what is judged and refined of `fit`
    limit = max_refinements
    # A held border farther from the mesh than the tolerance keeps the surface beyond it whatever the
    # rounds do (`border_distance`): they would only cost time, four times the control points each
    # (on a 50k-point Fandisk cloud, 18 of its fit's 76 s, for patches over tolerance either way).
    # (1e-9 mm: knot insertion moves the border by rounding only.)
    if mesh is not None and border_distance(mesh, fit.knots_u, fit.knots_v, fit.control_points) > tolerance_mm + 1e-9:
        limit = 0
    while rounds < limit and _largest(seen, peaks) > tolerance_mm:
        if check_cancel is not None:
            check_cancel()
        tu, tv = _split_targets(seen, peaks, tolerance_mm=tolerance_mm, fix_border=fix_border,
                                border_band=border_band, min_span=min_span)
        if tu.size == fit.knots_u.size and tv.size == fit.knots_v.size:
            break
        rounds += 1
        refit = _refit_round(points, normals, fit, peaks, tu, tv, tolerance_mm=tolerance_mm, fix_border=fix_border,
                             check_cancel=check_cancel, progress=_round_progress(progress, rounds, max_refinements),
                             **options)
        refit_peaks = _peaks(mesh, refit)
        seen_refit = judged(refit)
        improved, enough = _judge_round(seen_refit, refit_peaks, judged(best), best_peaks,
                                        tolerance_mm=tolerance_mm, min_gain=min_gain)
        if improved:
            best, best_peaks = refit, refit_peaks
        weak = 0 if enough else weak + 1
        # A round that took under `min_drop` off the largest distance: see the docstring.
        if weak >= 2 or _largest(seen_refit, refit_peaks) > _largest(seen, peaks) * (1.0 - min_drop):
            break
        fit, peaks, seen = refit, refit_peaks, seen_refit
    return Refined(best, rounds, first, best_peaks)


def _round_progress(progress: Progress | None, round_: int, rounds: int) -> Progress | None:
    """`progress` for the fit of round `round_` (0: the first fit) of `rounds` at most: its share of them,
    its message saying which."""
    if progress is None:
        return None
    name = "fit" if rounds == 0 else "first fit" if round_ == 0 else f"refinement round {round_} of {rounds} at most"

    def report(fraction: float, message: str | None = None) -> None:
        share = (round_ + min(max(float(fraction), 0.0), 1.0)) / (rounds + 1)
        progress(share, f"{name}, {message}" if message else name)

    return report


def _split_targets(fit: SurfaceFit, peaks, *, tolerance_mm: float, fix_border: bool, border_band: float,
                   min_span: float) -> tuple[np.ndarray, np.ndarray]:
    """The fit's knot vectors with the spans halved where samples, or the surface, are beyond the tolerance."""
    bad = (fit.distance > tolerance_mm) & ~fit.clamped  # spans with data inside, not border reach
    # Spans where the surface leaves the mesh: on the fit's lattice, and where the search between
    # its points finds it (a fit within tolerance on the lattice can still be beyond it there).
    su, sv = np.concatenate([fit.surface_u, peaks[0]]), np.concatenate([fit.surface_v, peaks[1]])
    d = np.concatenate([fit.surface_distance, peaks[2]])
    off = d > tolerance_mm
    if fix_border:
        # Along a fixed border the surface leaves the mesh as far as its boundary curve does,
        # whatever the knots inside: halving those spans (whole knot lines, across the patch)
        # would only narrow the band, round after round, at the cost of every row and column.
        # Farther than the border itself is anywhere, though, the error is the surface's own
        # (a ripple beside a flat border, left by the spans split for a bump inside).
        off &= _inside(fit, su, sv, border_band) | (d > _border_distance(fit))
    return refine_targets(fit.knots_u, fit.knots_v, np.concatenate([fit.u, su]), np.concatenate([fit.v, sv]),
                          np.concatenate([bad, off]), min_span=min_span)


def _refit_round(points, normals, fit: SurfaceFit, peaks, target_u, target_v, *, tolerance_mm: float,
                 fix_border: bool, check_cancel: CheckCancel | None, progress: Progress | None,
                 **options) -> SurfaceFit:
    """`fit_surface` again from the fit refined into the target knots by exact knot insertion."""
    ku, kv, cp = refine_surface(fit.knots_u, fit.knots_v, fit.control_points, target_u=target_u, target_v=target_v)
    # A free refit starts warm (at the smoothing floor). A refit inside fixed borders takes the
    # smoothing schedule from the top: warm, its new spans stalled a few hundredths of a mm
    # over the tolerance round after round (a bump 0.9 mm wide: 0.085, 0.079, 0.074 mm), where
    # one cold round brings it within.
    # The peaks that asked for the new knots are measured and drawn onto the mesh in the refit too:
    # judged on the lattice alone, a refit within tolerance there kept its start, the same surface
    # to the last bit (Block's patch 5: 0.0341 mm at a peak beside a crease, round after round).
    return fit_surface(points, normals, fit.u, fit.v, knots_u=ku, knots_v=kv, control_points=cp,
                       fixed=border_mask(cp.shape[:2]) if fix_border else None, tolerance_mm=tolerance_mm,
                       clamped_samples="drop" if fix_border else "pull", warm=not fix_border,
                       mesh_points=(peaks[0], peaks[1]) if peaks[0].size else None,
                       check_cancel=check_cancel, progress=progress, **options)


def _judge_round(refit: SurfaceFit, refit_peaks, best: SurfaceFit, best_peaks, *, tolerance_mm: float,
                 min_gain: float) -> tuple[bool, bool]:
    """Whether a round's refit improves on the best fit at all, and by enough to go on."""
    improved = refit.folded <= best.folded and _improves(refit, refit_peaks, best, best_peaks, tolerance_mm)
    # Each round can multiply the control points by four; two rounds in a row that gain little
    # mean the remaining error is not a lack of freedom (a border held by its curve, noise). One
    # such round is not enough to tell: spans still wider than a feature gain little from the
    # first split (a bump a tenth of its patch wide: 2 %, then within tolerance two rounds on).
    enough = improved and _improves(refit, refit_peaks, best, best_peaks, tolerance_mm, by=min_gain)
    return improved, enough


def _near_sides(fit: SurfaceFit, band: float) -> SurfaceFit:
    """The fit with the distances of its samples and surface points farther than `band` from every side set
    to zero, so that what is judged and refined is along its sides alone."""
    near = ~_inside(fit, fit.u, fit.v, band)
    near_surface = ~_inside(fit, fit.surface_u, fit.surface_v, band)
    return replace(fit, distance=np.where(near, fit.distance, 0.0),
                   surface_distance=np.where(near_surface, fit.surface_distance, 0.0))


def _largest(fit: SurfaceFit, peaks) -> float:
    """The fit's largest distance (mm) with the peaks found between its lattice's points counted."""
    return max(fit.max_error, float(peaks[2].max(initial=0.0)))


def _peaks(mesh, fit: SurfaceFit) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`surface_peaks` of the fit (u, v, distance), or three empty arrays without a mesh."""
    if mesh is None:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    return surface_peaks(mesh, fit.knots_u, fit.knots_v, fit.control_points)


def _improves(a: SurfaceFit, peaks_a, b: SurfaceFit, peaks_b, tolerance_mm: float, by: float = 1e-9) -> bool:
    """`SurfaceFit.improves_on` with the peaks found between the lattice's points counted too: their
    mean squared distance beyond the tolerance adds to the excess, their largest to the largest."""
    def score(fit, peaks):
        d = peaks[2]
        extra = float(np.mean(np.maximum(d - tolerance_mm, 0.0) ** 2)) if d.size else 0.0
        return fit.excess(tolerance_mm) + extra, _largest(fit, peaks)

    (ea, ma), (eb, mb) = score(a, peaks_a), score(b, peaks_b)
    if ea > 0.0 or eb > 0.0:
        return ea < eb * (1.0 - by)
    return ma < mb * (1.0 - by)


def _border_distance(fit: SurfaceFit) -> float:
    """Largest distance (mm) from the mesh of the fit's lattice points on the sides of its domain."""
    (u0, u1), (v0, v1) = (fit.knots_u[0], fit.knots_u[-1]), (fit.knots_v[0], fit.knots_v[-1])
    u, v = fit.surface_u, fit.surface_v
    side = (u == u0) | (u == u1) | (v == v0) | (v == v1)
    return float(fit.surface_distance[side].max(initial=0.0))


def _inside(fit: SurfaceFit, u: np.ndarray, v: np.ndarray, band: float) -> np.ndarray:
    """bool (m,): which of the points (u, v) of the fit lie farther than the band from every side of its domain.

    The band is `band` parameter units, or a quarter of the domain's narrower side where that is less:
    half a unit from both sides covers a patch one quad wide entirely, and its middle never refined.
    """
    (u0, u1), (v0, v1) = (fit.knots_u[0], fit.knots_u[-1]), (fit.knots_v[0], fit.knots_v[-1])
    band = min(band, 0.25 * min(u1 - u0, v1 - v0))
    return (u - u0 > band) & (u1 - u > band) & (v - v0 > band) & (v1 - v > band)
