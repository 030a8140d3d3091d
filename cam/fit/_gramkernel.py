"""Compiled accumulation of the normal equations' Gram blocks B^T diag(w) B, in band storage.

A surface's design-matrix row touches the (p + 1)(q + 1) control points of one knot cell, so two control
points i*nv + j and i'*nv + j' meet in B^T B only when |i - i'| ≤ p and |j - j'| ≤ q: each Gram block fits in
(nu nv, (2p + 1)(2q + 1)) band storage, entry [c, (di + p)(2q + 1) + dj + q] holding its (c, c + di nv + dj).
Summed row by row here, and the upper triangle only (each block is symmetric), the six coordinate-pair
blocks of a row set cost a few multiply-adds per product instead of six sparse matrix products and
conversions.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["accumulate_grams", "band_slot"]


def band_slot(di: np.ndarray, dj: np.ndarray, degree: tuple[int, int]) -> np.ndarray:
    """Band column of the entry between control points (i, j) and (i + di, j + dj).

    Parameters
    ----------
    di, dj : ndarray of int
        Offsets along u and v, |di| ≤ p, |dj| ≤ q.
    degree : tuple of int
        (p, q).

    Returns
    -------
    ndarray of int64
        (di + p)(2q + 1) + dj + q, in [0, (2p + 1)(2q + 1)).
    """
    p, q = degree
    return ((np.asarray(di) + p) * (2 * q + 1) + np.asarray(dj) + q).astype(np.int64)


@njit(cache=True, nogil=True)
def _accumulate(cols, vals, weights, order, p, q, band):
    n, m = cols.shape
    width = 2 * q + 1
    # One knot cell's rows at a time, gathered (transposed, so a row index runs along memory): each entry of
    # the cell's six blocks summed over them from zero in row order, then added to the band once. The six
    # sums run side by side, each its own chain in the same order as alone: six times the additions in
    # flight, the same bits.
    rows_v = np.empty((m, n))
    rows_w = np.empty((6, n))
    first = 0
    while first < n:
        last = first
        while last + 1 < n and cols[order[last + 1], 0] == cols[order[first], 0]:
            last += 1
        count = last - first + 1
        for t in range(count):
            r = order[first + t]
            for a in range(m):
                rows_v[a, t] = vals[r, a]
            for k in range(6):
                rows_w[k, t] = weights[r, k]
        head = order[first]
        for a in range(m):
            ia, ja = a // (q + 1), a % (q + 1)
            c = cols[head, a]
            for b in range(a, m):  # columns grow with the position: b ≥ a is the upper triangle
                slot = (b // (q + 1) - ia + p) * width + (b % (q + 1) - ja + q)
                a0 = a1 = a2 = a3 = a4 = a5 = 0.0
                for t in range(count):
                    product = rows_v[a, t] * rows_v[b, t]
                    a0 += rows_w[0, t] * product
                    a1 += rows_w[1, t] * product
                    a2 += rows_w[2, t] * product
                    a3 += rows_w[3, t] * product
                    a4 += rows_w[4, t] * product
                    a5 += rows_w[5, t] * product
                band[c, slot, 0] += a0
                band[c, slot, 1] += a1
                band[c, slot, 2] += a2
                band[c, slot, 3] += a3
                band[c, slot, 4] += a4
                band[c, slot, 5] += a5
        first = last + 1


def accumulate_grams(cols: np.ndarray, vals: np.ndarray, weights: np.ndarray, degree: tuple[int, int],
                     band: np.ndarray) -> None:
    """Add the upper triangle of B^T diag(weights[:, k]) B to band[..., k] for each of the six k, B given by
    its rows.

    Parameters
    ----------
    cols : ndarray, shape (n, (p + 1)(q + 1)), int64
        Column indices of each row's non-zeros, as `cam.spline.basis.surface_rows` lays them out
        (control point (i0 + i) nv + (j0 + j) at position i (q + 1) + j, so they grow along a row).
    vals : ndarray, shape (n, (p + 1)(q + 1)), float64
        The matching values.
    weights : ndarray, shape (n, 6), float64
        Row weights of each of the six blocks (the coordinate pairs xx, xy, xz, yy, yz, zz).
    degree : tuple of int
        (p, q).
    band : ndarray, shape (nu nv, (2p + 1)(2q + 1), 6), float64
        The blocks in band storage (see the module docstring), entries (c, c2) with c2 ≥ c only (the
        blocks are symmetric); updated in place.

    Raises
    ------
    ValueError
        For weights or a band without six blocks.
    """
    if np.shape(weights)[1:] != (6,) or band.shape[2:] != (6,):
        raise ValueError(f"accumulate_grams sums six blocks; got weights {np.shape(weights)}, band {band.shape}")
    cols = np.ascontiguousarray(cols, dtype=np.int64)
    # Rows of one knot cell share their columns: summed cell by cell, the band is touched once per cell.
    order = np.argsort(cols[:, 0], kind="stable") if len(cols) else np.zeros(0, dtype=np.int64)
    _accumulate(cols, np.ascontiguousarray(vals, dtype=np.float64), np.ascontiguousarray(weights, dtype=np.float64),
                order, int(degree[0]), int(degree[1]), band)
