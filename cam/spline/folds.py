"""Folds of a fitted B-spline surface: where its normal turns back on itself.

A patch whose boundary curve sits on a crease the mesh rounded can fold over in a thin strip; there
the surface has no outward normal and no scallop bound means anything. The fit reports folds and the
planner leaves them out, both on the grid `FOLD_CHECK_SAMPLES` sets.
"""

from __future__ import annotations

import numpy as np

from cam.spline.surface import BSplineSurface

__all__ = ["FOLD_CHECK_SAMPLES", "find_folds", "flipped_normals", "fold_mask"]


# The grid the planner checks a surface for folds (and hollows) on before it plans it. The fit reports
# folds on the same grid, so that surfaces.json names every fold the planner then leaves out; its own
# iterations compare folds on the default 33 x 33 grid, a quarter of the cost.
FOLD_CHECK_SAMPLES = 65


def fold_mask(surface: BSplineSurface, *, samples: int = 33) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where a surface folds over itself on a samples x samples parameter grid.

    A regular patch keeps the direction of S_u x S_v; a fold reverses it, and there normals, curvature
    and every offset built on them are meaningless. A sample is marked when its normal points against a
    grid neighbour's; samples where S_u x S_v vanishes (a degenerate corner) are not.

    Parameters
    ----------
    surface : BSplineSurface
        The surface to check.
    samples : int, optional
        Grid samples per direction over the domain, ends included (default 33).

    Returns
    -------
    mask : (samples, samples) bool
        True at folded samples (see `flipped_normals`).
    u, v : (samples, samples) float64
        The parameters of the samples, index [i, j] along u then v.
    """
    (u0, u1), (v0, v1) = surface.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, samples), np.linspace(v0, v1, samples), indexing="ij")
    n = np.cross(surface.evaluate(uu, vv, du=1), surface.evaluate(uu, vv, dv=1))
    folded = flipped_normals(n)
    return folded, uu, vv


def flipped_normals(normals: np.ndarray) -> np.ndarray:
    """Mark the samples of a grid of normals that point against a grid neighbour's.

    The normals need not be unit; those of vanishing length (a degenerate corner, at most 1e-9 times
    the median length) are not marked.

    Parameters
    ----------
    normals : (a, b, 3) array_like of float
        Normals (such as S_u x S_v) on a parameter grid; any length unit.

    Returns
    -------
    mask : (a, b) bool
        True where the normal's dot product with a neighbour's along either grid axis is negative.
    """
    n = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(n, axis=-1)
    ok = length > 1e-9 * max(float(np.median(length)), 1e-300)
    n = n / np.where(ok, length, 1.0)[..., None]
    folded = np.zeros(ok.shape, dtype=bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        flip = (np.einsum("ijk,ijk->ij", n[tuple(a)], n[tuple(b)]) < 0) & ok[tuple(a)] & ok[tuple(b)]
        folded[tuple(a)] |= flip
        folded[tuple(b)] |= flip
    return folded


def find_folds(surface: BSplineSurface, *, samples: int = 33) -> tuple[float, np.ndarray | None]:
    """The share of a samples x samples parameter grid where the surface folds (`fold_mask`), and one such
    point.

    Parameters
    ----------
    surface : BSplineSurface
        The surface to check.
    samples : int, optional
        Grid samples per direction (default 33; the planner checks on `FOLD_CHECK_SAMPLES`).

    Returns
    -------
    fraction : float
        Share of folded samples, in [0, 1].
    point : (3,) float64 or None
        A folded sample's point in mm (the first in grid order), or None when there is no fold.
    """
    folded, uu, vv = fold_mask(surface, samples=samples)
    if not folded.any():
        return 0.0, None
    i = np.unravel_index(np.argmax(folded), folded.shape)
    return float(folded.mean()), surface.evaluate(uu[i], vv[i])
