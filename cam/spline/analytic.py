"""Analytic test parts as bicubic B-splines (machine frame, mm): known geometry for tests and benchmarks.

Polynomial shapes (plane, saddle, paraboloid) are reproduced exactly by the cubic splines; circular
sections are least-squares fits to the arc, parameterised by angle, within about 1e-7 mm for the sizes
used here. Every surface is oriented so that S_u × S_v points up (out of the material).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import make_lsq_spline

from cam.spline.surface import (
    BSplineSurface,
    clamped_uniform_knots,
    make_bspline_surface,
)

__all__ = ["cylinder", "fit_grid", "paraboloid", "plane", "saddle", "v_groove"]


def fit_grid(fn, *, n: tuple[int, int] = (8, 8), samples: int = 80) -> BSplineSurface:
    """Least-squares bicubic fit of fn(u, v) on [0, 1]² with n control points per direction.

    Parameters
    ----------
    fn : callable
        ``fn(u, v) -> (..., 3)``: u, v float64 (samples, samples) parameter grids (index [i, j] along u
        then v); returns the points in mm.
    n : tuple of (int, int), optional
        Control points along u and v, each at least 4 (default (8, 8)); knots are clamped uniform.
    samples : int, optional
        Samples per direction, ends included (default 80).

    Returns
    -------
    surface : BSplineSurface
        Degree (3, 3) on [0, 1]².

    Raises
    ------
    ValueError
        When a count in `n` is below 4.
    """
    ku, kv = clamped_uniform_knots(n[0]), clamped_uniform_knots(n[1])
    t = np.linspace(0, 1, samples)
    uu, vv = np.meshgrid(t, t, indexing="ij")
    pts = fn(uu, vv)
    # Separable fit: along u for every sample row in v, then along v.
    cu = np.stack([make_lsq_spline(t, pts[:, j], ku, 3).c for j in range(samples)], axis=1)  # (n0, samples, 3)
    cp = np.stack([make_lsq_spline(t, cu[i], kv, 3).c for i in range(n[0])], axis=0)
    return make_bspline_surface(cp, ku, kv)


def plane(width: float = 20.0, height: float = 16.0, *, z: float = 0.0) -> BSplineSurface:
    """The plane z = const over [0, width] × [0, height].

    Parameters
    ----------
    width, height : float, optional
        Extent in x and y, mm (default 20 and 16).
    z : float, optional
        Height in mm (default 0).

    Returns
    -------
    surface : BSplineSurface
        4 x 4 control points; u runs along x, v along y.
    """
    return fit_grid(lambda u, v: np.stack([width * u, height * v, np.full_like(u, z)], -1), n=(4, 4))


def cylinder(radius: float = 20.0, length: float = 20.0, angle_deg: float = 80.0, *, concave: bool = False) -> BSplineSurface:
    """A cylinder section with its axis along y: convex (a hill, z = √(R² − x²) − R) or concave (a trough).

    u runs around the axis (angle linear in u), v along it.

    Parameters
    ----------
    radius : float, optional
        R in mm (default 20).
    length : float, optional
        Length along y in mm, from y = 0 (default 20).
    angle_deg : float, optional
        Angle the section spans in degrees, centred on x = 0 (default 80).
    concave : bool, optional
        True for the trough z = R − √(R² − x²) (default False).

    Returns
    -------
    surface : BSplineSurface
        24 x 4 control points.
    """
    half = np.radians(angle_deg) / 2

    def fn(u, v):
        th = -half + 2 * half * u
        z = radius * np.cos(th) - radius
        return np.stack([radius * np.sin(th), length * v, -z if concave else z], -1)

    return fit_grid(fn, n=(24, 4))


def saddle(radius: float = 40.0, size: float = 20.0) -> BSplineSurface:
    """The saddle z = (x² − y²) / (2R) over [−size/2, size/2]²: convex across y, hollow across x.

    Parameters
    ----------
    radius : float, optional
        R in mm (default 40).
    size : float, optional
        Side of the square in mm (default 20).

    Returns
    -------
    surface : BSplineSurface
        6 x 6 control points; u runs along x, v along y.
    """
    return fit_grid(lambda u, v: np.stack([size * (u - 0.5), size * (v - 0.5),
                                           ((size * (u - 0.5)) ** 2 - (size * (v - 0.5)) ** 2) / (2 * radius)], -1),
                    n=(6, 6))


def paraboloid(radius: float = 30.0, size: float = 20.0, *, concave: bool = False) -> BSplineSurface:
    """A dome z = −(x² + y²)/(2R) (or a bowl with concave=True) over [−size/2, size/2]².

    Parameters
    ----------
    radius : float, optional
        R in mm (default 30).
    size : float, optional
        Side of the square in mm (default 20).
    concave : bool, optional
        True for the bowl z = (x² + y²)/(2R) (default False).

    Returns
    -------
    surface : BSplineSurface
        6 x 6 control points; u runs along x, v along y.
    """
    s = 1.0 if concave else -1.0
    return fit_grid(lambda u, v: np.stack([size * (u - 0.5), size * (v - 0.5),
                                           s * ((size * (u - 0.5)) ** 2 + (size * (v - 0.5)) ** 2) / (2 * radius)], -1),
                    n=(6, 6))


def v_groove(width: float = 12.0, length: float = 16.0, slope_deg: float = 25.0) -> list[BSplineSurface]:
    """Two planes meeting in a hollow sharp edge along y at x = 0 (a two-patch part).

    Parameters
    ----------
    width : float, optional
        Width of each plane in x, mm (default 12).
    length : float, optional
        Length along y in mm, from y = 0 (default 16).
    slope_deg : float, optional
        Slope of each plane in degrees: z = tan(slope) · |x| (default 25).

    Returns
    -------
    surfaces : list of BSplineSurface
        The plane over x in [−width, 0], then the one over [0, width]; 4 x 4 control points each.
    """
    k = np.tan(np.radians(slope_deg))
    left = fit_grid(lambda u, v: np.stack([-width * (1 - u), length * v, k * width * (1 - u)], -1), n=(4, 4))
    right = fit_grid(lambda u, v: np.stack([width * u, length * v, k * width * u], -1), n=(4, 4))
    return [left, right]
