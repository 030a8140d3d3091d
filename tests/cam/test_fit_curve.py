"""Boundary curves: exact junctions, and no loops where the data zig-zag."""

from __future__ import annotations

import numpy as np

from cam.fit.curve import fit_curve, turns_back
from cam.fit.knots import lattice_knots

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
    from cam.fit.basis import evaluate_curve

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

    def deviation(q):
        return np.hypot(q[:, 1], q[:, 2])

    def on_axis(s):
        return np.stack([s, np.zeros_like(s), np.zeros_like(s)], 1)

    fit = fit_curve(P, t, knots=lattice_knots(0, 10, 2.0), constraints=ENDS, length_mm=10.0, tolerance_mm=1e-6,
                    deviation=deviation, project=on_axis)
    from cam.fit.basis import evaluate_curve

    s = np.linspace(0, 10, 201)
    np.testing.assert_allclose(evaluate_curve(fit.knots, fit.control_points, s)[0], on_axis(s), atol=1e-6)
    assert fit.max_error < 1e-6
