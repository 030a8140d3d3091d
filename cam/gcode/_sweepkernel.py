"""Compiled inner loop of `Sweep.probe`: every capsule near a point, met by the point's normal line.

The points spread along the moves are bucketed on a 3-D grid whose cell is the search radius, so the
moves near a point are those owning a spread point in the 27 cells around it. Each move is taken once
per point, measured exactly (its axis within r + reach, then the capsule interval) and folded into a
minimum and a maximum, which do not depend on the order: the results are those of the vectorised code
that came before, bit for bit (its operations are written out here in the same order, its three-term
einsum dot products included, `_dot`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from cam.mesh._compiled import KERNEL_LOCK

__all__ = ["probe_sweep"]

_BLOCK = 256


@njit(cache=True, inline="always")
def _dot(x0, x1, x2, y0, y1, y2):
    """x · y as numpy's einsum("ij,ij->i") sums three products here: (x0 y0 + x2 y2) + x1 y1."""
    return (x0 * y0 + x2 * y2) + x1 * y1


@njit(cache=True, inline="always")
def _sphere(px, py, pz, nx, ny, nz, cx, cy, cz, r):
    wx, wy, wz = px - cx, py - cy, pz - cz
    b = _dot(nx, ny, nz, wx, wy, wz)
    q = b * b - (_dot(wx, wy, wz, wx, wy, wz) - r * r)
    root = math.sqrt(max(q, 0.0))
    if q >= 0:
        return -b - root, -b + root
    return np.inf, -np.inf


@njit(cache=True, error_model="numpy")
def _capsule(px, py, pz, nx, ny, nz, a, b, r):
    """[t_in, t_out] of the line p + t·n with the capsule a → b (as `sweep.capsule_intervals`)."""
    t_in, t_out = _sphere(px, py, pz, nx, ny, nz, a[0], a[1], a[2], r)
    s_in, s_out = _sphere(px, py, pz, nx, ny, nz, b[0], b[1], b[2], r)
    t_in, t_out = min(t_in, s_in), max(t_out, s_out)
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    length = math.sqrt(abx * abx + aby * aby + abz * abz)
    ok = length > 1e-12
    dx, dy, dz = (abx / length, aby / length, abz / length) if ok else (0.0, 0.0, 0.0)
    wx, wy, wz = px - a[0], py - a[1], pz - a[2]
    nd, wd = _dot(nx, ny, nz, dx, dy, dz), _dot(wx, wy, wz, dx, dy, dz)
    npx, npy, npz = nx - nd * dx, ny - nd * dy, nz - nd * dz
    wpx, wpy, wpz = wx - wd * dx, wy - wd * dy, wz - wd * dz
    qa = _dot(npx, npy, npz, npx, npy, npz)
    qb = _dot(npx, npy, npz, wpx, wpy, wpz)
    qc = _dot(wpx, wpy, wpz, wpx, wpy, wpz) - r * r
    disc = qb * qb - qa * qc
    good = ok and qa > 1e-14 and disc >= 0
    if not good:
        return t_in, t_out
    root = math.sqrt(max(disc, 0.0))
    c_in, c_out = (-qb - root) / qa, (-qb + root) / qa
    if abs(nd) < 1e-14:
        inside = wd >= 0 and wd <= length
        lo, hi = (-np.inf, np.inf) if inside else (np.inf, -np.inf)
    else:
        s0, s1 = (0.0 - wd) / nd, (length - wd) / nd
        lo, hi = min(s0, s1), max(s0, s1)
    c_in, c_out = max(c_in, lo), min(c_out, hi)
    if c_in <= c_out:
        t_in, t_out = min(t_in, c_in), max(t_out, c_out)
    return t_in, t_out


@njit(cache=True, inline="always")
def _segment_distance(px, py, pz, a, b):
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    den = max(_dot(abx, aby, abz, abx, aby, abz), 1e-300)
    t = _dot(px - a[0], py - a[1], pz - a[2], abx, aby, abz) / den
    t = min(max(t, 0.0), 1.0)
    ex, ey, ez = px - (a[0] + t * abx), py - (a[1] + t * aby), pz - (a[2] + t * abz)
    return math.sqrt(ex * ex + ey * ey + ez * ez)


@njit(cache=True)
def _probe_point(i, p, n, a, b, r, reach, origin, cell, dims, keys, order, owner, stamp, scallop, gouge):
    px, py, pz = p[i, 0], p[i, 1], p[i, 2]
    ci = (math.floor((px - origin[0]) / cell), math.floor((py - origin[1]) / cell),
          math.floor((pz - origin[2]) / cell))
    sc, g = np.inf, 0.0
    for di in range(-1, 2):
        x = ci[0] + di
        if x < 0 or x >= dims[0]:
            continue
        for dj in range(-1, 2):
            y = ci[1] + dj
            if y < 0 or y >= dims[1]:
                continue
            for dk in range(-1, 2):
                z = ci[2] + dk
                if z < 0 or z >= dims[2]:
                    continue
                key = (x * dims[1] + y) * dims[2] + z
                for s in range(np.searchsorted(keys, key), np.searchsorted(keys, key, side="right")):
                    j = owner[order[s]]
                    if stamp[j] == i:
                        continue
                    stamp[j] = i
                    dist = _segment_distance(px, py, pz, a[j], b[j])
                    if not dist <= r + reach:
                        continue
                    t_in, t_out = _capsule(px, py, pz, n[i, 0], n[i, 1], n[i, 2], a[j], b[j], r)
                    if t_in <= t_out and t_out >= 0:
                        sc = min(sc, max(t_in, 0.0))
                    g = max(g, max(r - dist, 0.0))
    scallop[i] = sc if sc <= reach else np.inf
    gouge[i] = g


@njit(cache=True, parallel=True)
def _probe(p, n, a, b, r, reach, origin, cell, dims, keys, order, owner, scallop, gouge):
    blocks = (p.shape[0] + _BLOCK - 1) // _BLOCK
    for blk in prange(blocks):
        stamp = np.full(a.shape[0], -1, dtype=np.int64)
        for i in range(blk * _BLOCK, min((blk + 1) * _BLOCK, p.shape[0])):
            _probe_point(i, p, n, a, b, r, reach, origin, cell, dims, keys, order, owner, stamp, scallop, gouge)


def probe_sweep(p: np.ndarray, n: np.ndarray, a: np.ndarray, b: np.ndarray, r: float, reach: float,
                spread: np.ndarray, owner: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Material left along n and overcut per point (`Sweep.probe`'s results), the moves found through the
    spread points (K, 3) within `radius` of a point (owner (K,): their moves)."""
    p = np.ascontiguousarray(p, dtype=np.float64)
    n = np.ascontiguousarray(n, dtype=np.float64)
    scallop, gouge = np.full(len(p), np.inf), np.zeros(len(p))
    if not len(p) or not len(spread):
        return scallop, gouge
    origin = spread.min(axis=0)
    extent = float((spread.max(axis=0) - origin).max())
    # At least a hundred-thousandth of the extent, so that the cell keys stay far inside int64.
    cell = max(float(radius), extent * 1e-5, 1e-9)
    dims = (np.floor((spread.max(axis=0) - origin) / cell).astype(np.int64) + 1)
    ijk = np.floor((spread - origin) / cell).astype(np.int64)
    keys = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(keys, kind="stable")
    with KERNEL_LOCK:
        _probe(p, n, np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64),
               float(r), float(reach), origin, cell, dims, keys[order], order, owner, scallop, gouge)
    return scallop, gouge
