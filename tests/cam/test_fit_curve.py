"""Boundary curves: exact junctions, and no loops where the data zig-zag."""

from __future__ import annotations

import numpy as np

from cam.fit.curve import fit_curve, turns_back
from cam.spline.knots import lattice_knots

ENDS = [(0.0, np.zeros(3)), (10.0, np.array([10.0, 0.0, 0.0]))]


def test_a_line_is_reproduced_through_its_ends():
    t = np.linspace(0, 10, 41)
    P = np.stack([t, 0.5 * t, np.zeros_like(t)], 1)
    ends = [(0.0, P[0]), (10.0, P[-1])]
    fit = fit_curve(P, t, knots=lattice_knots(0, 10, 2.0), constraints=ends, length_mm=11.2, tolerance_mm=1e-6)
    assert fit.max_error < 1e-6 and not turns_back(fit.knots, fit.control_points)


def test_zig_zag_data_do_not_make_the_curve_turn_back():
    # Points on a line whose parameters disagree with their order (a crease snapped to both sides).
    t = np.linspace(0, 10, 81)
    P = np.stack([t + 0.6 * (-1.0) ** np.arange(81), np.zeros_like(t), np.zeros_like(t)], 1)
    knots = lattice_knots(0, 10, 0.25)
    fit = fit_curve(P, t, knots=knots, constraints=ENDS, length_mm=10.0, tolerance_mm=0.01, max_refinements=0,
                    smoothing_mm2=1e-8)
    assert not turns_back(fit.knots, fit.control_points)
    # The ends stay exact whatever the smoothing became.
    from cam.spline.basis import evaluate_curve

    ends = evaluate_curve(fit.knots, fit.control_points, np.array([0.0, 10.0]))[0]
    np.testing.assert_allclose(ends, [[0, 0, 0], [10, 0, 0]], atol=1e-9)


def test_turns_back_sees_a_loop():
    knots = np.array([0, 0, 0, 0, 1, 1, 1, 1], dtype=float)
    assert turns_back(knots, np.array([[0, 0, 0], [3, 0, 0], [-1, 0, 0], [2, 0, 0]], dtype=float))
    assert not turns_back(knots, np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], dtype=float))


def test_data_off_the_surface_are_replaced_at_their_own_parameter():
    # The curve must run along the x axis, C(t) = (t, 0, 0). A stretch of its data swung off it
    # and forward (a patch fit's border past its samples); their closest points on the axis
    # would sit 0.8 ahead of where their parameters say, out of order with their neighbours.
    t = np.linspace(0, 10, 41)
    P = np.stack([t, np.zeros_like(t), np.zeros_like(t)], 1)
    off = (t > 6) & (t < 8)
    P[off] += [0.8, 1.0, 0.0]

    def closest(q):
        feet = q * [1.0, 0.0, 0.0]
        off = q - feet
        return feet, off / np.maximum(np.linalg.norm(off, axis=1), 1e-300)[:, None]

    def on_axis(s):
        return np.stack([s, np.zeros_like(s), np.zeros_like(s)], 1)

    fit = fit_curve(P, t, knots=lattice_knots(0, 10, 2.0), constraints=ENDS, length_mm=10.0, tolerance_mm=1e-6,
                    closest=closest, project=on_axis)
    from cam.spline.basis import evaluate_curve

    s = np.linspace(0, 10, 201)
    np.testing.assert_allclose(evaluate_curve(fit.knots, fit.control_points, s)[0], on_axis(s), atol=1e-6)
    assert fit.max_error < 1e-6


def test_two_borders_apart_on_a_cylinder_are_averaged_on_it():
    # Two patches' own borders, both on a cylinder of radius 5 about the x axis, 0.1 rad apart
    # either side of the seam: their mean lies 0.025 mm inside. Refining the knots cannot fix that
    # (the data are on the surface); holding the curve on the surface can, and by symmetry it
    # runs along the seam.
    radius, tol = 5.0, 0.005
    t = np.linspace(0, 10, 41)
    P = np.concatenate([np.stack([t, radius * np.cos(a) * np.ones_like(t), radius * np.sin(a) * np.ones_like(t)], 1)
                        for a in (0.1, -0.1)])
    h = np.concatenate([t, t])
    ends = [(0.0, np.array([0.0, radius, 0.0])), (10.0, np.array([10.0, radius, 0.0]))]

    def closest(q):
        r = np.hypot(q[:, 1], q[:, 2])[:, None]
        feet = np.concatenate([q[:, :1], radius * q[:, 1:] / r], 1)
        normal = np.concatenate([np.zeros((len(q), 1)), q[:, 1:] / r], 1)
        return feet, normal

    from cam.spline.basis import evaluate_curve

    kw = dict(knots=lattice_knots(0, 10, 2.0), constraints=ends, length_mm=10.0, tolerance_mm=tol, closest=closest)
    assert fit_curve(P, h, surface_weight=0.0, **kw).max_error > 0.02
    fit = fit_curve(P, h, **kw)
    s = np.linspace(0, 10, 401)
    C = evaluate_curve(fit.knots, fit.control_points, s)[0]
    assert fit.max_error <= tol
    assert np.abs(np.hypot(C[:, 1], C[:, 2]) - radius).max() <= tol
    np.testing.assert_allclose(C[:, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(C[:, 0], s, atol=1e-6)


def test_a_curve_along_a_crease_follows_it_not_just_the_faces_beside_it():
    # A crease that is a polygon in the plane z = 0 (a quarter circle of radius 10 in 6 chords, the
    # way a mesh creases a round edge), and a mesh that is that plane: a curve cutting the polygon's
    # corners is on the mesh everywhere, 0.068 mm off the crease. Given which data are the crease,
    # the curve's distance from them counts, and refinement brings it within.
    from cam.spline.basis import evaluate_curve

    n, tol = 6, 0.05
    a = np.linspace(0, np.pi / 2, n + 1)
    corners = np.stack([10 * np.cos(a), 10 * np.sin(a), np.zeros_like(a)], 1)
    t = np.arange(8 * n + 1) / 8
    i = np.minimum(np.floor(t).astype(int), n - 1)
    P = corners[i] + (t - i)[:, None] * (corners[i + 1] - corners[i])

    def closest(q):
        return q * [1.0, 1.0, 0.0], np.tile([0.0, 0.0, 1.0], (len(q), 1))

    kw = dict(knots=lattice_knots(0, n, 2.0), constraints=[(0.0, corners[0]), (float(n), corners[-1])],
              length_mm=15.7, tolerance_mm=tol, closest=closest)
    for exact, within in ((None, False), (np.ones(len(P), dtype=bool), True)):
        fit = fit_curve(P, t, exact=exact, **kw)
        miss = np.linalg.norm(evaluate_curve(fit.knots, fit.control_points, t)[0] - P, axis=1).max()
        assert bool(miss <= tol) == within
        # Without them the curve reports itself within while it misses the crease; with them, honestly.
        assert fit.max_error >= miss if exact is not None else fit.max_error <= tol < miss
