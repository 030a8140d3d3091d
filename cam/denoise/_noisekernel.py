"""Compiled loops of the noise estimate (`cam.denoise.noise`): ring neighbourhoods and one quadric fit per vertex.

Per vertex the arithmetic of the model `cam.denoise.noise` describes, with two small 3 x 3 and 6 x 6
symmetric eigen-decompositions instead of numpy's stacked ones: the normal matrix's eigenvalues give its
condition (a 2-norm condition number, as `np.linalg.cond` computes it for a symmetric positive semidefinite
matrix) and its inverse, from which both the constant term and the leverage are read. The residuals agree
with the vectorised fit to rounding (`tests/cam/test_denoise_noise.py` keeps it as the oracle).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from cam.mesh._compiled import KERNEL_LOCK

__all__ = ["quadric_residuals", "ring_neighbourhoods"]


@njit(cache=True)
def _fit_one(x, nbrs, count, origin):
    p = np.empty((count, 3))
    cen = np.zeros(3)
    for j in range(count):
        for a in range(3):
            p[j, a] = x[nbrs[j], a] - x[origin, a]
            cen[a] += p[j, a]
    cen /= count
    cov = np.zeros((3, 3))
    for j in range(count):
        for a in range(3):
            for b in range(3):
                cov[a, b] += (p[j, a] - cen[a]) * (p[j, b] - cen[b])
    evals, evecs = np.linalg.eigh(cov)
    # scale u, v by the neighbourhood's spread so that the normal matrix is well conditioned at any unit
    s = math.sqrt(max(evals[2], 1e-300) / count)
    ata = np.zeros((6, 6))
    atb = np.zeros(6)
    row = np.empty(6)
    for j in range(count):
        u = (p[j, 0] * evecs[0, 2] + p[j, 1] * evecs[1, 2] + p[j, 2] * evecs[2, 2]) / s
        v = (p[j, 0] * evecs[0, 1] + p[j, 1] * evecs[1, 1] + p[j, 2] * evecs[2, 1]) / s
        h = p[j, 0] * evecs[0, 0] + p[j, 1] * evecs[1, 0] + p[j, 2] * evecs[2, 0]
        row[0], row[1], row[2], row[3], row[4], row[5] = 1.0, u, v, u * u, u * v, v * v
        for a in range(6):
            atb[a] += row[a] * h
            for b in range(6):
                ata[a, b] += row[a] * row[b]
    lam, w = np.linalg.eigh(ata)
    if not lam[0] > lam[5] * 1e-12:  # a fit through collinear points
        return np.nan
    # The vertex itself is at u = v = 0: its prediction is the constant term, its design row e_0.
    coef0 = 0.0
    leverage = 0.0
    for i in range(6):
        wtb = 0.0
        for a in range(6):
            wtb += w[a, i] * atb[a]
        coef0 += w[0, i] * wtb / lam[i]
        leverage += w[0, i] * w[0, i] / lam[i]
    return -coef0 / math.sqrt(max(1.0 - leverage, 1e-6))


@njit(cache=True, parallel=True)
def _residuals(x, idx, count, min_count, out):
    for k in prange(idx.shape[0]):
        out[k] = _fit_one(x, idx[k], count[k], k) if count[k] >= min_count else np.nan


def quadric_residuals(x: np.ndarray, idx: np.ndarray, count: np.ndarray, *, min_count: int) -> np.ndarray:
    """Each vertex's standardised residual along the normal of a quadric fitted to its neighbours.

    Parameters
    ----------
    x : ndarray, shape (n, 3), float64
        Vertex positions, any unit.
    idx : ndarray, shape (n, K), int64
        Per vertex its neighbours (itself included), the first ``count`` of the row.
    count : ndarray, shape (n,), int64
        How many of each row's entries are neighbours.
    min_count : int
        Vertices with fewer neighbours get NaN.

    Returns
    -------
    ndarray, shape (n,), float64
        The residuals in the units of ``x``; NaN where a vertex has too few neighbours or its fit is
        degenerate (condition number of the normal matrix 1e12 or more).
    """
    out = np.empty(len(idx))
    with KERNEL_LOCK:
        _residuals(np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(idx, dtype=np.int64),
                   np.ascontiguousarray(count, dtype=np.int64), int(min_count), out)
    return out


@njit(cache=True)
def _ring(indptr, indices, k, rings):
    # breadth first from k, `rings` edges deep; the neighbourhoods are tens of vertices, so a linear
    # membership test is cheaper than a visited mark per vertex
    buf = np.empty(64, np.int64)
    buf[0], size, lo = k, 1, 0
    for _ in range(rings):
        hi = size
        for a in range(lo, hi):
            for jj in range(indptr[buf[a]], indptr[buf[a] + 1]):
                w = indices[jj]
                seen = False
                for b in range(size):
                    if buf[b] == w:
                        seen = True
                        break
                if not seen:
                    if size == len(buf):
                        grown = np.empty(2 * size, np.int64)
                        grown[:size] = buf
                        buf = grown
                    buf[size] = w
                    size += 1
        lo = hi
    return np.sort(buf[:size])


@njit(cache=True, parallel=True)
def _rings(indptr, indices, x, rings, idx, count):
    for k in prange(x.shape[0]):
        near = _ring(indptr, indices, k, rings)
        d = np.empty(len(near))
        for b in range(len(near)):
            e0, e1, e2 = x[near[b], 0] - x[k, 0], x[near[b], 1] - x[k, 1], x[near[b], 2] - x[k, 2]
            d[b] = e0 * e0 + e1 * e1 + e2 * e2
        order = np.argsort(d, kind="mergesort")  # stable: equal distances in vertex order
        count[k] = min(len(near), idx.shape[1])
        for b in range(count[k]):
            idx[k, b] = near[order[b]]


def ring_neighbourhoods(x: np.ndarray, indptr: np.ndarray, indices: np.ndarray, *, rings: int,
                        max_neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """The nearest vertices within ``rings`` edges of each vertex (itself included).

    Parameters
    ----------
    x : ndarray, shape (n, 3), float64
        Vertex positions.
    indptr, indices : ndarray, int
        The vertex adjacency in compressed-row form (each vertex's edge neighbours, itself not among them).
    rings, max_neighbours : int
        Neighbourhood depth in edges; at most this many of its vertices, the nearest (equal distances in
        vertex order).

    Returns
    -------
    idx : ndarray, shape (n, K), int64
        Per vertex its neighbours by distance, the first ``count`` of the row (the rest 0);
        K = min(max_neighbours, the largest neighbourhood).
    count : ndarray, shape (n,), int64
    """
    idx = np.zeros((len(x), max_neighbours), np.int64)
    count = np.zeros(len(x), np.int64)
    with KERNEL_LOCK:
        _rings(np.ascontiguousarray(indptr, dtype=np.int64), np.ascontiguousarray(indices, dtype=np.int64),
               np.ascontiguousarray(x, dtype=np.float64), int(rings), idx, count)
    return idx[:, :max(int(count.max(initial=1)), 1)], count
