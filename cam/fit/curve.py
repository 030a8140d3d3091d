"""Boundary curves: one cubic B-spline per shared boundary, fitted once, interpolating its junctions.

A boundary curve is fitted to where the neighbouring patches' own fits put their
borders (sampled at matching parameters), by linear least squares with a small
bending term; the points where patches meet (curve ends and T-junctions inside a
curve) are interpolated exactly, through a KKT system, so every curve that
passes through a junction agrees on it to round-off. A curve that misses the mesh
is refined and held on it (its squared distance to the mesh, linearised at its
closest points, joins the least squares); along a crease it must follow the
crease data too, not just stay on the mesh.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from cam.fit.refine import split_spans
from cam.spline.basis import curve_matrix, evaluate_curve, gram_matrix, span_params

__all__ = ["CurveFit", "fit_curve", "turns_back"]


@dataclass(frozen=True, eq=False)
class CurveFit:
    """A fitted boundary curve.

    Attributes
    ----------
    knots : ndarray, shape (n + 4,), float64
        Clamped cubic knots, in the curve's own parameter.
    control_points : ndarray, shape (n, 3), float64
        The control polygon, mm.
    max_error : float
        Largest deviation found (from the mesh, or from the data), mm.
    """

    knots: np.ndarray
    control_points: np.ndarray
    max_error: float


def fit_curve(points: np.ndarray, t: np.ndarray, *, knots: np.ndarray, constraints: list[tuple[float, np.ndarray]],
              length_mm: float, tolerance_mm: float,
              closest: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
              project: Callable[[np.ndarray], np.ndarray] | None = None, smoothing_mm2: float = 1e-8,
              surface_weight: float = 100.0, slide: list[tuple[float, float]] | None = None,
              exact: np.ndarray | None = None, max_refinements: int = 3, min_span: float = 0.125,
              degree: int = 3) -> CurveFit:
    """Least-squares cubic through data points at given parameters, exact at `constraints`.

    Each refinement round, data points farther than `tolerance_mm` from what the curve must stay on
    are replaced by `project`, spans that stay farther are halved (knot insertion, down to
    `min_span`), and the curve is refitted with the squared distance to the surface added (its
    tangent-plane approximation, `surface_weight` times the data term, feet found again three
    times): data that agree with each other place the curve, data that disagree (two patches'
    borders, each on the mesh, apart across it) are averaged along the surface, not through the air.

    Parameters
    ----------
    points : ndarray, shape (n, 3), float64
        The data, mm.
    t : ndarray, shape (n,), float64
        Their curve parameters.
    knots : ndarray, shape (m + degree + 1,), float64
        The knots to start with, in the curve's parameter.
    constraints : list of (float, ndarray of shape (3,))
        (parameter, point in mm) pairs the curve must pass through (its two ends at least).
    length_mm : float
        The curve's length, mm (scales the bending term to the part).
    tolerance_mm : float
        The distance the curve aims to stay within, mm.
    closest : callable or None
        Maps curve points (k, 3) mm to their closest points (k, 3) mm on what the curve must stay
        on (the mesh) and the unit normals (k, 3) there; None: the distance to the data at their
        parameters is the error.
    project : callable or None
        Maps parameters (k,) to points (k, 3) mm where the curve should pass at them (replacing
        data off the mesh).
    smoothing_mm2 : float
        Weight of the bending term, mm².
    surface_weight : float
        Weight of the distance to the surface against the data term.
    slide : list of (float, float) or None
        The parameter ranges (lo, hi) where the surface term applies (None: everywhere); elsewhere
        the data alone place the curve (a crease: on the mesh is not enough there, the curve must
        follow it).
    exact : ndarray, shape (n,), bool, or None
        The data the curve must pass through (a crease), so its distance from them counts in its
        error as well.
    max_refinements : int
        Rounds at most.
    min_span : float
        Spans are never halved below this, parameter units.
    degree : int
        The curve's degree.

    Returns
    -------
    CurveFit
        The knots, control points and largest deviation found.

    Raises
    ------
    ValueError
        Where points is not (n, 3) or t not (n,).
    """
    P = np.asarray(points, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    k = np.asarray(knots, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or t.shape != (len(P),):
        raise ValueError(f"need points (n, 3) and t (n,), got {P.shape} and {t.shape}")
    rounds = 0
    previous = None
    while True:
        cp = _solve_round(P, t, k, constraints, length_mm=length_mm, smoothing_mm2=smoothing_mm2,
                          stiffen=previous is None, hold=bool(rounds) and closest is not None and surface_weight > 0,
                          closest=closest, surface_weight=surface_weight, slide=slide, degree=degree)
        if previous is not None and turns_back(k, cp, degree=degree) and not turns_back(*previous[:2], degree=degree):
            # Finer spans let the curve loop between its data: a border that turns back folds
            # both patches on it. Keep the last curve that ran one way.
            k, cp, worst = previous
            break
        where, err = _curve_errors(P, t, k, cp, closest=closest, exact=exact, degree=degree)
        worst = float(err.max(initial=0.0))
        if worst <= tolerance_mm or rounds >= max_refinements:
            break
        P, moved = _replace_off_mesh(P, t, closest=closest, project=project, tolerance_mm=tolerance_mm)
        new = _split_missed(P, t, k, cp, where[err > tolerance_mm], tolerance_mm=tolerance_mm, min_span=min_span,
                            degree=degree)
        if new.size == k.size and not moved:
            break
        previous = (k, cp, worst)
        k, rounds = new, rounds + 1
    return CurveFit(knots=k, control_points=cp, max_error=worst)


def _solve_round(P, t, k, constraints, *, length_mm: float, smoothing_mm2: float, stiffen: bool, hold: bool,
                 closest, surface_weight: float, slide, degree: int) -> np.ndarray:
    """The round's control points (m, 3) mm: the data's least squares, stiffened where it loops (the
    first round only), then, with `hold`, held on the surface (three times, feet found again)."""
    cp = _solve(P, t, k, constraints, length_mm, smoothing_mm2, degree)
    stiffer = smoothing_mm2
    for _ in range(4):  # data that zig-zag (a crease found on both sides) make a loop; bend less
        if not stiffen or not turns_back(k, cp, degree=degree):
            break
        stiffer *= 100.0
        cp = _solve(P, t, k, constraints, length_mm, stiffer, degree)
    if hold:
        near = span_params(k, 8)
        if slide is not None:
            near = near[_within(near, slide)]
        for _ in range(3 if near.size else 0):
            feet, normals = closest(evaluate_curve(k, cp, near, degree=degree)[0])
            cp = _solve(P, t, k, constraints, length_mm, stiffer, degree,
                        surface=(near, feet, normals, surface_weight))
    return cp


def _curve_errors(P, t, k, cp, *, closest, exact, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the curve's error is measured (parameters (e,)) and the error there (e,) mm: from what it
    must stay on, and from the data it must pass through; without `closest`, from all the data."""
    if closest is not None:
        where = span_params(k, 8)
        on = evaluate_curve(k, cp, where, degree=degree)[0]
        err = np.linalg.norm(on - closest(on)[0], axis=1)
        if exact is not None and len(P):
            # On the mesh is not enough where the data are the crease itself: a curve on one face
            # beside it leaves the crease to neither patch.
            mine = np.asarray(exact, dtype=bool)
            where = np.concatenate([where, t[mine]])
            err = np.concatenate([err, np.linalg.norm(evaluate_curve(k, cp, t[mine], degree=degree)[0] - P[mine],
                                                      axis=1)])
    else:
        where = t
        err = np.linalg.norm(evaluate_curve(k, cp, t, degree=degree)[0] - P, axis=1) if len(P) else np.zeros(0)
    return where, err


def _replace_off_mesh(P, t, *, closest, project, tolerance_mm: float) -> tuple[np.ndarray, bool]:
    """The data (n, 3) with the points off the mesh replaced by `project`'s, and whether any was."""
    if closest is None or project is None or not len(P):
        return P, False
    # Data off the mesh (a patch fit's border past where it had samples) is no data for the
    # curve. Its replacement keeps the parameter: the closest point on the mesh instead
    # would shift it along the curve, and data out of order make the curve zig-zag.
    off = np.linalg.norm(P - closest(P)[0], axis=1) > tolerance_mm
    if not off.any():
        return P, False
    P = P.copy()
    P[off] = project(t[off])
    return P, True


def _split_missed(P, t, k, cp, far: np.ndarray, *, tolerance_mm: float, min_span: float, degree: int) -> np.ndarray:
    """Knots with the spans halved that hold a parameter of `far` (the error's) or of data the curve misses."""
    # Spans that miss their own data need knots too: a stiff span that slides along the mesh
    # (no deviation there) bends its neighbours off it through the curve's continuity.
    missed = t[np.linalg.norm(evaluate_curve(k, cp, t, degree=degree)[0] - P, axis=1) > tolerance_mm] \
        if len(P) else np.zeros(0)
    return split_spans(k, np.concatenate([far, missed]), degree=degree, min_span=min_span)


def _within(t: np.ndarray, ranges: list[tuple[float, float]]) -> np.ndarray:
    """bool (n,): which parameters t (n,) lie in one of the closed ranges (lo, hi)."""
    out = np.zeros(t.shape, dtype=bool)
    for lo, hi in ranges:
        out |= (t >= lo) & (t <= hi)
    return out


def turns_back(knots: np.ndarray, control_points: np.ndarray, *, degree: int = 3, per_span: int = 16) -> bool:
    """Whether the curve's direction reverses anywhere (C'(t) against C'(t + dt), sampled per span).

    Parameters
    ----------
    knots : ndarray, shape (n + degree + 1,), float64
        The curve's clamped knots.
    control_points : ndarray, shape (n, 3), float64
        Its control polygon, mm.
    degree : int
        Its degree.
    per_span : int
        Samples per knot span.

    Returns
    -------
    bool
        True where two consecutive samples' derivatives point more than 90 degrees apart.
    """
    d = evaluate_curve(knots, control_points, span_params(knots, per_span), degree=degree, derivatives=1)[1]
    return bool(np.any(np.einsum("ij,ij->i", d[1:], d[:-1]) < 0))


def _solve(P, t, knots, constraints, length_mm, smoothing_mm2, degree, surface=None) -> np.ndarray:
    """Control points (n, 3): least squares to the data with bending, exact at the constraints (KKT).

    surface: (params (m,), feet (m, 3), normals (m, 3), weight) adds weight times the mean squared
    distance of C(params) from the planes through the feet; the planes couple the coordinates.
    """
    n = knots.size - degree - 1
    span = knots[-1] - knots[0]
    # Bending ∫|C''|² ds in mm: the parameter runs over `span` units for `length_mm` mm.
    scale = span / max(length_mm, 1e-6 * span)  # a degenerate (zero-length) curve still solves
    K = gram_matrix(knots, degree, 2) * scale**3
    if len(P):
        B = curve_matrix(knots, degree, t).toarray()
        M = B.T @ B / len(P) + smoothing_mm2 * K
        rhs = B.T @ P / len(P)
    else:
        M = smoothing_mm2 * K + 1e-12 * np.eye(n)
        rhs = np.zeros((n, 3))
    C = curve_matrix(knots, degree, np.array([c[0] for c in constraints], dtype=np.float64)).toarray()
    values = np.array([c[1] for c in constraints], dtype=np.float64).reshape(-1, 3)
    if surface is None:
        return _kkt(M, rhs, C, values, n)
    # One system for the three coordinates (coordinate-major unknowns): a plane's row mixes them.
    near, feet, normals, weight = surface
    S = curve_matrix(knots, degree, near).toarray()
    J = np.concatenate([normals[:, c:c + 1] * S for c in range(3)], axis=1)
    eye = np.eye(3)
    M3 = np.kron(eye, M) + weight / len(near) * J.T @ J
    rhs3 = rhs.T.ravel() + weight / len(near) * J.T @ np.einsum("ij,ij->i", normals, feet)
    sol = _kkt(M3, rhs3[:, None], np.kron(eye, C), values.T.reshape(-1, 1), 3 * n)
    return sol.reshape(3, n).T


def _kkt(M: np.ndarray, rhs: np.ndarray, C: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Minimiser of x'Mx/2 - rhs'x subject to Cx = values: (n, columns of rhs)."""
    m = len(C)
    kkt = np.zeros((n + m, n + m))
    kkt[:n, :n] = M
    kkt[:n, n:] = C.T
    kkt[n:, :n] = C
    sol = np.linalg.lstsq(kkt, np.concatenate([rhs, values]), rcond=None)[0]
    return sol[:n]
