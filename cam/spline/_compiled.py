"""Compiled B-spline surface evaluation and foot-point Newton iteration: one point at a time.

The fit evaluates its nets thousands of times at a few hundred points each (a surface with C0 knot lines
is searched piece by piece), so numpy's per-call cost, not arithmetic, was its time. These kernels work
point by point, operation for operation as the vectorised numpy code they replace (kept in the tests as
the reference): the basis functions by the same recursions, each surface
value summed in the order numpy's einsum sums it over the strided gather of the net (one product after
another), three-term dot products and norms as einsum and np.linalg.norm sum them, no fused multiply-add. So values, feet and distances are bit for bit the numpy code's.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from cam.mesh._compiled import dot3, norm3

__all__ = ["design_rows", "evaluate_net", "newton_feet", "project_in_boxes", "window_boxes"]


@njit(cache=True)
def _span(knots, degree, t):
    """`basis.find_spans` for one parameter: the last knot ≤ t, clipped to [degree, count - 1]."""
    count = knots.size - degree - 1
    if math.isnan(t):
        return count - 1  # NaN sorts last in np.searchsorted
    lo, hi = 0, knots.size
    while lo < hi:
        mid = (lo + hi) // 2
        if knots[mid] <= t:
            lo = mid + 1
        else:
            hi = mid
    return min(max(lo - 1, degree), count - 1)


@njit(cache=True)
def _tables(knots, degree, t, span, table, left, right):
    """`basis._values` for one parameter: table[j, :j + 1] holds the degree-j functions."""
    table[0, 0] = 1.0
    for j in range(1, degree + 1):
        left[j] = t - knots[span + 1 - j]
        right[j] = knots[span + j] - t
        saved = 0.0
        for r in range(j):
            denom = right[r + 1] + left[j - r]
            temp = table[j - 1, r] / denom if denom != 0 else 0.0
            table[j, r] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        table[j, j] = saved


@njit(cache=True)
def _raise(knots, span, degree, lower, out):
    """One step of `basis._derivative`: from the degree - 1 functions' derivatives `lower` (degree,) to
    the degree functions' next derivative, into out (degree + 1,)."""
    for m in range(degree + 1):
        a = span - degree + m
        d1 = knots[a + degree] - knots[a]
        d2 = knots[a + degree + 1] - knots[a + 1]
        e1 = lower[m - 1] if m >= 1 else 0.0
        e2 = lower[m] if m < degree else 0.0
        t1 = e1 / d1 if d1 != 0 else 0.0
        t2 = e2 / d2 if d2 != 0 else 0.0
        out[m] = degree * (t1 - t2)


@njit(cache=True)
def _basis(knots, degree, t, order, out, table, left, right, scratch):
    """Span of t and the basis functions' derivatives 0..min(order, degree) into out[d, :degree + 1]."""
    span = _span(knots, degree, t)
    _tables(knots, degree, t, span, table, left, right)
    for m in range(degree + 1):
        out[0, m] = table[degree, m]
    if order >= 1 and degree >= 1:
        _raise(knots, span, degree, table[degree - 1], out[1])
    if order >= 2 and degree >= 2:
        _raise(knots, span, degree - 1, table[degree - 2], scratch)
        _raise(knots, span, degree, scratch, out[2])
    return span


@njit(cache=True)
def _term(cp, bu, bv, iu0, iv0, p, q, k):
    """Σ bu[i] bv[j] cp[iu0 + i, iv0 + j, k] summed as numpy's einsum("nm,nm->n") sums it in
    `basis.evaluate_surface`, where the net's gather is strided: one product after another."""
    acc = 0.0
    for i in range(p + 1):
        for j in range(q + 1):
            acc = (bu[i] * bv[j]) * cp[iu0 + i, iv0 + j, k] + acc
    return acc + 0.0


# The partials (du, dv) in the kernels' order: out[k] holds _PAIRS[k].
_PAIRS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))


@njit(cache=True)
def _second_order_terms(cp, bu, bv, iu0, iv0, p, q, out):
    """out[:6] for order 2 (p, q ≥ 2): each entry `_term`'s sum with `_term`'s operations, six of them side by
    side per coordinate (independent chains instead of one after another)."""
    for k in range(cp.shape[2]):
        a0 = a1 = a2 = a3 = a4 = a5 = 0.0
        for i in range(p + 1):
            for j in range(q + 1):
                c = cp[iu0 + i, iv0 + j, k]
                a0 = (bu[0, i] * bv[0, j]) * c + a0
                a1 = (bu[1, i] * bv[0, j]) * c + a1
                a2 = (bu[0, i] * bv[1, j]) * c + a2
                a3 = (bu[2, i] * bv[0, j]) * c + a3
                a4 = (bu[1, i] * bv[1, j]) * c + a4
                a5 = (bu[0, i] * bv[2, j]) * c + a5
        out[0, k], out[1, k], out[2, k] = a0 + 0.0, a1 + 0.0, a2 + 0.0
        out[3, k], out[4, k], out[5, k] = a3 + 0.0, a4 + 0.0, a5 + 0.0


@njit(cache=True)
def _point_terms(cp, bu, bv, iu0, iv0, p, q, out):
    """out[0] (order 0) of a net in three coordinates, the three sums side by side."""
    a0 = a1 = a2 = 0.0
    for i in range(p + 1):
        for j in range(q + 1):
            w = bu[0, i] * bv[0, j]
            a0 = w * cp[iu0 + i, iv0 + j, 0] + a0
            a1 = w * cp[iu0 + i, iv0 + j, 1] + a1
            a2 = w * cp[iu0 + i, iv0 + j, 2] + a2
    out[0, 0], out[0, 1], out[0, 2] = a0 + 0.0, a1 + 0.0, a2 + 0.0


@njit(cache=True)
def _evaluate(ku, kv, cp, p, q, u, v, order, out, work):
    """S and its partials up to total `order` (≤ 2) at (u, v): out[k, coordinate] for _PAIRS[k]; a pair
    beyond the degrees is zero. `work` holds the scratch arrays."""
    bu, bv, table, left, right, scratch = work
    su = _basis(ku, p, u, order, bu, table, left, right, scratch)
    sv = _basis(kv, q, v, order, bv, table, left, right, scratch)
    if order >= 2 and p >= 2 and q >= 2:
        _second_order_terms(cp, bu, bv, su - p, sv - q, p, q, out)
        return
    if order == 0 and cp.shape[2] == 3:
        _point_terms(cp, bu, bv, su - p, sv - q, p, q, out)
        return
    for n in range(6 if order >= 2 else (3 if order == 1 else 1)):
        a, b = _PAIRS[n]
        for k in range(cp.shape[2]):
            out[n, k] = 0.0 if a > p or b > q else _term(cp, bu[a], bv[b], su - p, sv - q, p, q, k)


@njit(cache=True)
def _work(p, q):
    deg = max(p, q)
    return (np.zeros((3, deg + 1)), np.zeros((3, deg + 1)), np.zeros((deg + 1, deg + 1)), np.zeros(deg + 1),
            np.zeros(deg + 1), np.zeros(deg + 1))


@njit(cache=True, nogil=True)
def _evaluate_net(ku, kv, cp, p, q, u, v, order, values):
    work = _work(p, q)
    out = np.zeros((6, cp.shape[2]))
    for i in range(u.size):
        _evaluate(ku, kv, cp, p, q, u[i], v[i], order, out, work)
        for n in range(values.shape[0]):
            for k in range(cp.shape[2]):
                values[n, i, k] = out[n, k]


def evaluate_net(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, u: np.ndarray,
                 v: np.ndarray, degree: tuple[int, int], order: int) -> dict[tuple[int, int], np.ndarray]:
    """A control net's points and partials up to total `order` at (u, v); see `basis.evaluate_surface`.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        Clamped knot vectors, parameter units.
    control_points : ndarray, shape (nu, nv, d), float64
        The control net.
    u, v : ndarray, shape (n,), float64
        Parameters.
    degree : tuple of int
        (p, q).
    order : int
        0, 1 or 2.

    Returns
    -------
    dict of (int, int) to ndarray, shape (n, d), float64
        {(du, dv): ∂^(du+dv)S/∂u^du∂v^dv} for every du + dv ≤ order.
    """
    cp = np.ascontiguousarray(control_points, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64).ravel()
    v = np.ascontiguousarray(v, dtype=np.float64).ravel()
    count = (1, 3, 6)[order]
    values = np.empty((count, u.size, cp.shape[2]))
    _evaluate_net(np.ascontiguousarray(knots_u, dtype=np.float64), np.ascontiguousarray(knots_v, dtype=np.float64),
                  cp, int(degree[0]), int(degree[1]), u, v, order, values)
    return {_PAIRS[k]: values[k] for k in range(count)}


@njit(cache=True, nogil=True)
def _design_rows(ku, kv, p, q, u, v, du, dv, nv, cols, vals):
    work = _work(p, q)
    bu, bv, table, left, right, scratch = work
    for n in range(u.size):
        su = _basis(ku, p, u[n], du, bu, table, left, right, scratch)
        sv = _basis(kv, q, v[n], dv, bv, table, left, right, scratch)
        for a in range(p + 1):
            for b in range(q + 1):
                cols[n, a * (q + 1) + b] = (su - p + a) * nv + (sv - q + b)
                vals[n, a * (q + 1) + b] = bu[du, a] * bv[dv, b]


def design_rows(knots_u: np.ndarray, knots_v: np.ndarray, u: np.ndarray, v: np.ndarray, degree: tuple[int, int],
                du: int, dv: int) -> tuple[np.ndarray, np.ndarray]:
    """`basis.surface_rows` for derivative orders du, dv of at most 2 (and at most the degrees).

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        Clamped knot vectors, parameter units.
    u, v : ndarray, shape (n,), float64
        Parameters.
    degree : tuple of int
        (p, q).
    du, dv : int
        Derivative orders, 0..min(2, p) and 0..min(2, q).

    Returns
    -------
    cols : ndarray, shape (n, (p + 1)(q + 1)), int64
        Column indices i * nv + j.
    vals : ndarray, shape (n, (p + 1)(q + 1)), float64
        Products of the basis functions' derivatives, bit for bit those of `basis.surface_rows`.
    """
    p, q = int(degree[0]), int(degree[1])
    ku = np.ascontiguousarray(knots_u, dtype=np.float64)
    kv = np.ascontiguousarray(knots_v, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64).ravel()
    v = np.ascontiguousarray(v, dtype=np.float64).ravel()
    m = (p + 1) * (q + 1)
    cols, vals = np.empty((u.size, m), dtype=np.int64), np.empty((u.size, m))
    _design_rows(ku, kv, p, q, u, v, int(du), int(dv), kv.size - q - 1, cols, vals)
    return cols, vals


@njit(cache=True)
def _distance(ku, kv, cp, p, q, u, v, x, y, z, out, work):
    _evaluate(ku, kv, cp, p, q, u, v, 0, out, work)
    return norm3(out[0, 0] - x, out[0, 1] - y, out[0, 2] - z)


@njit(cache=True)
def _newton_one(ku, kv, cp, p, q, x, y, z, u, v, lo_u, lo_v, hi_u, hi_v, iterations, out, work, result):
    """Feet of one point: result = (u, v, distance); the iteration of `cam.fit.foot._newton`, row by row."""
    u = min(max(u, lo_u), hi_u)
    v = min(max(v, lo_v), hi_v)
    dist = np.nan
    for _ in range(iterations):
        _evaluate(ku, kv, cp, p, q, u, v, 2, out, work)
        r0, r1, r2 = out[0, 0] - x, out[0, 1] - y, out[0, 2] - z
        su0, su1, su2 = out[1, 0], out[1, 1], out[1, 2]
        sv0, sv1, sv2 = out[2, 0], out[2, 1], out[2, 2]
        g0 = dot3(r0, r1, r2, su0, su1, su2)
        g1 = dot3(r0, r1, r2, sv0, sv1, sv2)
        held_u = (u <= lo_u and g0 > 0) or (u >= hi_u and g0 < 0)
        held_v = (v <= lo_v and g1 > 0) or (v >= hi_v and g1 < 0)
        if held_u:
            g0 = 0.0
        if held_v:
            g1 = 0.0
        free = not (held_u or held_v)
        juu = dot3(su0, su1, su2, su0, su1, su2)
        juv = dot3(su0, su1, su2, sv0, sv1, sv2)
        jvv = dot3(sv0, sv1, sv2, sv0, sv1, sv2)
        huu = 1.0 if held_u else juu + dot3(r0, r1, r2, out[3, 0], out[3, 1], out[3, 2])
        huv = juv + dot3(r0, r1, r2, out[4, 0], out[4, 1], out[4, 2]) if free else 0.0
        hvv = 1.0 if held_v else jvv + dot3(r0, r1, r2, out[5, 0], out[5, 1], out[5, 2])
        det = huu * hvv - huv * huv
        if det <= 1e-12 * (huu * hvv + 1e-300) or huu <= 0 or hvv <= 0:
            # Not positive definite: Gauss–Newton (J^T J) where the parameter is free.
            if not held_u:
                huu = juu
            if free:
                huv = juv
            if not held_v:
                hvv = jvv
        det = huu * hvv - huv * huv
        if abs(det) < 1e-300:
            det = 1e-300
        step_u = -(hvv * g0 - huv * g1) / det
        step_v = -(huu * g1 - huv * g0) / det
        current = norm3(r0, r1, r2)
        new_u, new_v, new_d = u, v, current
        if abs(step_u) + abs(step_v) > 1e-13:
            scale = 1.0
            for _half in range(3):  # full step, then halves, until one shortens the distance
                tu = min(max(u + scale * step_u, lo_u), hi_u)
                tv = min(max(v + scale * step_v, lo_v), hi_v)
                td = _distance(ku, kv, cp, p, q, tu, tv, x, y, z, out, work)
                if td < current:
                    new_u, new_v, new_d = tu, tv, td
                    break
                scale *= 0.5
        moved = max(abs(new_u - u), abs(new_v - v))
        u, v, dist = new_u, new_v, new_d
        if not moved >= 1e-10:
            break
    if math.isnan(dist):  # no step taken (iterations = 0), as the numpy iteration measures it
        dist = _distance(ku, kv, cp, p, q, u, v, x, y, z, out, work)
    result[0], result[1], result[2] = u, v, dist


@njit(cache=True, nogil=True)
def _newton_feet(ku, kv, cp, p, q, points, u, v, lo, hi, iterations, fu, fv, fd):
    n = points.shape[0]
    work = _work(p, q)
    out = np.zeros((6, 3))
    result = np.zeros(3)
    for i in range(n):
        _newton_one(ku, kv, cp, p, q, points[i, 0], points[i, 1], points[i, 2], u[i], v[i], lo[i, 0], lo[i, 1],
                    hi[i, 0], hi[i, 1], iterations, out, work, result)
        fu[i], fv[i], fd[i] = result[0], result[1], result[2]


def newton_feet(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, points: np.ndarray,
                u: np.ndarray, v: np.ndarray, lo: np.ndarray, hi: np.ndarray, degree: tuple[int, int],
                iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton feet of `points` on a B-spline surface, each kept inside its parameter box.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        Clamped knot vectors, parameter units.
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    points : ndarray, shape (n, 3), float64
        Points, mm.
    u, v : ndarray, shape (n,), float64
        Starts, parameter units.
    lo, hi : ndarray, shape (n, 2), float64
        Each point's parameter box.
    degree : tuple of int
        (p, q), each at least 1.
    iterations : int
        Newton steps at most.

    Returns
    -------
    u, v : ndarray, shape (n,), float64
        The feet's parameters.
    distance : ndarray, shape (n,), float64
        Distance from each point to its foot, mm.
    """
    p, q = int(degree[0]), int(degree[1])
    n = len(points)
    fu, fv, fd = np.empty(n), np.empty(n), np.empty(n)
    as64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)
    _newton_feet(as64(knots_u), as64(knots_v), as64(control_points), p, q, as64(points).reshape(n, 3),
                 as64(u).ravel(), as64(v).ravel(), as64(lo).reshape(n, 2), as64(hi).reshape(n, 2),
                 int(iterations), fu, fv, fd)
    return fu, fv, fd


@njit(cache=True)
def _project_one(ku, kv, cp, p, q, x, y, z, u, v, lo_u, lo_v, hi_u, hi_v, iterations, out, work, result):
    """Projected Newton for the foot of one point inside its box: `cam.plan.gouge`'s iteration, point by point."""
    u = min(max(u, lo_u), hi_u)
    v = min(max(v, lo_v), hi_v)
    for _ in range(iterations):
        _evaluate(ku, kv, cp, p, q, u, v, 2, out, work)
        d0, d1, d2 = out[0, 0] - x, out[0, 1] - y, out[0, 2] - z
        su0, su1, su2 = out[1, 0], out[1, 1], out[1, 2]
        sv0, sv1, sv2 = out[2, 0], out[2, 1], out[2, 2]
        g0 = dot3(su0, su1, su2, d0, d1, d2)
        g1 = dot3(sv0, sv1, sv2, d0, d1, d2)
        juu = dot3(su0, su1, su2, su0, su1, su2)
        juv = dot3(su0, su1, su2, sv0, sv1, sv2)
        jvv = dot3(sv0, sv1, sv2, sv0, sv1, sv2)
        a = juu + dot3(out[3, 0], out[3, 1], out[3, 2], d0, d1, d2)
        b = juv + dot3(out[4, 0], out[4, 1], out[4, 2], d0, d1, d2)
        c = jvv + dot3(out[5, 0], out[5, 1], out[5, 2], d0, d1, d2)
        if a * c - b * b <= 1e-12 * (a * a + c * c + 1e-300) or a <= 0:
            a, b, c = juu, juv, jvv  # not positive definite: Gauss–Newton
        det = max(a * c - b * b, 1e-300)
        step_u = -(c * g0 - b * g1) / det
        step_v = -(a * g1 - b * g0) / det
        # A coordinate on its bound with the gradient pushing out stays there; the other takes a 1-D step.
        pin_u = (u <= lo_u and g0 > 0) or (u >= hi_u and g0 < 0)
        pin_v = (v <= lo_v and g1 > 0) or (v >= hi_v and g1 < 0)
        if pin_u or pin_v:
            step_u = 0.0 if pin_u else -g0 / max(a, 1e-300)
            step_v = 0.0 if pin_v or not pin_u else -g1 / max(c, 1e-300)
        u = min(max(u + step_u, lo_u), hi_u)
        v = min(max(v + step_v, lo_v), hi_v)
        if max(abs(step_u), abs(step_v)) < 1e-13:
            break
    result[0], result[1] = u, v


@njit(cache=True, nogil=True)
def _project_in_boxes(ku, kv, cp, p, q, points, uv, lo, hi, iterations, found):
    work = _work(p, q)
    out = np.zeros((6, 3))
    result = np.zeros(2)
    for i in range(points.shape[0]):
        _project_one(ku, kv, cp, p, q, points[i, 0], points[i, 1], points[i, 2], uv[i, 0], uv[i, 1], lo[i, 0],
                     lo[i, 1], hi[i, 0], hi[i, 1], iterations, out, work, result)
        found[i, 0], found[i, 1] = result[0], result[1]


def project_in_boxes(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, points: np.ndarray,
                     uv: np.ndarray, lo: np.ndarray, hi: np.ndarray, degree: tuple[int, int], iterations: int
                     ) -> np.ndarray:
    """Projected-Newton feet of `points` on a B-spline surface, each inside its parameter box.

    Each step solves with the Hessian of |S - x|² (Gauss–Newton where it is not positive definite); a
    parameter on its bound whose gradient points out of the box is held there while the other takes a
    one-dimensional Newton step; a point stops once its step is below 1e-13.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        Clamped knot vectors, parameter units.
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    points : ndarray, shape (n, 3), float64
        Points, mm.
    uv : ndarray, shape (n, 2), float64
        Starts, parameter units.
    lo, hi : ndarray, shape (n, 2), float64
        Each point's parameter box.
    degree : tuple of int
        (p, q), each at least 1.
    iterations : int
        Newton steps at most.

    Returns
    -------
    ndarray, shape (n, 2), float64
        The feet's parameters.
    """
    n = len(points)
    found = np.empty((n, 2))
    as64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)
    _project_in_boxes(as64(knots_u), as64(knots_v), as64(control_points), int(degree[0]), int(degree[1]),
                      as64(points).reshape(n, 3), as64(uv).reshape(n, 2), as64(lo).reshape(n, 2),
                      as64(hi).reshape(n, 2), int(iterations), found)
    return found


@njit(cache=True, nogil=True)
def _box_bounds(points, key, lo, hi, starts, out):
    for i in range(points.shape[0]):
        k = key[i]
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        best = np.inf
        for b in range(starts[k], starts[k + 1]):
            g0 = max(max(lo[b, 0] - x, x - hi[b, 0]), 0.0)
            g1 = max(max(lo[b, 1] - y, y - hi[b, 1]), 0.0)
            g2 = max(max(lo[b, 2] - z, z - hi[b, 2]), 0.0)
            # Summed as numpy's einsum sums three products, so that the bounds, and the pieces they prune, are
            # those of the numpy code this replaced.
            d = dot3(g0, g1, g2, g0, g1, g2)
            if d < best:
                best = d
                if d == 0.0:
                    break
        out[i] = math.sqrt(best)


def box_bounds(points: np.ndarray, key: np.ndarray, lo: np.ndarray, hi: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest of its group's boxes (the `PieceBoxes.distance_bound` kernel).

    Parameters
    ----------
    points : (n, 3) float
        Points, mm.
    key : (n,) int
        The group of each point; its boxes are rows starts[key] .. starts[key + 1] of lo and hi.
    lo, hi : (m, 3) float
        Box corners, mm.
    starts : (groups + 1,) int
        Where each group's boxes begin.

    Returns
    -------
    (n,) float64
        The distances, mm: 0 inside a box, inf for a group without boxes. The same numbers as
        sqrt(min over boxes of the gap's squared length) summed by einsum.
    """
    n = len(points)
    out = np.empty(n)
    _box_bounds(np.ascontiguousarray(points, dtype=np.float64).reshape(n, 3),
                np.ascontiguousarray(key, dtype=np.int64).ravel(), np.ascontiguousarray(lo, dtype=np.float64),
                np.ascontiguousarray(hi, dtype=np.float64), np.ascontiguousarray(starts, dtype=np.int64), out)
    return out


@njit(cache=True, nogil=True)
def _window_boxes(cp, p, q, lo, hi):
    for i in range(lo.shape[0]):
        for j in range(lo.shape[1]):
            for k in range(cp.shape[2]):
                small = large = cp[i, j, k]
                for a in range(p + 1):
                    for b in range(q + 1):
                        x = cp[i + a, j + b, k]
                        # as np.min and np.max: a NaN anywhere is the answer
                        if not math.isnan(small) and (math.isnan(x) or x < small):
                            small = x
                        if not math.isnan(large) and (math.isnan(x) or x > large):
                            large = x
                lo[i, j, k], hi[i, j, k] = small, large


def window_boxes(control_points: np.ndarray, degree: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Per window of (p + 1) x (q + 1) control points, their box: `pieces.span_boxes`' lo and hi.

    Parameters
    ----------
    control_points : ndarray, shape (nu, nv, d), float64
        The control net.
    degree : tuple of int
        (p, q).

    Returns
    -------
    lo, hi : ndarray, shape (nu - p, nv - q, d), float64
        Each window's smallest and largest coordinates (NaN where it holds one, as numpy's).
    """
    p, q = int(degree[0]), int(degree[1])
    cp = np.ascontiguousarray(control_points, dtype=np.float64)
    shape = (cp.shape[0] - p, cp.shape[1] - q, cp.shape[2])
    lo, hi = np.empty(shape), np.empty(shape)
    _window_boxes(cp, p, q, lo, hi)
    return lo, hi
