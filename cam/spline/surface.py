"""Tensor-product B-spline surfaces: the record every later stage shares, and its evaluation.

`make_bspline_surface` validates once; `BSplineSurface.evaluate` gives points
and partial derivatives (for curvature and normals) through SciPy's `NdBSpline` (compiled: the planner
and verify evaluate surfaces millions of times, mostly a few points at a call). The fit evaluates the
nets it is solving for with its own basis functions (`cam.spline.basis`), those of its design matrices.
Coordinates are millimetres in the part frame; parameters run over the
clamped knot span, normally [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.interpolate import NdBSpline


@dataclass(frozen=True, eq=False)
class BSplineSurface:
    """A non-rational tensor-product B-spline surface.

    Build one with `make_bspline_surface` (which validates it) or `surface_from_json`; evaluation goes
    through SciPy's `NdBSpline`, built once with the record.

    Attributes
    ----------
    degree : tuple of (int, int)
        The degrees (p, q) in u and v.
    knots_u : (nu + p + 1,) float64
        Clamped knot vector in u (parameter units).
    knots_v : (nv + q + 1,) float64
        Clamped knot vector in v (parameter units).
    control_points : (nu, nv, 3) float64
        Control net in mm, index [i, j] along u then v.
    """

    degree: tuple[int, int]
    knots_u: np.ndarray
    knots_v: np.ndarray
    control_points: np.ndarray
    _spline: NdBSpline = field(repr=False, compare=False)

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The parameter rectangle the surface is defined on: the clamped knot span.

        Returns
        -------
        domain : tuple of ((float, float), (float, float))
            ((u0, u1), (v0, v1)) = ((knots_u[p], knots_u[-p - 1]), (knots_v[q], knots_v[-q - 1])), normally
            ((0, 1), (0, 1)).
        """
        p, q = self.degree
        return ((float(self.knots_u[p]), float(self.knots_u[-p - 1])),
                (float(self.knots_v[q]), float(self.knots_v[-q - 1])))

    def derivatives(self, u: np.ndarray, v: np.ndarray, *, order: int = 2) -> dict[tuple[int, int], np.ndarray]:
        """Points and every partial derivative up to total `order` (≤ 2) in one pass.

        Parameters
        ----------
        u, v : (...) float
            Parameters, both of one shape, clipped to `domain`.
        order : int

        Returns
        -------
        dict of (int, int) to (..., 3) float64
            {(du, dv): ∂^(du+dv)S/∂u^du∂v^dv}, the same values `evaluate` gives one at a time.
        """
        uv, shape = self._clipped(u, v)
        p, q = self.degree
        return {(a, b): (np.asarray(self._spline(uv, nu=(a, b)), dtype=np.float64).reshape(shape + (3,))
                         if a <= p and b <= q else np.zeros(shape + (3,)))
                for a in range(order + 1) for b in range(order + 1 - a)}

    def _clipped(self, u, v) -> tuple[np.ndarray, tuple[int, ...]]:
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        if u.shape != v.shape:
            raise ValueError(f"u and v must have one shape, got {u.shape} and {v.shape}")
        (u0, u1), (v0, v1) = self.domain
        # Clip by a hair: round-off just outside the clamped span would extrapolate.
        return np.stack([np.clip(u, u0, u1), np.clip(v, v0, v1)], axis=-1).reshape(-1, 2), u.shape

    def evaluate(self, u: np.ndarray, v: np.ndarray, *, du: int = 0, dv: int = 0) -> np.ndarray:
        """Evaluate points (du = dv = 0) or partial derivatives ∂^(du+dv)S/∂u^du∂v^dv at parameters.

        Parameters
        ----------
        u, v : (...) float
            Parameters, both of one shape. Values outside `domain` are clipped to it: round-off just outside
            the clamped span would otherwise extrapolate.
        du, dv : int, optional
            Orders of differentiation in u and in v (default 0: points).

        Returns
        -------
        values : (..., 3) float64
            Points in mm, or derivatives in mm per parameter unit^(du+dv).

        Raises
        ------
        ValueError
            When u and v differ in shape.
        """
        uv, shape = self._clipped(u, v)
        return np.asarray(self._spline(uv, nu=(du, dv)), dtype=np.float64).reshape(shape + (3,))

    def normals(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit normals S_u × S_v at parameters.

        Parameters
        ----------
        u, v : (...) float
            Parameters, both of one shape (see `evaluate`).

        Returns
        -------
        normals : (..., 3) float64
            Unit vectors along S_u × S_v (not oriented towards the tool); NaN where the surface is
            degenerate (S_u × S_v vanishes).
        """
        n = np.cross(self.evaluate(u, v, du=1), self.evaluate(u, v, dv=1))
        length = np.linalg.norm(n, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(length > 0, n / length, np.nan)

    def to_json(self) -> dict[str, Any]:
        """DESIGN's `surfaces.json` fields for one surface (without `patch` and errors).

        Returns
        -------
        fields : dict
            ``degree`` [p, q], ``knots_u`` and ``knots_v`` lists of float, ``control_points`` nested lists
            (nu, nv, 3) in mm; `surface_from_json` reads it back.
        """
        return {"degree": list(self.degree), "knots_u": self.knots_u.tolist(), "knots_v": self.knots_v.tolist(),
                "control_points": self.control_points.tolist()}


def _check_knots(name: str, knots: np.ndarray, degree: int, count: int) -> None:
    if knots.ndim != 1 or knots.size != count + degree + 1:
        raise ValueError(f"{name} needs {count + degree + 1} values for {count} control points of degree "
                         f"{degree}, got {knots.size}")
    if not np.all(np.isfinite(knots)) or np.any(np.diff(knots) < 0):
        raise ValueError(f"{name} must be finite and non-decreasing")
    if np.any(knots[: degree + 1] != knots[0]) or np.any(knots[-degree - 1:] != knots[-1]):
        raise ValueError(f"{name} must be clamped: its first and last {degree + 1} values repeated")
    if knots[-1] <= knots[0]:
        raise ValueError(f"{name} spans no interval: [{knots[0]}, {knots[-1]}]")
    inner = knots[degree + 1: -degree - 1]
    if inner.size and np.max(np.unique(inner, return_counts=True)[1]) > degree:
        raise ValueError(f"{name} has an interior knot repeated more than {degree} times (a break in the surface)")


def make_bspline_surface(control_points: Any, knots_u: Any, knots_v: Any, *,
                         degree: tuple[int, int] = (3, 3)) -> BSplineSurface:
    """Build a validated surface.

    Parameters
    ----------
    control_points : (nu, nv, 3) array_like of float
        Control net in mm, index [i, j] along u then v; finite.
    knots_u : (nu + p + 1,) array_like of float
        Knot vector in u: finite, non-decreasing, clamped (first and last p + 1 values repeated), spanning
        a positive interval, no interior knot repeated more than p times.
    knots_v : (nv + q + 1,) array_like of float
        Knot vector in v, with the same rules for q.
    degree : tuple of (int, int), optional
        The degrees (p, q), each at least 1 (default (3, 3)).

    Returns
    -------
    surface : BSplineSurface
        The surface, holding the arrays as float64.

    Raises
    ------
    ValueError
        Naming what is wrong: the control net's shape, NaN or Inf in it, a degree below 1, too few
        control points for the degree, or a knot vector of the wrong length, not finite or decreasing,
        not clamped, spanning no interval, or with an interior knot repeated more than the degree (a break
        in the surface).
    """
    cp = np.asarray(control_points, dtype=np.float64)
    if cp.ndim != 3 or cp.shape[2] != 3:
        raise ValueError(f"control_points must have shape (nu, nv, 3), got {cp.shape}")
    if not np.all(np.isfinite(cp)):
        raise ValueError("control_points contain NaN or Inf")
    p, q = (int(d) for d in degree)
    if p < 1 or q < 1:
        raise ValueError(f"degrees must be at least 1, got {degree}")
    if cp.shape[0] <= p or cp.shape[1] <= q:
        raise ValueError(f"degree {degree} needs more than {p} x {q} control points, got {cp.shape[:2]}")
    ku = np.asarray(knots_u, dtype=np.float64)
    kv = np.asarray(knots_v, dtype=np.float64)
    _check_knots("knots_u", ku, p, cp.shape[0])
    _check_knots("knots_v", kv, q, cp.shape[1])
    spline = NdBSpline((ku, kv), cp, (p, q), extrapolate=False)
    return BSplineSurface(degree=(p, q), knots_u=ku, knots_v=kv, control_points=cp, _spline=spline)


def clamped_uniform_knots(count: int, degree: int = 3) -> np.ndarray:
    """Clamped uniform knots on [0, 1] for `count` control points.

    Parameters
    ----------
    count : int
        Number of control points; more than `degree`.
    degree : int, optional
        Spline degree (default 3).

    Returns
    -------
    knots : (count + degree + 1,) float64
        0 and 1 each repeated degree + 1 times, with count - degree - 1 evenly spaced interior knots.

    Raises
    ------
    ValueError
        When `count` <= `degree`.
    """
    if count <= degree:
        raise ValueError(f"{count} control points are too few for degree {degree}")
    inner = np.linspace(0.0, 1.0, count - degree + 1)
    return np.concatenate([np.zeros(degree), inner, np.ones(degree)])


def surface_from_json(data: dict[str, Any]) -> BSplineSurface:
    """Read one entry of `surfaces.json`: the inverse of `BSplineSurface.to_json`.

    Parameters
    ----------
    data : dict
        With ``control_points`` (nu, nv, 3) in mm, ``knots_u``, ``knots_v`` and optionally ``degree``
        (default (3, 3)); other keys are ignored.

    Returns
    -------
    surface : BSplineSurface
        The validated surface.

    Raises
    ------
    KeyError
        When a required field is missing.
    ValueError
        When the fields do not make a valid surface (see `make_bspline_surface`).
    """
    return make_bspline_surface(data["control_points"], data["knots_u"], data["knots_v"],
                                degree=tuple(data.get("degree", (3, 3))))
