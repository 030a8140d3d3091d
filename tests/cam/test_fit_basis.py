"""Basis functions, design matrices, knot operations and closest points of cam.fit against exact answers."""

from __future__ import annotations

import numpy as np
import pytest

from cam.fit.refine import split_spans
from cam.mesh.closest import closest_on_triangles, closest_points, mesh_index
from cam.spline.basis import (
    evaluate_curve,
    evaluate_surface,
    gram_matrix,
    surface_matrix,
    thin_plate_matrix,
)
from cam.spline.knots import (
    insert_knot,
    join_curves,
    merge_knots,
    refine_knots,
    refine_surface,
    reverse_curve,
    split_curve,
    sub_curve,
)
from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

KU = np.array([0, 0, 0, 0, 0.2, 0.5, 0.5, 1, 1, 1, 1.0])


def _surface(rng):
    return make_bspline_surface(rng.normal(size=(7, 5, 3)), KU, clamped_uniform_knots(5))


def test_evaluation_and_design_matrix_match_the_shared_record():
    rng = np.random.default_rng(0)
    s = _surface(rng)
    u, v = rng.uniform(0, 1, 60), rng.uniform(0, 1, 60)
    u[:3], v[:3] = [1.0, 0.5, 0.0], [1.0, 0.0, 0.0]
    ev = evaluate_surface(s.knots_u, s.knots_v, s.control_points, u, v)
    for (du, dv), value in ev.items():
        np.testing.assert_allclose(value, s.evaluate(u, v, du=du, dv=dv), atol=1e-10)
        B = surface_matrix(s.knots_u, s.knots_v, u, v, du=du, dv=dv)
        np.testing.assert_allclose(B @ s.control_points.reshape(-1, 3), value, atol=1e-10)


def test_knot_insertion_and_refinement_leave_the_surface_unchanged():
    rng = np.random.default_rng(1)
    s = _surface(rng)
    ku, kv, cp = refine_surface(s.knots_u, s.knots_v, s.control_points, target_u=merge_knots(KU, [0.3, 0.7, 0.7]),
                                target_v=merge_knots(s.knots_v, [0.25] * 3))
    t = make_bspline_surface(cp, ku, kv)
    u, v = rng.uniform(0, 1, 50), rng.uniform(0, 1, 50)
    np.testing.assert_allclose(t.evaluate(u, v), s.evaluate(u, v), atol=1e-13)
    with pytest.raises(ValueError, match="multiplicity"):
        k = KU
        P = s.control_points[:, 0]
        for _ in range(2):
            k, P = insert_knot(k, P, 0.5)
    with pytest.raises(ValueError, match="does not contain"):
        refine_knots(KU, s.control_points[:, 0], clamped_uniform_knots(7))


def test_split_join_sub_and_reverse_are_exact():
    rng = np.random.default_rng(2)
    P = rng.normal(size=(7, 3))
    t = np.linspace(0, 1, 101)
    full = evaluate_curve(KU, P, t)[0]
    (kl, pl), (kr, pr) = split_curve(KU, P, 0.37)
    np.testing.assert_array_equal(pl[-1], pr[0])
    m = t <= 0.37
    np.testing.assert_allclose(evaluate_curve(kl, pl, t[m])[0], full[m], atol=1e-14)
    np.testing.assert_allclose(evaluate_curve(kr, pr, t[~m])[0], full[~m], atol=1e-14)
    kj, pj = join_curves([(kl, pl), (kr, pr)])
    np.testing.assert_allclose(evaluate_curve(kj, pj, t)[0], full, atol=1e-14)
    ks, ps = sub_curve(KU, P, 0.2, 0.5)
    tt = np.linspace(0.2, 0.5, 17)
    np.testing.assert_allclose(evaluate_curve(ks, ps, tt)[0], evaluate_curve(KU, P, tt)[0], atol=1e-14)
    kb, pb = reverse_curve(KU, P)
    np.testing.assert_allclose(evaluate_curve(kb, pb, 1 - t)[0], full, atol=1e-14)


def test_thin_plate_matrix_is_the_exact_bending_energy():
    # S = (x, y, x^2 + x y) on [0, 2] x [0, 3] mm: S_xx = 2, S_xy = 1, S_yy = 0 -> energy (4 + 2) * 6 = 36.
    ku, kv = clamped_uniform_knots(5), clamped_uniform_knots(4)
    u, v = np.meshgrid(np.linspace(0, 1, 9), np.linspace(0, 1, 9), indexing="ij")
    x, y = 2 * u.ravel(), 3 * v.ravel()
    B = surface_matrix(ku, kv, u.ravel(), v.ravel()).toarray()
    cp = np.linalg.lstsq(B, np.stack([x, y, x**2 + x * y], 1), rcond=None)[0]
    H = thin_plate_matrix(ku, kv, length_u=2.0, length_v=3.0)
    assert float(sum(cp[:, k] @ (H @ cp[:, k]) for k in range(3))) == pytest.approx(36.0, rel=1e-9)
    G = gram_matrix(ku, 3, 0)
    assert G.sum() == pytest.approx(1.0)  # the basis is a partition of unity on [0, 1]


def test_split_spans_halves_only_spans_with_bad_points():
    k = np.array([0, 0, 0, 0, 2, 4, 4, 4, 4.0])
    np.testing.assert_array_equal(split_spans(k, [0.5]), [0, 0, 0, 0, 1, 2, 4, 4, 4, 4])
    np.testing.assert_array_equal(split_spans(k, [0.5], min_span=1.5), k)


def test_closest_points_are_exact_against_brute_force():
    import trimesh

    m = trimesh.creation.icosphere(2)
    V, F = m.vertices * 10, m.faces
    rng = np.random.default_rng(3)
    P = rng.normal(size=(400, 3)) * 8
    q, d, f, b = closest_points(mesh_index(V, F), P)
    best = np.full(len(P), np.inf)
    for tri in V[F]:
        c, _ = closest_on_triangles(P, *(np.broadcast_to(tri[i], P.shape) for i in range(3)))
        best = np.minimum(best, np.linalg.norm(c - P, axis=1))
    np.testing.assert_allclose(d, best, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nk,nkd->nd", b, V[F[f]]), q, atol=1e-12)
    with pytest.raises(ValueError, match="triangle indices"):
        mesh_index(V, F + len(V))


def test_foot_points_cross_a_c0_line():
    # A sheet whose u = 1 iso-line is a C0 line: its v = 0 border runs along x, then turns up
    # at 76 degrees (a border round a corner); its v = 1 border stays straight. Each piece is
    # bilinear, so its net is the map at the Greville abscissae. Points on it must get distance
    # 0 and their own foot, whichever piece Newton starts in, and without a start.
    from cam.fit.foot import distance_to_surface, project_points

    ku = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2.0])
    kv = np.array([0, 0, 0, 0, 1, 1, 1, 1.0])
    S, T = np.meshgrid([0, 1 / 3, 2 / 3, 1, 4 / 3, 5 / 3, 2], [0, 1 / 3, 2 / 3, 1], indexing="ij")
    bottom = 4.0 * np.maximum(S - 1.0, 0.0)
    cp = np.stack([S, bottom * (1 - T) + 2 * T, 0.3 * S * T], -1)
    rng = np.random.default_rng(3)
    u = np.concatenate([rng.uniform(1.0, 1.2, 50), rng.uniform(0.8, 1.0, 50)])
    v = rng.uniform(0.2, 0.8, 100)
    on = evaluate_surface(ku, kv, cp, u, v, order=0)[(0, 0)]
    for start_u in (np.where(u > 1.0, 0.9, 1.1), np.ones(100)):  # in the other piece, on the line
        fu, fv, d = project_points(ku, kv, cp, on, start_u, v)
        assert d.max() < 1e-9
        np.testing.assert_allclose(np.stack([fu, fv], 1), np.stack([u, v], 1), atol=1e-6)
    assert distance_to_surface(ku, kv, cp, on)[2].max() < 1e-9


def _bent_sheet():
    ku = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2.0])
    kv = np.array([0, 0, 0, 0, 0.5, 1, 1, 1, 1.0])
    S, T = np.meshgrid([0, 1 / 3, 2 / 3, 1, 4 / 3, 5 / 3, 2], np.linspace(0, 1, 5), indexing="ij")
    cp = np.stack([S, 4.0 * np.maximum(S - 1.0, 0.0) * (1 - T) + 2 * T, 0.3 * S * T + 0.2 * np.sin(3 * S)], -1)
    return ku, kv, cp


def test_piece_boxes_bound_the_distance_to_the_piece():
    # Against the nearest of 201 x 201 samples of each piece (which is at least the true distance):
    # the bound never exceeds it, it is zero for points on the piece, and it prunes far points.
    from cam.spline.pieces import c0_pieces, make_piece_boxes

    ku, kv, cp = _bent_sheet()
    rng = np.random.default_rng(5)
    on = evaluate_surface(ku, kv, cp, rng.uniform(1, 2, 50), rng.uniform(0, 1, 50), order=0)[(0, 0)]
    pts = np.concatenate([rng.uniform([-0.5, -0.5, -0.5], [2.5, 4.5, 1.0], (300, 3)), on])
    pu, pv = c0_pieces(ku, 3, 0.0, 2.0), c0_pieces(kv, 3, 0.0, 1.0)
    assert pu.tolist() == [0.0, 1.0, 2.0] and pv.tolist() == [0.0, 1.0]
    boxes = make_piece_boxes(ku, kv, cp, pu, pv)
    zero = np.zeros(len(pts), dtype=np.int64)
    for piece in (0, 1):
        u, v = np.meshgrid(np.linspace(piece, piece + 1, 201), np.linspace(0, 1, 201), indexing="ij")
        dense = evaluate_surface(ku, kv, cp, u.ravel(), v.ravel(), order=0)[(0, 0)]
        nearest = np.min(np.linalg.norm(pts[:, None] - dense[None], axis=2), axis=1)
        b = boxes.distance_bound(pts, zero + piece, zero)
        assert np.all(b <= nearest + 1e-12)
        assert np.mean(b > 0.5) > 0.2
    assert np.all(boxes.distance_bound(pts[300:], zero[300:] + 1, zero[300:]) == 0.0)


def test_foot_points_with_the_piece_bound_match_those_without():
    # The bound only skips runs that cannot win: every foot and distance is the same as trying all.
    from cam.fit.foot import _newton
    from cam.spline.pieces import c0_pieces, foot_in_pieces, make_piece_boxes

    ku, kv, cp = _bent_sheet()
    rng = np.random.default_rng(8)
    pts = rng.uniform([-0.2, -0.2, -0.6], [2.2, 4.2, 0.8], (500, 3))
    start = rng.uniform([0, 0], [2, 1], (500, 2))

    def newton(rows, uv, lo, hi):
        fu, fv, d = _newton(ku, kv, cp, pts[rows], uv[:, 0], uv[:, 1], lo, hi, (3, 3), 8)
        return np.stack([fu, fv], -1), d

    pu, pv = c0_pieces(ku, 3, 0.0, 2.0), c0_pieces(kv, 3, 0.0, 1.0)
    full = foot_in_pieces(newton, pu, pv, start)
    boxes = make_piece_boxes(ku, kv, cp, pu, pv)
    pruned = foot_in_pieces(newton, pu, pv, start,
                            lower_bound=lambda rows, iu, iv: boxes.distance_bound(pts[rows], iu, iv))
    np.testing.assert_array_equal(pruned[1], full[1])
    np.testing.assert_array_equal(pruned[0], full[0])


def test_a_foot_on_the_border_of_a_skewed_sheet_is_found():
    # S(u, v) = (u + v, v, 0) on [0, 1]^2, a bicubic net at the Greville abscissae. The point's
    # unconstrained foot has u < 0, so the true foot lies on the border u = 0, at v = 0.15
    # (the closest point of the line (v, v, 0) to (-0.2, 0.5)). The full Newton step leads out
    # through u = 0 from anywhere: clamped, it stops at v = 0.5 unless u is held on its bound.
    from cam.fit.foot import distance_to_surface, project_points

    k = np.array([0, 0, 0, 0, 1, 1, 1, 1.0])
    g = np.array([0, 1 / 3, 2 / 3, 1])
    U, W = np.meshgrid(g, g, indexing="ij")
    cp = np.stack([U + W, W, np.zeros_like(U)], -1)
    p = np.array([[-0.2, 0.5, 0.1]])
    exact = np.sqrt(0.35**2 + 0.35**2 + 0.1**2)
    for start in ((0.5, 0.9), (0.0, 0.9), (1.0, 0.0), (0.3, 0.5)):
        fu, fv, d = project_points(k, k, cp, p, np.array([start[0]]), np.array([start[1]]))
        np.testing.assert_allclose([fu[0], fv[0], d[0]], [0.0, 0.15, exact], atol=1e-9)
    np.testing.assert_allclose(distance_to_surface(k, k, cp, p)[2], [exact], atol=1e-9)


def test_distance_to_a_closed_surface_is_found_on_either_side_of_its_seam():
    # A tube whose v = 0 and v = 1 borders coincide (the control net goes once round a circle of
    # radius 3 and ends where it began), like a patch that wraps round a boss. Points just off
    # it near the seam, on both sides: the grid sample nearest them can sit on the seam's far
    # side, where Newton stops on the border. Oracle: from the nearest of 401 x 2001 surface
    # points, scipy's bounded quasi-Newton (L-BFGS-B) on the squared distance.
    from scipy.optimize import minimize
    from scipy.spatial import cKDTree

    from cam.fit.foot import distance_to_surface

    n = 16
    kv = clamped_uniform_knots(n)
    ku = clamped_uniform_knots(4)
    theta = np.linspace(0.0, 2 * np.pi, n)
    z = np.linspace(0.0, 2.0, 4)
    ring = np.stack([3 * np.cos(theta), 3 * np.sin(theta)], -1)
    cp = np.concatenate([np.broadcast_to(ring, (4, n, 2)), np.broadcast_to(z[:, None, None], (4, n, 1))], -1)
    s = make_bspline_surface(cp, ku, kv)
    rng = np.random.default_rng(11)
    v = np.concatenate([rng.uniform(0.0, 0.01, 40), rng.uniform(0.99, 1.0, 40)])
    u = rng.uniform(0.1, 0.9, 80)
    on = s.evaluate(u, v)
    normal = np.cross(s.evaluate(u, v, du=1), s.evaluate(u, v, dv=1))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    pts = on + rng.uniform(-0.1, 0.1, (80, 1)) * normal
    uu, vv = np.meshgrid(np.linspace(0, 1, 401), np.linspace(0, 1, 2001), indexing="ij")
    dense = s.evaluate(uu.ravel(), vv.ravel())
    nearest = cKDTree(dense).query(pts)[1]
    oracle = np.empty(len(pts))
    for i, (p, j) in enumerate(zip(pts, nearest)):
        res = minimize(lambda x, p=p: float(np.sum((s.evaluate(x[:1], x[1:]) - p) ** 2)), [uu.ravel()[j], vv.ravel()[j]],
                       method="L-BFGS-B", bounds=[(0, 1), (0, 1)], options=dict(ftol=1e-15, gtol=1e-12))
        oracle[i] = np.sqrt(res.fun)
    d = distance_to_surface(s.knots_u, s.knots_v, s.control_points, pts)[2]
    np.testing.assert_allclose(d, oracle, atol=1e-6)


def test_distance_searched_span_by_span_finds_the_nearest_point_of_a_folded_surface():
    # One bicubic span folded over itself along u (its net runs 0, 2, -1, 1) and bent in v: a
    # point has several local minima of the distance. Searched span by span (search_above=0),
    # every distance is the oracle's: scipy's L-BFGS-B from the nearest of 801 x 801 surface points.
    from scipy.optimize import minimize
    from scipy.spatial import cKDTree

    from cam.fit.foot import distance_to_surface

    k = np.array([0, 0, 0, 0, 1, 1, 1, 1.0])
    x = np.array([0.0, 2.0, -1.0, 1.0])
    y = np.array([0.0, 1.0, 2.0, 3.0])
    X, Y = np.meshgrid(x, y, indexing="ij")
    cp = np.stack([X, Y, 0.5 * np.sin(X) + 0.3 * (Y - 1.5) ** 2], -1)
    s = make_bspline_surface(cp, k, k)
    rng = np.random.default_rng(21)
    pts = rng.uniform([-0.2, -0.2, -0.5], [1.2, 3.2, 1.0], (150, 3))
    uu, vv = np.meshgrid(np.linspace(0, 1, 801), np.linspace(0, 1, 801), indexing="ij")
    nearest = cKDTree(s.evaluate(uu.ravel(), vv.ravel())).query(pts)[1]
    oracle = np.empty(len(pts))
    for i, (p, j) in enumerate(zip(pts, nearest)):
        res = minimize(lambda z, p=p: float(np.sum((s.evaluate(z[:1], z[1:]) - p) ** 2)), [uu.ravel()[j], vv.ravel()[j]],
                       method="L-BFGS-B", bounds=[(0, 1), (0, 1)], options=dict(ftol=1e-15, gtol=1e-12))
        oracle[i] = np.sqrt(res.fun)
    d = distance_to_surface(s.knots_u, s.knots_v, s.control_points, pts, search_above=0.0)[2]
    np.testing.assert_allclose(d, oracle, atol=1e-6)


def test_fits_compare_by_their_error_beyond_the_tolerance():
    from cam.fit.solve import SurfaceFit

    def fit(samples, surface):
        d = np.asarray(samples, dtype=np.float64)
        z = np.zeros(d.size)
        return SurfaceFit(np.zeros(8), np.zeros(8), np.zeros((4, 4, 3)), z, z, d, z.astype(bool),
                          np.ones(d.size, dtype=bool), 0, surface_u=np.zeros(len(surface)),
                          surface_v=np.zeros(len(surface)), surface_distance=np.asarray(surface, dtype=np.float64))

    # Both are held 0.1 mm off by a border point; inside, one is within the tolerance of 0.03 mm.
    held = fit([0.05, 0.04, 0.01], [0.1, 0.0])
    better = fit([0.02, 0.01, 0.01], [0.1, 0.0])
    assert held.max_error == better.max_error == 0.1
    assert better.excess(0.03) == pytest.approx((0.07**2) / 2) and held.excess(0.03) == pytest.approx(
        (0.02**2 + 0.01**2) / 3 + (0.07**2) / 2)
    assert better.improves_on(held, 0.03) and not held.improves_on(better, 0.03)
    # Within the tolerance everywhere, the largest distance decides.
    assert fit([0.01], [0.02]).improves_on(fit([0.01], [0.025]), 0.03)
