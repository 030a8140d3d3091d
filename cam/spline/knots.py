"""Exact knot manipulation: insertion, refinement to a target vector, splitting, joining, reversing.

Every operation here leaves the curve or surface unchanged as a point set and
parameterisation (up to round-off); C0 across patches rests on that: two patches
that take their boundary rows from one curve by these operations meet exactly.
Control points run along axis 0 (curves: (n, dim); surfaces: refine along u, or
pass the transposed net for v).
"""

from __future__ import annotations

import numpy as np

from cam.spline.surface import BSplineSurface, make_bspline_surface

__all__ = ["lattice_knots", "insert_knot", "refine_knots", "merge_knots", "split_curve", "sub_curve", "join_curves",
           "reverse_curve", "shift_curve", "refine_surface", "sub_surface"]


def lattice_knots(start: float, end: float, spacing: float, *, degree: int = 3) -> np.ndarray:
    """Clamped knots on [start, end] with interior knots at the multiples of `spacing` inside it.

    Parameters
    ----------
    start, end : float
        The parameter span, end > start.
    spacing : float
        Distance between interior knots, > 0 (parameter units).
    degree : int, optional
        Spline degree (default 3).

    Returns
    -------
    knots : (k,) float64
        The start repeated degree + 1 times, the multiples of `spacing` strictly inside (start, end), the
        end repeated degree + 1 times.

    Raises
    ------
    ValueError
        When end <= start.
    """
    if not end > start:
        raise ValueError(f"knot span must be positive, got [{start}, {end}]")
    first = np.floor(start / spacing) + 1
    inner = np.arange(first, np.ceil(end / spacing)) * spacing
    inner = inner[(inner > start) & (inner < end)]
    return np.concatenate([[start] * (degree + 1), inner, [end] * (degree + 1)]).astype(np.float64)


def insert_knot(knots: np.ndarray, control_points: np.ndarray, t: float, *, degree: int = 3
                ) -> tuple[np.ndarray, np.ndarray]:
    """Insert `t` once (Boehm); the curve is unchanged.

    Parameters
    ----------
    knots : (m,) array_like of float
        A clamped knot vector (parameter units).
    control_points : (n, ...) array_like of float
        Control points along axis 0, such as (n, 3) in mm.
    t : float
        The knot, in [knots[degree], knots[-degree - 1]].
    degree : int, optional
        Spline degree (default 3).

    Returns
    -------
    knots : (m + 1,) float64
        The knot vector with `t` added.
    control_points : (n + 1, ...) float64
        The new control points.

    Raises
    ------
    ValueError
        When `t` lies outside the curve's span, or is an interior knot that already has multiplicity
        `degree` (inserting it again would break the curve).
    """
    k = np.asarray(knots, dtype=np.float64)
    P = np.asarray(control_points, dtype=np.float64)
    p = degree
    if not k[p] <= t <= k[-p - 1]:
        raise ValueError(f"knot {t} lies outside the curve's span [{k[p]}, {k[-p - 1]}]")
    n = P.shape[0]
    span = int(np.clip(np.searchsorted(k, t, side="right") - 1, p, n - 1))
    if np.count_nonzero(k == t) >= p and k[0] < t < k[-1]:
        raise ValueError(f"knot {t} already has multiplicity {p}; inserting it again would break the curve")
    Q = np.empty((n + 1,) + P.shape[1:])
    Q[: span - p + 1] = P[: span - p + 1]
    Q[span + 1:] = P[span:]
    for i in range(span - p + 1, span + 1):
        alpha = (t - k[i]) / (k[i + p] - k[i])
        Q[i] = alpha * P[i] + (1.0 - alpha) * P[i - 1]
    return np.insert(k, span + 1, t), Q


def _missing(knots: np.ndarray, target: np.ndarray) -> list[float]:
    """Values of `target` not in `knots`, with multiplicity (a multiset difference)."""
    have = dict(zip(*np.unique(knots, return_counts=True)))
    out: list[float] = []
    for value, count in zip(*np.unique(target, return_counts=True)):
        out.extend([float(value)] * max(0, int(count) - int(have.get(value, 0))))
    return out


def refine_knots(knots: np.ndarray, control_points: np.ndarray, target: np.ndarray, *, degree: int = 3
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Insert every knot of `target` that `knots` lacks; `target` must contain `knots` as a multiset.

    Parameters
    ----------
    knots : (m,) array_like of float
        The curve's clamped knot vector.
    control_points : (n, ...) array_like of float
        Its control points along axis 0.
    target : (k,) array_like of float
        The knot vector wanted.
    degree : int, optional
        Spline degree (default 3).

    Returns
    -------
    knots : (k,) float64
        Equal to `target` as a multiset, sorted.
    control_points : (n + k - m, ...) float64
        The control points of the same curve on it.

    Raises
    ------
    ValueError
        When `target` lacks some knot of `knots`, or a knot cannot be inserted (see `insert_knot`).
    """
    k = np.asarray(knots, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if _missing(target, k):
        raise ValueError(f"target knot vector does not contain the curve's knots {_missing(target, k)}")
    P = np.asarray(control_points, dtype=np.float64)
    for t in _missing(k, target):
        k, P = insert_knot(k, P, t, degree=degree)
    return k, P


def merge_knots(*vectors: np.ndarray) -> np.ndarray:
    """The smallest knot vector containing each of `vectors` (max multiplicity per value), sorted.

    Parameters
    ----------
    *vectors : array_like of float
        Knot vectors.

    Returns
    -------
    knots : (k,) float64
        Each value repeated as often as in the vector that repeats it most.
    """
    counts: dict[float, int] = {}
    for vec in vectors:
        for value, count in zip(*np.unique(np.asarray(vec, dtype=np.float64), return_counts=True)):
            counts[float(value)] = max(counts.get(float(value), 0), int(count))
    return np.array(sorted(v for v, c in counts.items() for _ in range(c)), dtype=np.float64)


def split_curve(knots: np.ndarray, control_points: np.ndarray, t: float, *, degree: int = 3
                ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Two clamped curves, on [start, t] and [t, end], that share the control point C(t).

    Parameters
    ----------
    knots : (m,) array_like of float
        A clamped knot vector (parameter units).
    control_points : (n, ...) array_like of float
        Control points along axis 0.
    t : float
        The split parameter, strictly inside [knots[degree], knots[-degree - 1]].
    degree : int, optional
        Spline degree (default 3).

    Returns
    -------
    left : tuple of (ndarray, ndarray)
        Knots float64 and control points float64 of the piece on [start, t].
    right : tuple of (ndarray, ndarray)
        The same for the piece on [t, end]; its first control point is the left piece's last.

    Raises
    ------
    ValueError
        When `t` does not lie strictly inside the span.
    """
    k = np.asarray(knots, dtype=np.float64)
    P = np.asarray(control_points, dtype=np.float64)
    p = degree
    if not k[p] < t < k[-p - 1]:
        raise ValueError(f"split parameter {t} must lie strictly inside [{k[p]}, {k[-p - 1]}]")
    for _ in range(p - np.count_nonzero(k == t)):
        k, P = insert_knot(k, P, t, degree=p)
    a = int(np.searchsorted(k, t, side="left"))  # first of the p copies of t
    left = (np.concatenate([k[: a + p], [t]]), P[:a].copy())
    right = (np.concatenate([[t], k[a:]]), P[a - 1:].copy())
    return left, right


def sub_curve(knots: np.ndarray, control_points: np.ndarray, t0: float, t1: float, *, degree: int = 3
              ) -> tuple[np.ndarray, np.ndarray]:
    """The piece of a curve on [t0, t1] as a clamped curve with the same parameterisation.

    Parameters
    ----------
    knots : (m,) array_like of float
        A clamped knot vector (parameter units).
    control_points : (n, ...) array_like of float
        Control points along axis 0.
    t0, t1 : float
        The piece, knots[0] <= t0 < t1 <= knots[-1].
    degree : int, optional
        Spline degree (default 3).

    Returns
    -------
    knots : (k,) float64
        Clamped knots on [t0, t1].
    control_points : (k - degree - 1, ...) float64
        Control points of the piece.

    Raises
    ------
    ValueError
        When [t0, t1] is not inside the curve's span.
    """
    k = np.asarray(knots, dtype=np.float64)
    P = np.asarray(control_points, dtype=np.float64)
    if not k[0] <= t0 < t1 <= k[-1]:
        raise ValueError(f"[{t0}, {t1}] is not inside the curve's span [{k[0]}, {k[-1]}]")
    if t0 > k[0]:
        k, P = split_curve(k, P, t0, degree=degree)[1]
    if t1 < k[-1]:
        k, P = split_curve(k, P, t1, degree=degree)[0]
    return k, P


def join_curves(pieces: list[tuple[np.ndarray, np.ndarray]], *, degree: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """One curve from clamped pieces end to end (C0 where they meet: the joint knot gets multiplicity p).

    Each piece must start at the parameter and the control point where the previous one ends; the
    parameter is checked, and the first control point of each later piece is dropped.

    Parameters
    ----------
    pieces : list of tuple of (array_like, array_like)
        (knots, control_points) of each piece, control points along axis 0.
    degree : int, optional
        Spline degree p of every piece (default 3).

    Returns
    -------
    knots : (k,) float64
        The joined knot vector.
    control_points : (n, ...) float64
        The joined control points.

    Raises
    ------
    ValueError
        When a piece does not start at the parameter where the previous one ends.
    """
    p = degree
    knots, P = (np.asarray(a, dtype=np.float64) for a in pieces[0])
    for nk, nP in pieces[1:]:
        nk = np.asarray(nk, dtype=np.float64)
        if nk[0] != knots[-1]:
            raise ValueError(f"piece starts at {nk[0]} but the previous one ends at {knots[-1]}")
        knots = np.concatenate([knots[:-p - 1], [knots[-1]] * p, nk[p + 1:]])
        P = np.concatenate([P, np.asarray(nP, dtype=np.float64)[1:]], axis=0)
    return knots, P


def reverse_curve(knots: np.ndarray, control_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same curve run backwards over the same span [a, b]: C'(t) = C(a + b - t).

    Parameters
    ----------
    knots : (m,) array_like of float
        The knot vector.
    control_points : (n, ...) array_like
        Control points along axis 0.

    Returns
    -------
    knots : (m,) float64
        The mirrored knot vector.
    control_points : (n, ...) ndarray
        The control points in reverse order (a copy, dtype kept).
    """
    k = np.asarray(knots, dtype=np.float64)
    return (k[0] + k[-1]) - k[::-1], np.asarray(control_points)[::-1].copy()


def shift_curve(knots: np.ndarray, control_points: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """The same curve with its parameter moved by `offset` (exact for the small dyadic values used here).

    Parameters
    ----------
    knots : (m,) array_like of float
        The knot vector.
    control_points : (n, ...) array_like
        Control points along axis 0.
    offset : float
        Added to every knot (parameter units).

    Returns
    -------
    knots : (m,) float64
        The shifted knot vector.
    control_points : (n, ...) ndarray
        The control points, unchanged (not copied).
    """
    return np.asarray(knots, dtype=np.float64) + offset, np.asarray(control_points)


def refine_surface(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, *,
                   target_u: np.ndarray | None = None, target_v: np.ndarray | None = None,
                   degree: tuple[int, int] = (3, 3)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Insert knots into a surface without changing it.

    Parameters
    ----------
    knots_u : (nu + p + 1,) array_like of float
        Clamped knot vector in u.
    knots_v : (nv + q + 1,) array_like of float
        Clamped knot vector in v.
    control_points : (nu, nv, 3) array_like of float
        Control net in mm.
    target_u, target_v : array_like of float or None, optional
        Knot vectors wanted in u and v (see `refine_knots`); None (default) leaves that direction as it is.
    degree : tuple of (int, int), optional
        The degrees (p, q) (default (3, 3)).

    Returns
    -------
    knots_u : (nu' + p + 1,) float64
        The refined knot vector in u.
    knots_v : (nv' + q + 1,) float64
        The refined knot vector in v.
    control_points : (nu', nv', 3) float64
        The control net of the same surface, in mm.

    Raises
    ------
    ValueError
        When a target lacks a knot of the surface's vector (see `refine_knots`).
    """
    ku = np.asarray(knots_u, dtype=np.float64)
    kv = np.asarray(knots_v, dtype=np.float64)
    cp = np.asarray(control_points, dtype=np.float64)
    if target_u is not None:
        ku, cp = refine_knots(ku, cp, target_u, degree=degree[0])
    if target_v is not None:
        kv, cpt = refine_knots(kv, np.swapaxes(cp, 0, 1), target_v, degree=degree[1])
        cp = np.swapaxes(cpt, 0, 1).copy()
    return ku, kv, cp


def sub_surface(surface: BSplineSurface, box: tuple[float, float, float, float]) -> BSplineSurface:
    """The same surface on the parameter rectangle `box` as its own B-spline (exact: knot insertion), with
    the same parameters.

    Parameters
    ----------
    surface : BSplineSurface
        The surface (mm).
    box : tuple of float
        (u0, u1, v0, v1) inside the surface's knot span, u0 < u1 and v0 < v1.

    Returns
    -------
    piece : BSplineSurface
        The surface restricted to `box`; its domain is `box`.

    Raises
    ------
    ValueError
        When `box` does not lie inside the knot span.
    """
    u0, u1, v0, v1 = box
    cp = surface.control_points
    nu, nv = cp.shape[:2]
    ku, P = sub_curve(surface.knots_u, cp.reshape(nu, -1), u0, u1, degree=surface.degree[0])
    P = P.reshape(len(P), nv, 3).transpose(1, 0, 2)
    kv, Q = sub_curve(surface.knots_v, P.reshape(nv, -1), v0, v1, degree=surface.degree[1])
    Q = Q.reshape(len(Q), -1, 3).transpose(1, 0, 2)
    return make_bspline_surface(Q, ku, kv, degree=surface.degree)
