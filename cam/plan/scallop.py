"""Exact scallop relations of a ball-end mill, in the normal section across two neighbouring passes.

Two passes leave balls of radius r whose centres lie on the offset of the surface. In the
normal section across the passes the surface is a circle of signed curvature κ (positive
where the surface bulges towards the tool, negative where it is hollow, zero on a plane),
the centres lie on a concentric circle of curvature κ_c = κ / (1 + rκ), and the scallop is
the height of the cusp where the two ball circles cross, measured along the surface normal.
With `a` half the distance between the two ball centres this is exactly

    h(a) = a² / (r + √(r² − a²))  −  a²·κ_c / (1 + √(1 − a²κ_c²))

(the first term is the flat scallop, the second the bending of the centre circle), and its
inverse, from the triangle (curvature centre, ball centre, cusp) by Heron's formula, is

    a(h) = √(h (2r − h) (2 + hκ) (2 + 2rκ + hκ)) / (2 (1 + hκ)).

Both forms stay accurate as κ → 0 (no R − R cancellation), reduce to the flat relation
l = 2a = 2√(2rh − h²) there, and hold for convex and concave sections alike. A concave
radius not larger than r (κ ≤ −1/r) cannot be finished by this tool: the ball does not fit.
The paper's approximation l ≈ √(8rh / (1 + rκ)) is kept for comparison only: it overshoots.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "approximate_spacing",
    "arc_gap",
    "fits_concave",
    "flat_spacing",
    "half_chord",
    "scallop_from_arc_gap",
    "scallop_from_half_chord",
]


def _check(r: float, h: np.ndarray | None = None) -> None:
    if not np.isfinite(r) or r <= 0:
        raise ValueError(f"tool radius must be a positive number of mm, got {r}")
    if h is not None and (np.any(~np.isfinite(h)) or np.any(h <= 0) or np.any(h >= r)):
        raise ValueError(f"scallop heights must lie in (0, r = {r}) mm, got {np.min(h)}..{np.max(h)}")


def fits_concave(kappa: np.ndarray, r: float) -> np.ndarray:
    """True where a ball of radius r fits the section: κ > −1/r. kappa: float (...) 1/mm → bool (...).

    Parameters
    ----------
    kappa : (...) float
        Signed normal curvature, 1/mm (convex > 0).
    r : float
        Ball radius, mm.

    Returns
    -------
    (...) bool
        1 + rκ > 0; False where κ is NaN.
    """
    return 1.0 + r * np.asarray(kappa, dtype=np.float64) > 0


def flat_spacing(h: float | np.ndarray, r: float) -> np.ndarray:
    """Pass interval on a plane for scallop h: l = 2·√(2rh − h²), mm (shape of h).

    Parameters
    ----------
    h : float or (...) float
        Scallop height, mm, in (0, r).
    r : float
        Ball radius, mm (> 0).

    Returns
    -------
    (...) float64
        The pass interval l, mm, shaped like h.

    Raises
    ------
    ValueError
        When r is not a positive number or some h is not in (0, r).
    """
    h = np.asarray(h, dtype=np.float64)
    _check(r, h)
    return 2.0 * np.sqrt(h * (2.0 * r - h))


def half_chord(h: float | np.ndarray, r: float, kappa: float | np.ndarray) -> np.ndarray:
    """Half the distance between neighbouring ball centres that leaves exactly scallop h.

    h: mm, kappa: signed normal curvature across the passes (1/mm, convex > 0), broadcast
    together; returns float64 mm. NaN where the ball does not fit (κ ≤ −1/r).

    In a hollow the centres lie on a circle of radius R − r: the half chord is at most 1/|κ_c|, and
    where the hollow leaves less than h at any spacing (no chord leaves exactly h) it is that largest one.

    Parameters
    ----------
    h : float or (...) float
        Scallop height, mm, in (0, r).
    r : float
        Ball radius, mm (> 0).
    kappa : float or (...) float
        Signed normal curvature across the passes, 1/mm (convex > 0), broadcast with the first argument.

    Returns
    -------
    a : (...) float64
        Half the ball-centre distance, mm; NaN where the ball does not fit.

    Raises
    ------
    ValueError
        When r is not a positive number or some h is not in (0, r).
    """
    h = np.asarray(h, dtype=np.float64)
    k = np.asarray(kappa, dtype=np.float64)
    _check(r, h)
    with np.errstate(invalid="ignore", over="ignore"):  # 1/|κ_c| of a hollow flat to round-off is inf
        q = h * (2 * r - h) * (2 + h * k) * (2 + 2 * r * k + h * k)
        a = np.sqrt(q) / (2 * (1 + h * k))
        # In a hollow the centres lie on a circle of radius (R − r); no wider chord exists, and a target the
        # hollow cannot even reach is met by any spacing up to it.
        # (q < 0 happens only there: a hollow so close to the ball that no spacing leaves h.)
        kc = k / (1 + r * k)
        hollow = kc < 0
        a = np.where(hollow, np.minimum(np.where(q >= 0, a, np.inf), 1 / np.abs(np.where(hollow, kc, -1.0))), a)
    return np.where(fits_concave(k, r) & ((q >= 0) | hollow), a, np.nan)


def scallop_from_half_chord(a: float | np.ndarray, r: float, kappa: float | np.ndarray) -> np.ndarray:
    """Scallop height (mm) left by two balls whose centres are 2a apart; inverse of `half_chord`.

    NaN where the ball does not fit (κ ≤ −1/r) and +inf where the balls do not meet (a ≥ r).

    Parameters
    ----------
    a : float or (...) float
        Half the distance between the ball centres, mm (its absolute value is used).
    r : float
        Ball radius, mm (> 0).
    kappa : float or (...) float
        Signed normal curvature across the passes, 1/mm (convex > 0), broadcast with a.

    Returns
    -------
    h : (...) float64
        Scallop height, mm; NaN also where 2a (< 2r) is wider than the diameter of a hollow's centre
        circle.

    Raises
    ------
    ValueError
        When r is not a positive number.
    """
    a = np.abs(np.asarray(a, dtype=np.float64))
    k = np.asarray(kappa, dtype=np.float64)
    _check(r)
    fits = fits_concave(k, r)
    with np.errstate(invalid="ignore", divide="ignore"):
        kc = np.where(fits, k / (1 + r * k), 0.0)
        a2 = a * a
        flat = a2 / (r + np.sqrt(r * r - a2))
        # Round-off at the centre circle's diameter (a = 1 / |κ_c|) counts as on it; past it stays NaN.
        inside = 1 - a2 * kc * kc
        bend = a2 * kc / (1 + np.sqrt(np.where(inside > -1e-9, np.maximum(inside, 0.0), inside)))
        h = flat - bend
    h = np.where(a >= r, np.inf, h)
    return np.where(fits, h, np.nan)


def _sinc(x: np.ndarray) -> np.ndarray:
    return np.sinc(x / np.pi)  # numpy's sinc is sin(πx)/(πx)


def _asinc(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, -1.0, 1.0)
    small = np.abs(x) < 1e-4
    safe = np.where(small, 0.5, x)
    return np.where(small, 1 + x * x / 6, np.arcsin(safe) / safe)


def arc_gap(h: float | np.ndarray, r: float, kappa: float | np.ndarray) -> np.ndarray:
    """Admissible distance between neighbouring contact points along the surface (arc length, mm).

    The contact points sit on the surface circle at the same angle as the ball centres on
    theirs, so w = 2·asin(a κ_c)/κ, written through asin(x)/x to stay exact near κ = 0.

    Parameters
    ----------
    h : float or (...) float
        Scallop height, mm, in (0, r).
    r : float
        Ball radius, mm (> 0).
    kappa : float or (...) float
        Signed normal curvature across the passes, 1/mm (convex > 0), broadcast with the first argument.

    Returns
    -------
    w : (...) float64
        Arc length between the contact points, mm; NaN where the ball does not fit (κ ≤ −1/r).

    Raises
    ------
    ValueError
        When r is not a positive number or some h is not in (0, r).
    """
    k = np.asarray(kappa, dtype=np.float64)
    a = half_chord(h, r, k)
    with np.errstate(invalid="ignore"):
        kc = k / (1 + r * k)
        return 2 * a / (1 + r * k) * _asinc(a * kc)


def scallop_from_arc_gap(w: float | np.ndarray, r: float, kappa: float | np.ndarray) -> np.ndarray:
    """Scallop height (mm) for contact points w apart along the surface; inverse of `arc_gap`.

    Parameters
    ----------
    w : float or (...) float
        Arc length between the contact points, mm.
    r : float
        Ball radius, mm (> 0).
    kappa : float or (...) float
        Signed normal curvature across the passes, 1/mm (convex > 0), broadcast with w.

    Returns
    -------
    h : (...) float64
        Scallop height, mm (`scallop_from_half_chord`): NaN where the ball does not fit, +inf where
        the balls do not meet.

    Raises
    ------
    ValueError
        When r is not a positive number.
    """
    w = np.asarray(w, dtype=np.float64)
    k = np.asarray(kappa, dtype=np.float64)
    _check(r)
    with np.errstate(invalid="ignore"):
        a = 0.5 * w * (1 + r * k) * _sinc(0.5 * w * k)
    return scallop_from_half_chord(a, r, k)


def approximate_spacing(h: float | np.ndarray, r: float, kappa: float | np.ndarray = 0.0) -> np.ndarray:
    """The usual approximation l ≈ √(8rh / (1 + rκ)) (mm): kept to measure how far it overshoots.

    Parameters
    ----------
    h : float or (...) float
        Scallop height, mm, in (0, r).
    r : float
        Ball radius, mm (> 0).
    kappa : float or (...) float
        Signed normal curvature across the passes, 1/mm (convex > 0), broadcast with the first argument.
        Default 0 (a plane).

    Returns
    -------
    l : (...) float64
        Approximate pass interval, mm; NaN where the ball does not fit (κ ≤ −1/r).

    Raises
    ------
    ValueError
        When r is not a positive number or some h is not in (0, r).
    """
    h = np.asarray(h, dtype=np.float64)
    k = np.asarray(kappa, dtype=np.float64)
    _check(r, h)
    with np.errstate(invalid="ignore"):
        return np.where(fits_concave(k, r), np.sqrt(8 * r * h / (1 + r * k)), np.nan)
