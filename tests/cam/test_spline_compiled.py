"""The compiled surface evaluation and foot-point Newton iteration against the numpy code they replaced
(kept here as the oracle): bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from cam.fit.foot import project_points
from cam.spline import basis
from cam.spline._compiled import newton_feet, project_in_boxes, window_boxes
from cam.spline.basis import evaluate_surface, surface_rows
from cam.spline.surface import clamped_uniform_knots, make_bspline_surface


def numpy_evaluate_surface(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray,
                     u: np.ndarray, v: np.ndarray, *, degree: tuple[int, int] = (3, 3), order: int = 2
                     ) -> dict[tuple[int, int], np.ndarray]:
    """The vectorised evaluation the kernel replaced (terms as `evaluate_surface` returns them)."""
    p, q = degree
    cp = np.asarray(control_points, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64).ravel()
    v = np.asarray(v, dtype=np.float64).ravel()
    ku = np.asarray(knots_u, dtype=np.float64)
    kv = np.asarray(knots_v, dtype=np.float64)
    su = basis.find_spans(ku, p, u)
    sv = basis.find_spans(kv, q, v)
    tu, tv = basis._values(ku, p, u, su), basis._values(kv, q, v, sv)
    bu = {d: basis._derivative(ku, tu, su, p, d) for d in range(min(order, p) + 1)}
    bv = {d: basis._derivative(kv, tv, sv, q, d) for d in range(min(order, q) + 1)}
    pairs = [(a, b) for a in range(order + 1) for b in range(order + 1 - a)]
    iu = su[:, None] - p + np.arange(p + 1)[None, :]
    iv = sv[:, None] - q + np.arange(q + 1)[None, :]
    n = u.size
    flat = (iu[:, :, None] * cp.shape[1] + iv[:, None, :]).reshape(n, (p + 1) * (q + 1))
    net = cp.reshape(-1, cp.shape[-1]).T[:, flat]  # (3, n, (p + 1)(q + 1)); per-coordinate gathers are fastest
    out = {}
    for a, b in pairs:
        if a in bu and b in bv:
            w = (bu[a][:, :, None] * bv[b][:, None, :]).reshape(n, -1)
            out[(a, b)] = np.stack([np.einsum("nm,nm->n", w, net[k]) for k in range(len(net))], axis=1)
        else:
            out[(a, b)] = np.zeros((n, cp.shape[-1]))
    return out


def numpy_newton(ku, kv, control_points, P, u, v, lo, hi, degree, iterations):
    """Newton steps for the feet of P (n, 3) from (u, v) (n,), each kept inside its box lo..hi (n, 2).

    A row stops once its step moves it less than 1e-10 (or not at all): most converge in two or
    three steps, and the rest keep iterating alone."""
    lo_u, lo_v, hi_u, hi_v = lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]
    u, v = np.clip(u, lo_u, hi_u), np.clip(v, lo_v, hi_v)  # new arrays: updated in place below
    dist = np.full(u.size, np.nan)

    def distance(uu, vv, idx):
        S = numpy_evaluate_surface(ku, kv, control_points, uu, vv, degree=degree, order=0)[(0, 0)]
        return np.linalg.norm(S - P[idx], axis=1)

    active = np.arange(u.size)
    for _ in range(iterations):
        if not active.size:
            break
        ua, va = u[active], v[active]
        d = numpy_evaluate_surface(ku, kv, control_points, ua, va, degree=degree, order=2)
        r = d[(0, 0)] - P[active]
        su, sv = d[(1, 0)], d[(0, 1)]
        g = np.stack([np.einsum("ij,ij->i", r, su), np.einsum("ij,ij->i", r, sv)], 1)
        # A parameter on its bound whose descent leads out of the box is held there, and the step is
        # taken in the other alone: the full step, clamped, can leave such a row where it is while
        # the foot lies along the border (a skewed parameterisation), short of it.
        held_u = ((ua <= lo_u[active]) & (g[:, 0] > 0)) | ((ua >= hi_u[active]) & (g[:, 0] < 0))
        held_v = ((va <= lo_v[active]) & (g[:, 1] > 0)) | ((va >= hi_v[active]) & (g[:, 1] < 0))
        g[held_u, 0] = 0.0
        g[held_v, 1] = 0.0
        free = ~(held_u | held_v)
        juu, juv, jvv = (np.einsum("ij,ij->i", a, b) for a, b in ((su, su), (su, sv), (sv, sv)))
        huu = np.where(held_u, 1.0, juu + np.einsum("ij,ij->i", r, d[(2, 0)]))
        huv = np.where(free, juv + np.einsum("ij,ij->i", r, d[(1, 1)]), 0.0)
        hvv = np.where(held_v, 1.0, jvv + np.einsum("ij,ij->i", r, d[(0, 2)]))
        det = huu * hvv - huv**2
        bad = (det <= 1e-12 * (huu * hvv + 1e-300)) | (huu <= 0) | (hvv <= 0)
        # Where the full Hessian is not positive definite, fall back to Gauss–Newton (J^T J).
        huu = np.where(bad & ~held_u, juu, huu)
        huv = np.where(bad & free, juv, huv)
        hvv = np.where(bad & ~held_v, jvv, hvv)
        det = huu * hvv - huv**2
        det = np.where(np.abs(det) < 1e-300, 1e-300, det)
        step_u = -(hvv * g[:, 0] - huv * g[:, 1]) / det
        step_v = -(huu * g[:, 1] - huv * g[:, 0]) / det
        current = np.linalg.norm(r, axis=1)
        new_u, new_v, new_d = ua.copy(), va.copy(), current.copy()
        todo = np.flatnonzero(np.abs(step_u) + np.abs(step_v) > 1e-13)
        scale = 1.0
        for _half in range(3):  # full step, then halves, only where the previous try did not help
            if not todo.size:
                break
            rows = active[todo]
            tu = np.clip(ua[todo] + scale * step_u[todo], lo_u[rows], hi_u[rows])
            tv = np.clip(va[todo] + scale * step_v[todo], lo_v[rows], hi_v[rows])
            td = distance(tu, tv, rows)
            better = td < current[todo]
            idx = todo[better]
            new_u[idx], new_v[idx], new_d[idx] = tu[better], tv[better], td[better]
            todo = todo[~better]
            scale *= 0.5
        moved = np.maximum(np.abs(new_u - ua), np.abs(new_v - va))
        u[active], v[active], dist[active] = new_u, new_v, new_d
        active = active[moved >= 1e-10]
    missing = np.flatnonzero(np.isnan(dist))  # only with iterations = 0
    if missing.size:
        dist[missing] = distance(u[missing], v[missing], missing)
    return u, v, dist

def _cases():
    """(knots_u, knots_v, net, degree): a random bicubic net with a triple (C0) knot, a bent sheet with
    C0 lines, a biquadratic net and a bilinear one (no second derivatives), all in parameter units."""
    rng = np.random.default_rng(11)
    ku = np.array([0, 0, 0, 0, 0.2, 0.5, 0.5, 0.5, 0.8, 1, 1, 1, 1.0])
    yield ku, clamped_uniform_knots(6), rng.normal(size=(9, 6, 3)), (3, 3)
    s, t = np.meshgrid([0, 1 / 3, 2 / 3, 1, 4 / 3, 5 / 3, 2], np.linspace(0, 1, 5), indexing="ij")
    bent = np.stack([s, 4.0 * np.maximum(s - 1.0, 0.0) * (1 - t) + 2 * t, 0.3 * s * t + 0.2 * np.sin(3 * s)], -1)
    yield np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2.0]), np.array([0, 0, 0, 0, 0.5, 1, 1, 1, 1.0]), bent, (3, 3)
    yield clamped_uniform_knots(5, degree=2), clamped_uniform_knots(4, degree=2), rng.normal(size=(5, 4, 3)), (2, 2)
    yield clamped_uniform_knots(4, degree=1), clamped_uniform_knots(3, degree=1), rng.normal(size=(4, 3, 3)), (1, 1)


@pytest.mark.parametrize("case", range(4))
@pytest.mark.parametrize("order", [0, 1, 2])
def test_compiled_evaluation_is_bit_for_bit_that_of_numpy(case, order):
    ku, kv, cp, degree = list(_cases())[case]
    rng = np.random.default_rng(case)
    u = np.concatenate([rng.uniform(ku[0] - 0.1, ku[-1] + 0.1, 500), np.unique(ku)])
    v = np.concatenate([rng.uniform(kv[0] - 0.1, kv[-1] + 0.1, 500), np.unique(kv)[:1].repeat(np.unique(ku).size)])
    want = numpy_evaluate_surface(ku, kv, cp, u, v, degree=degree, order=order)
    got = evaluate_surface(ku, kv, cp, u, v, degree=degree, order=order)
    assert sorted(got) == sorted(want)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key])


def numpy_surface_rows(ku, kv, u, v, degree, du, dv):
    """The vectorised design-matrix rows the kernel replaced (as `surface_rows` returns them)."""
    p, q = degree
    su, bu = basis.basis_functions(ku, p, u, derivative=du)
    sv, bv = basis.basis_functions(kv, q, v, derivative=dv)
    n, m = su.size, (p + 1) * (q + 1)
    iu = su[:, None] - p + np.arange(p + 1)[None, :]
    iv = sv[:, None] - q + np.arange(q + 1)[None, :]
    cols = (iu[:, :, None] * (kv.size - q - 1) + iv[:, None, :]).reshape(n, m)
    return cols, (bu[:, :, None] * bv[:, None, :]).reshape(n, m)


@pytest.mark.parametrize("case", range(4))
def test_compiled_design_rows_are_bit_for_bit_those_of_numpy(case):
    ku, kv, _, degree = list(_cases())[case]
    rng = np.random.default_rng(case)
    u = np.concatenate([rng.uniform(ku[0] - 0.1, ku[-1] + 0.1, 500), np.unique(ku), [np.nan]])
    v = np.concatenate([rng.uniform(kv[0] - 0.1, kv[-1] + 0.1, 500), np.unique(kv)[:1].repeat(np.unique(ku).size),
                        [0.5]])
    for du in range(min(degree[0], 2) + 1):
        for dv in range(min(degree[1], 2) + 1):
            want = numpy_surface_rows(ku, kv, u, v, degree, du, dv)
            got = surface_rows(ku, kv, u, v, degree=degree, du=du, dv=dv)
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
    with pytest.raises(ValueError, match="derivative"):
        surface_rows(ku, kv, u, v, degree=degree, du=degree[0] + 1)


@pytest.mark.parametrize("case", range(4))
@pytest.mark.parametrize("iterations", [0, 1, 8, 12])
def test_compiled_feet_are_bit_for_bit_those_of_the_numpy_iteration(case, iterations):
    ku, kv, cp, degree = list(_cases())[case]
    p, q = degree
    rng = np.random.default_rng(case * 100 + iterations)
    n = 400
    lo_u, hi_u, lo_v, hi_v = ku[p], ku[-p - 1], kv[q], kv[-q - 1]
    on = numpy_evaluate_surface(ku, kv, cp, rng.uniform(lo_u, hi_u, n), rng.uniform(lo_v, hi_v, n), degree=degree,
                          order=0)[(0, 0)]
    points = on + rng.normal(scale=0.3, size=(n, 3))
    u, v = rng.uniform(lo_u - 0.1, hi_u + 0.1, n), rng.uniform(lo_v - 0.1, hi_v + 0.1, n)
    u[:4], v[:4] = [lo_u, hi_u, lo_u, 0.5 * (lo_u + hi_u)], [lo_v, hi_v, hi_v, lo_v]  # corners, a border
    # Boxes: the whole domain, and a sub-box per point (as the search piece by piece gives).
    a, b = rng.uniform(lo_u, hi_u, (2, n)), rng.uniform(lo_v, hi_v, (2, n))
    lo = np.where(rng.random((n, 1)) < 0.5, [lo_u, lo_v], np.stack([a.min(0), b.min(0)], -1))
    hi = np.where(lo == [lo_u, lo_v], [hi_u, hi_v], np.stack([a.max(0), b.max(0)], -1))
    want = numpy_newton(ku, kv, cp, points, u, v, lo, hi, degree, iterations)
    got = newton_feet(ku, kv, cp, points, u, v, lo, hi, degree, iterations)
    for w, g in zip(want, got):
        np.testing.assert_array_equal(g, w)


def test_project_points_finds_the_feet_on_a_plane_exactly():
    # S(u, v) = (u, v, 0) on [0, 3] x [0, 2] (a bicubic net at the Greville abscissae): the foot of
    # (x, y, z) inside the domain is (x, y) at distance |z|; outside, the nearest border point.
    ku, kv = clamped_uniform_knots(6) * 3.0, clamped_uniform_knots(5) * 2.0
    gu = np.array([(ku[i + 1] + ku[i + 2] + ku[i + 3]) / 3 for i in range(6)])
    gv = np.array([(kv[i + 1] + kv[i + 2] + kv[i + 3]) / 3 for i in range(5)])
    cp = np.stack([*np.meshgrid(gu, gv, indexing="ij"), np.zeros((6, 5))], -1)
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-1, 4, 300), rng.uniform(-1, 3, 300), rng.normal(size=300)])
    u, v, d = project_points(ku, kv, cp, pts, np.full(300, 1.5), np.full(300, 1.0))
    x, y = np.clip(pts[:, 0], 0, 3), np.clip(pts[:, 1], 0, 2)
    np.testing.assert_allclose(u, x, atol=1e-9)
    np.testing.assert_allclose(v, y, atol=1e-9)
    np.testing.assert_allclose(d, np.linalg.norm(pts - np.column_stack([x, y, 0 * x]), axis=1), atol=1e-9)


def numpy_project_box(s, x: np.ndarray, uv: np.ndarray, lo: np.ndarray, hi: np.ndarray, iterations: int = 12
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The vectorised projected Newton the kernel replaced (s: a BSplineSurface)."""
    uv = np.clip(uv, lo, hi)
    active = np.arange(len(uv))
    for _ in range(iterations):
        if not active.size:
            break
        u, v, xa, la, ha = uv[active, 0], uv[active, 1], x[active], lo[active], hi[active]
        p, su, sv = s.evaluate(u, v), s.evaluate(u, v, du=1), s.evaluate(u, v, dv=1)
        suu, suv, svv = s.evaluate(u, v, du=2), s.evaluate(u, v, du=1, dv=1), s.evaluate(u, v, dv=2)
        d = p - xa
        g = np.stack([np.einsum("ij,ij->i", su, d), np.einsum("ij,ij->i", sv, d)], -1)
        a = np.einsum("ij,ij->i", su, su) + np.einsum("ij,ij->i", suu, d)
        b = np.einsum("ij,ij->i", su, sv) + np.einsum("ij,ij->i", suv, d)
        c = np.einsum("ij,ij->i", sv, sv) + np.einsum("ij,ij->i", svv, d)
        det = a * c - b * b
        bad = (det <= 1e-12 * (a * a + c * c + 1e-300)) | (a <= 0)
        # Where the full Hessian is not positive, fall back to Gauss–Newton (first derivatives only).
        a = np.where(bad, np.einsum("ij,ij->i", su, su), a)
        b = np.where(bad, np.einsum("ij,ij->i", su, sv), b)
        c = np.where(bad, np.einsum("ij,ij->i", sv, sv), c)
        det = np.maximum(a * c - b * b, 1e-300)
        step = -np.stack([c * g[:, 0] - b * g[:, 1], a * g[:, 1] - b * g[:, 0]], -1) / det[:, None]
        # A coordinate pinned at its bound with the gradient pushing out stays there (projected Newton).
        here = uv[active]
        pinned = ((here <= la) & (g > 0)) | ((here >= ha) & (g < 0))
        step = np.where(pinned, 0.0, step)
        one = pinned.any(axis=1)
        if np.any(one):  # 1-D Newton along the free coordinate
            free_u = ~pinned[:, 0]
            step[one] = np.where(free_u[one, None],
                                 np.stack([-g[one, 0] / np.maximum(a[one], 1e-300), np.zeros(one.sum())], -1),
                                 np.stack([np.zeros(one.sum()), -g[one, 1] / np.maximum(c[one], 1e-300)], -1))
            step[pinned] = 0.0
        uv[active] = np.clip(here + step, la, ha)
        active = active[np.max(np.abs(step), axis=1) >= 1e-13]
    return uv, s.evaluate(uv[:, 0], uv[:, 1])


def test_projected_feet_match_the_numpy_iteration_within_round_off():
    # The kernel evaluates by de Boor's recursion, the numpy iteration through SciPy's NdBSpline: the same
    # feet up to round-off, which a few slowly converging points carry further within 12 steps.
    ku, kv, cp, degree = next(_cases())
    s = make_bspline_surface(cp, ku, kv)
    rng = np.random.default_rng(21)
    n = 2000
    uv = rng.uniform(0, 1, (n, 2))
    x = s.evaluate(uv[:, 0], uv[:, 1]) + rng.normal(scale=0.3, size=(n, 3))
    start = rng.uniform(0, 1, (n, 2))
    a, b = rng.uniform(0, 1, (2, n, 2))
    lo = np.where(rng.random((n, 1)) < 0.5, 0.0, np.minimum(a, b))
    hi = np.where(lo == 0.0, 1.0, np.maximum(a, b))
    want, foot = numpy_project_box(s, x, start.copy(), lo, hi)
    got = project_in_boxes(ku, kv, cp, x, start, lo, hi, degree, 12)
    assert np.all((got >= lo) & (got <= hi))
    gap = np.abs(got - want).max(axis=1)
    assert np.quantile(gap, 0.99) < 1e-9 and gap.max() < 1e-5
    d_want = np.linalg.norm(foot - x, axis=1)
    d_got = np.linalg.norm(s.evaluate(got[:, 0], got[:, 1]) - x, axis=1)
    np.testing.assert_allclose(d_got, d_want, rtol=0, atol=1e-6)


def test_projected_feet_on_a_plane_are_exact_and_held_in_their_box():
    # S(u, v) = (3u, 2v, 0) (a bicubic net at the Greville abscissae): the foot of (x, y, z) in the box
    # [0.2, 0.7] x [0.1, 0.9] is (x / 3, y / 2) clipped to the box.
    ku, kv = clamped_uniform_knots(6), clamped_uniform_knots(5)
    gu = np.array([(ku[i + 1] + ku[i + 2] + ku[i + 3]) / 3 for i in range(6)])
    gv = np.array([(kv[i + 1] + kv[i + 2] + kv[i + 3]) / 3 for i in range(5)])
    cp = np.stack([*np.meshgrid(3 * gu, 2 * gv, indexing="ij"), np.zeros((6, 5))], -1)
    rng = np.random.default_rng(5)
    x = np.column_stack([rng.uniform(-1, 4, 400), rng.uniform(-1, 3, 400), rng.normal(size=400)])
    lo, hi = np.tile([0.2, 0.1], (400, 1)), np.tile([0.7, 0.9], (400, 1))
    got = project_in_boxes(ku, kv, cp, x, np.full((400, 2), 0.5), lo, hi, (3, 3), 12)
    np.testing.assert_allclose(got, np.clip(x[:, :2] / [3, 2], lo, hi), atol=1e-12)


def numpy_box_bounds(points, key, lo, hi, starts):
    """`PieceBoxes.distance_bound`'s numpy code before the kernel: piece by piece, gaps to every box."""
    out = np.full(len(points), np.inf)
    for k in np.unique(key):
        blo, bhi = lo[starts[k]:starts[k + 1]], hi[starts[k]:starts[k + 1]]
        if not len(blo):
            continue
        at = np.flatnonzero(key == k)
        x = points[at][:, None, :]
        gap = np.maximum(np.maximum(blo - x, x - bhi), 0.0)
        out[at] = np.sqrt(np.min(np.einsum("kmi,kmi->km", gap, gap), axis=1))
    return out


def test_box_bounds_are_bit_for_bit_those_of_numpy():
    from cam.spline._compiled import box_bounds

    rng = np.random.default_rng(7)
    counts = np.array([5, 0, 40, 1, 17])  # piece 1 has no boxes: its bound is inf
    starts = np.r_[0, np.cumsum(counts)]
    centre = rng.uniform(-20.0, 20.0, (starts[-1], 3))
    half = rng.uniform(0.0, 3.0, (starts[-1], 3))
    lo, hi = centre - half, centre + half
    points = np.vstack([rng.uniform(-30.0, 30.0, (2000, 3)), centre[:50]])  # the last 50 lie inside boxes
    key = rng.integers(0, len(counts), len(points))
    got = box_bounds(points, key, lo, hi, starts)
    np.testing.assert_array_equal(got, numpy_box_bounds(points, key, lo, hi, starts))
    assert np.all(np.isinf(got[key == 1])) and np.isfinite(got[key != 1]).all()


@pytest.mark.parametrize("case", range(4))
def test_window_boxes_are_numpys_min_and_max(case):
    _, _, cp, degree = list(_cases())[case]
    cp = cp.copy()
    cp[1, 1, 0] = np.nan  # numpy's answer for every window holding it
    nets = np.lib.stride_tricks.sliding_window_view(cp, (degree[0] + 1, degree[1] + 1), axis=(0, 1))
    lo, hi = window_boxes(cp, degree)
    np.testing.assert_array_equal(lo, nets.min(axis=(3, 4)))
    np.testing.assert_array_equal(hi, nets.max(axis=(3, 4)))
