"""Compiled inner loops of the ball drop-cutter (`dropcutter.drop_ball`, `dropcutter.surface_height`).

One query at a time over the triangles bucketed in its cell, in bucket order: bounds first, the most
promising triangles exactly, then only the triangles whose bound beats the best so far. The arithmetic is
the closed forms of `dropcutter`'s docstring, written operation for operation as the earlier vectorised
code wrote them (no fused multiply-add, no reassociation), and ties go the way that code sent them, so the
heights and contact points are bit for bit what it gave.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from cam.mesh._compiled import KERNEL_LOCK

__all__ = ["bucket_boxes", "clear_queries", "drop_queries", "surface_queries"]


@njit(cache=True, inline="always")
def _vertex(qx, qy, t, r):
    best, k_best = -np.inf, 0
    for k in range(3):
        dx, dy = t[k, 0] - qx, t[k, 1] - qy
        d2 = dx * dx + dy * dy
        z = t[k, 2] + math.sqrt(max(r * r - d2, 0.0)) if d2 <= r * r else -np.inf
        if z > best:
            best, k_best = z, k
    return best, t[k_best, 0], t[k_best, 1], t[k_best, 2]


@njit(cache=True, inline="always")
def _edges(qx, qy, t, r):
    best, px, py, pz = -np.inf, 0.0, 0.0, 0.0
    for a in range(3):
        b = (a + 1) % 3
        dx, dy = t[b, 0] - t[a, 0], t[b, 1] - t[a, 1]
        length = math.sqrt(dx * dx + dy * dy)
        if not length > 1e-12:
            continue
        ux, uy = dx / length, dy / length
        rx, ry = qx - t[a, 0], qy - t[a, 1]
        s_q = rx * ux + ry * uy
        d = abs(rx * uy - ry * ux)
        if not d <= r:
            continue
        rho = math.sqrt(max(r * r - d * d, 0.0))
        m = (t[b, 2] - t[a, 2]) / length
        root = math.sqrt(1.0 + m * m)
        sigma = m * rho / root
        s = (sigma + s_q) / length
        if not (s >= 0.0 and s <= 1.0):
            continue
        z = t[a, 2] + m * s_q + rho * root
        if z > best:
            best = z
            px = t[a, 0] + s * (t[b, 0] - t[a, 0])
            py = t[a, 1] + s * (t[b, 1] - t[a, 1])
            pz = t[a, 2] + s * (t[b, 2] - t[a, 2])
    return best, px, py, pz


@njit(cache=True, inline="always")
def _facet(qx, qy, t, n, r):
    up = n[2] > 1e-12
    nz = n[2] if up else 1.0
    px, py = qx - r * n[0], qy - r * n[1]
    v0x, v0y = t[1, 0] - t[0, 0], t[1, 1] - t[0, 1]
    v1x, v1y = t[2, 0] - t[0, 0], t[2, 1] - t[0, 1]
    v2x, v2y = px - t[0, 0], py - t[0, 1]
    den = v0x * v1y - v0y * v1x
    if not abs(den) > 1e-300:
        den = np.inf
    s = (v2x * v1y - v2y * v1x) / den
    u = (v0x * v2y - v0y * v2x) / den
    plane_z = t[0, 2] - (n[0] * (px - t[0, 0]) + n[1] * (py - t[0, 1])) / nz
    inside = up and s >= 0 and u >= 0 and s + u <= 1
    return (plane_z + r * n[2] if inside else -np.inf), px, py, plane_z


@njit(cache=True)
def _exact(qx, qy, t, n, r, out):
    """Highest contact of the ball over (qx, qy) with one triangle: out[:] = centre z, contact x, y, z."""
    z, x, y, w = _vertex(qx, qy, t, r)
    ze, xe, ye, we = _edges(qx, qy, t, r)
    if ze > z:
        z, x, y, w = ze, xe, ye, we
    zf, xf, yf, wf = _facet(qx, qy, t, n, r)
    if zf > z:
        z, x, y, w = zf, xf, yf, wf
    out[0], out[1], out[2], out[3] = z, x, y, w


@njit(cache=True, inline="always")
def _bucket(qx, qy, origin, cell, shape, starts):
    """The range of `members` bucketed in the cell of (qx, qy); empty outside the grid or for NaN."""
    if not (math.isfinite(qx) and math.isfinite(qy)):
        return 0, 0
    ci = math.floor((qx - origin[0]) / cell)
    cj = math.floor((qy - origin[1]) / cell)
    if not (0 <= ci < shape[0] and 0 <= cj < shape[1]):
        return 0, 0
    c = int(ci) * shape[1] + int(cj)
    return starts[c], starts[c + 1]


@njit(cache=True, parallel=True)
def _drop_queries(xy, triangles, normals, top, lo, hi, r, origin, cell, shape, starts, members, z_out, p_out):
    """Fill z_out (n,) and p_out (n, 3) with the drop-cutter height and contact over each xy (n, 2)."""
    for i in prange(xy.shape[0]):
        qx, qy = xy[i, 0], xy[i, 1]
        first, last = _bucket(qx, qy, origin, cell, shape, starts)
        bounds = np.empty(last - first)
        top_bound = -np.inf
        for k in range(first, last):
            tri = members[k]
            gx = max(max(lo[tri, 0] - qx, qx - hi[tri, 0]), 0.0)
            gy = max(max(lo[tri, 1] - qy, qy - hi[tri, 1]), 0.0)
            d2 = gx * gx + gy * gy
            bound = top[tri] + math.sqrt(r * r - d2) if d2 <= r * r else np.nan
            bounds[k - first] = bound
            if bound > top_bound:  # noqa: PLR1730 — NaN (out of reach) must never win
                top_bound = bound
        if top_bound == -np.inf or np.isnan(top_bound):
            continue
        best = np.full(4, np.nan)
        best[0] = -np.inf
        cand = np.empty(4)
        found = False
        # The most promising triangles first (ties: the later one wins), then those that may still beat them.
        for k in range(first, last):
            if bounds[k - first] == top_bound:
                _exact(qx, qy, triangles[members[k]], normals[members[k]], r, cand)
                if cand[0] >= best[0]:
                    best[:] = cand
                    found = True
        guess = best[0]
        for k in range(first, last):
            bound = bounds[k - first]
            if bound > guess and bound != top_bound:
                _exact(qx, qy, triangles[members[k]], normals[members[k]], r, cand)
                if cand[0] >= best[0]:
                    best[:] = cand
        if found:
            z_out[i] = best[0]
            if np.isfinite(best[0]):
                p_out[i, 0], p_out[i, 1], p_out[i, 2] = best[1], best[2], best[3]


@njit(cache=True, parallel=True)
def _clear_queries(xy, limit, triangles, normals, top, lo, hi, r, origin, cell, shape, starts, members, clear):
    """Fill clear (n,) with whether no triangle lifts the ball over each xy (n, 2) above limit (n,): the
    drop-cutter height is the highest of the triangles' exact contacts, and a triangle whose bound is not
    above the limit cannot be the one that exceeds it, so `_drop_queries`'s height <= limit without
    finding the height.

    `members` lists each cell's triangles highest first (`DropIndex.by_top`): once a triangle's top plus
    the largest bound term, sqrt(r * r), is not above the limit, no bound after it is (d2 >= 0 makes every
    rounded sqrt(r * r - d2) at most that), and the query ends there."""
    reach = math.sqrt(r * r)
    for i in prange(xy.shape[0]):
        qx, qy, z = xy[i, 0], xy[i, 1], limit[i]
        first, last = _bucket(qx, qy, origin, cell, shape, starts)
        cand = np.empty(4)
        ok = True
        for k in range(first, last):
            tri = members[k]
            if top[tri] + reach <= z:  # and every triangle after it: none can bound above the limit
                break
            gx = max(max(lo[tri, 0] - qx, qx - hi[tri, 0]), 0.0)
            gy = max(max(lo[tri, 1] - qy, qy - hi[tri, 1]), 0.0)
            d2 = gx * gx + gy * gy
            if d2 <= r * r and top[tri] + math.sqrt(r * r - d2) > z:
                _exact(qx, qy, triangles[tri], normals[tri], r, cand)
                if cand[0] > z:
                    ok = False
                    break
        clear[i] = ok


def clear_queries(*args) -> None:
    """`_clear_queries` under the kernels' lock (arguments as there)."""
    with KERNEL_LOCK:
        _clear_queries(*args)


@njit(cache=True, parallel=True)
def _surface_queries(xy, triangles, normals, lo, hi, origin, cell, shape, starts, members, z_out):
    """Fill z_out (n,) with the highest facet height over each xy (n, 2) (-inf where none)."""
    for i in prange(xy.shape[0]):
        qx, qy = xy[i, 0], xy[i, 1]
        first, last = _bucket(qx, qy, origin, cell, shape, starts)
        for k in range(first, last):
            tri = members[k]
            if lo[tri, 0] <= qx <= hi[tri, 0] and lo[tri, 1] <= qy <= hi[tri, 1]:
                z, _, _, _ = _facet(qx, qy, triangles[tri], normals[tri], 0.0)
                if z > z_out[i]:  # noqa: PLR1730 — as the bound above
                    z_out[i] = z


def drop_queries(*args) -> None:
    """`_drop_queries` under the kernels' lock (arguments as there)."""
    with KERNEL_LOCK:
        _drop_queries(*args)


def surface_queries(*args) -> None:
    """`_surface_queries` under the kernels' lock (arguments as there)."""
    with KERNEL_LOCK:
        _surface_queries(*args)


@njit(cache=True)
def _bucket_boxes(i0, j0, i1, j1, ids, columns, cells, starts, members):
    for t in range(i0.size):  # count each cell's boxes
        for i in range(i0[t], i1[t] + 1):
            for j in range(j0[t], j1[t] + 1):
                starts[i * columns + j + 1] += 1
    for c in range(cells):
        starts[c + 1] += starts[c]
    fill = starts[:-1].copy()
    for t in range(i0.size):  # then list them, in box order within a cell
        for i in range(i0[t], i1[t] + 1):
            for j in range(j0[t], j1[t] + 1):
                c = i * columns + j
                members[fill[c]] = ids[t]
                fill[c] += 1


def bucket_boxes(i0: np.ndarray, j0: np.ndarray, i1: np.ndarray, j1: np.ndarray, shape: tuple[int, int], *,
                 ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The boxes (cell ranges i0..i1 x j0..j1, inclusive, int (m,)) each cell of a grid of `shape` meets.

    Returns (starts, members): int64 (shape[0] shape[1] + 1,) and (Σ box cells,); the boxes of cell
    c = i shape[1] + j are members[starts[c]:starts[c + 1]], in the order the boxes come (a counting sort:
    no sort, no array of every (box, cell) pair beside the result). Members are the boxes' positions
    (int64), or `ids[position]` (int (m,), members of its dtype) where given."""
    cells = int(shape[0]) * int(shape[1])
    counts = (i1 - i0 + 1) * (j1 - j0 + 1)
    starts = np.zeros(cells + 1, dtype=np.int64)
    ids = np.arange(len(i0), dtype=np.int64) if ids is None else np.ascontiguousarray(ids)
    members = np.empty(int(counts.sum()), dtype=ids.dtype)
    as64 = lambda a: np.ascontiguousarray(a, dtype=np.int64)
    _bucket_boxes(as64(i0), as64(j0), as64(i1), as64(j1), ids, int(shape[1]), cells, starts, members)
    return starts, members
