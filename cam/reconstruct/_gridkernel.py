"""Compiled trilinear interpolation of one `GridField` level on the CPU: weights, values and the gradient.

A training step interpolates every level at some 140k points; as torch operations that was a dozen
passes over (points, 8, 4) temporaries, half of the reconstruction's time. These kernels do one pass per
point with the same float32 operations in the same order as the torch code they replace (kept in
`cam.reconstruct.fields` for other devices and in the tests as the reference): each weight the same
products, each sum over the corners and over the four columns from zero in index order as torch's CPU
sum kernel adds so few terms, and the parameters' gradient added up in index order as `index_add_`
does. So a field trains to the same bits either way. Points are independent in `cell_weights` and
`interpolate` (threads over points); `scatter_gradient` runs in one thread, in index order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["cell_weights", "interpolate", "scatter_gradient"]


@njit(cache=True, inline="always")
def _axis(x, lo, h, top):
    """The cell along one axis and the weights (1 - t, t) of its two ends."""
    u = np.float32(x - lo) / h
    cell = min(max(math.floor(u), 0), top)
    t = u - np.float32(cell)  # outside the box t leaves [0, 1]: linear extrapolation
    return cell, np.float32(1.0) - t, t


@njit(cache=True, parallel=True)
def _cell_weights(x, lo, h, ones, dims, idx, weights):
    sx, sy = dims[1] * dims[2], dims[2]
    columns = weights.shape[2]
    for b in prange(x.shape[0]):
        cx, wx0, wx1 = _axis(x[b, 0], lo[0], h, dims[0] - 2)
        cy, wy0, wy1 = _axis(x[b, 1], lo[1], h, dims[1] - 2)
        cz, wz0, wz1 = _axis(x[b, 2], lo[2], h, dims[2] - 2)
        base = cx * sx + cy * sy + cz
        for i in range(2):
            wx = wx0 if i == 0 else wx1
            for j in range(2):
                wy = wy0 if j == 0 else wy1
                for k in range(2):
                    wz = wz0 if k == 0 else wz1
                    n = 4 * i + 2 * j + k
                    idx[8 * b + n] = base + i * sx + j * sy + k
                    weights[b, n, 0] = wx * (wy * wz)
                    if columns == 4:
                        weights[b, n, 1] = ones[i] * (wy * wz)
                        weights[b, n, 2] = wx * (ones[j] * wz)
                        weights[b, n, 3] = wx * (wy * ones[k])


def cell_weights(x: np.ndarray, lo: np.ndarray, h: float, dims: np.ndarray, with_grad: bool
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Corner indices and weights of one grid level at x; `fields._trilinear_weights` on the CPU.

    Parameters
    ----------
    x : ndarray, shape (B, 3), float32
        Points, normalised frame.
    lo : ndarray, shape (3,), float32
        The grid's lower corner.
    h : float
        The level's cell size (rounded to float32 as torch rounds a Python scalar).
    dims : ndarray, shape (3,), int64
        Vertices along each axis.
    with_grad : bool
        Also the weights of the gradient's three columns.

    Returns
    -------
    idx : ndarray, shape (B * 8,), int64
        Flat vertex index of each point's 8 cell corners (x-major, z fastest).
    weights : ndarray, shape (B, 8, 4 or 1), float32
        f (and df/dx, df/dy, df/dz) as the sum over the corners of value * weight.
    """
    x = np.ascontiguousarray(x, dtype=np.float32)
    ones = np.array([-1.0 / h, 1.0 / h], dtype=np.float32)
    idx = np.empty(8 * len(x), dtype=np.int64)
    weights = np.empty((len(x), 8, 4 if with_grad else 1), dtype=np.float32)
    _cell_weights(x, np.ascontiguousarray(lo, dtype=np.float32), np.float32(h), ones,
                  np.ascontiguousarray(dims, dtype=np.int64), idx, weights)
    return idx, weights


@njit(cache=True, parallel=True)
def _interpolate(values, idx, weights, out):
    for b in prange(weights.shape[0]):
        for c in range(weights.shape[2]):
            acc = np.float32(0.0)
            for n in range(8):
                acc += values[idx[8 * b + n]] * weights[b, n, c]
            out[b, c] = acc


def interpolate(values: np.ndarray, idx: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(B, C) float32: per point and column, the sum over its 8 corners of values[idx] * weights.

    values (V,) float32, idx (B * 8,) int64 and weights (B, 8, C) float32 as `cell_weights` gives them.
    """
    out = np.empty((weights.shape[0], weights.shape[2]), dtype=np.float32)
    _interpolate(values, idx, weights, out)
    return out


@njit(cache=True)
def _scatter_gradient(idx, weights, grad_out, grad):
    for b in range(weights.shape[0]):
        for n in range(8):
            acc = np.float32(0.0)
            for c in range(weights.shape[2]):
                acc += weights[b, n, c] * grad_out[b, c]
            grad[idx[8 * b + n]] += acc


def scatter_gradient(idx: np.ndarray, weights: np.ndarray, grad_out: np.ndarray, size: int) -> np.ndarray:
    """(size,) float32 gradient of the level's values: each corner's weights dotted with grad_out (B, C)
    float32, added up in index order."""
    grad = np.zeros(size, dtype=np.float32)
    _scatter_gradient(idx, weights, np.ascontiguousarray(grad_out, dtype=np.float32), grad)
    return grad
