"""B-spline surfaces against plain reference code and exact answers."""

from __future__ import annotations

import numpy as np
import pytest

from cam.spline.surface import (
    clamped_uniform_knots,
    make_bspline_surface,
    surface_from_json,
)


def _basis(knots, degree, i, t):
    """Cox–de Boor, written out for the test (the right end belongs to the last span)."""
    if degree == 0:
        last = knots[i + 1] == knots[-1] and knots[i] < knots[i + 1]
        return float(knots[i] <= t < knots[i + 1] or (last and t == knots[-1]))
    out = 0.0
    if knots[i + degree] > knots[i]:
        out += (t - knots[i]) / (knots[i + degree] - knots[i]) * _basis(knots, degree - 1, i, t)
    if knots[i + degree + 1] > knots[i + 1]:
        out += (knots[i + degree + 1] - t) / (knots[i + degree + 1] - knots[i + 1]) * _basis(knots, degree - 1, i + 1, t)
    return out


def test_matches_cox_de_boor():
    rng = np.random.default_rng(1)
    cp = rng.normal(size=(6, 5, 3))
    ku, kv = clamped_uniform_knots(6), np.array([0, 0, 0, 0, 0.3, 1, 1, 1, 1.0])
    s = make_bspline_surface(cp, ku, kv)
    for u, v in rng.uniform(0, 1, size=(20, 2)).tolist() + [[0.0, 0.0], [1.0, 1.0], [1.0, 0.3]]:
        ref = sum(_basis(ku, 3, i, u) * _basis(kv, 3, j, v) * cp[i, j] for i in range(6) for j in range(5))
        np.testing.assert_allclose(s.evaluate(np.array(u), np.array(v)), ref, atol=1e-12)


def test_bilinear_plane_has_exact_points_derivatives_and_normals():
    # Degree (1, 1) through the corners of a 10 x 20 mm rectangle: S(u, v) = (10u, 20v, 0).
    cp = np.array([[[0, 0, 0], [0, 20, 0]], [[10, 0, 0], [10, 20, 0]]], float)
    s = make_bspline_surface(cp, [0, 0, 1, 1], [0, 0, 1, 1], degree=(1, 1))
    u, v = np.meshgrid(np.linspace(0, 1, 7), np.linspace(0, 1, 5))
    np.testing.assert_allclose(s.evaluate(u, v), np.stack([10 * u, 20 * v, 0 * u], -1), atol=1e-12)
    np.testing.assert_allclose(s.evaluate(u, v, du=1), np.broadcast_to([10, 0, 0], u.shape + (3,)), atol=1e-12)
    np.testing.assert_allclose(s.normals(u, v), np.broadcast_to([0, 0, 1], u.shape + (3,)), atol=1e-12)


def test_cubic_reproduces_a_polynomial_and_its_second_derivative():
    # Control points of the cubic Bernstein form of z = u^3 on one span (degree 3, 4 points).
    ku = kv = np.array([0, 0, 0, 0, 1, 1, 1, 1.0])
    gu, gv = np.meshgrid(np.arange(4) / 3, np.arange(4) / 3, indexing="ij")
    z = np.zeros((4, 4))
    z[3, :] = 1.0  # Bernstein coefficients of u^3 are (0, 0, 0, 1)
    s = make_bspline_surface(np.stack([gu, gv, z], -1), ku, kv)
    u = np.linspace(0, 1, 11)
    v = np.full_like(u, 0.4)
    np.testing.assert_allclose(s.evaluate(u, v)[:, 2], u**3, atol=1e-12)
    np.testing.assert_allclose(s.evaluate(u, v, du=2)[:, 2], 6 * u, atol=1e-10)


def test_json_round_trip_and_validation():
    cp = np.random.default_rng(0).normal(size=(4, 4, 3))
    s = make_bspline_surface(cp, clamped_uniform_knots(4), clamped_uniform_knots(4))
    t = surface_from_json(s.to_json())
    np.testing.assert_array_equal(t.control_points, s.control_points)
    with pytest.raises(ValueError, match="shape"):
        make_bspline_surface(cp[..., :2], clamped_uniform_knots(4), clamped_uniform_knots(4))
    with pytest.raises(ValueError, match="clamped"):
        make_bspline_surface(cp, [0, 0, 0, 0.1, 0.9, 1, 1, 1], clamped_uniform_knots(4))
    with pytest.raises(ValueError, match="NaN"):
        make_bspline_surface(np.full((4, 4, 3), np.nan), clamped_uniform_knots(4), clamped_uniform_knots(4))
    with pytest.raises(ValueError, match="needs 8 values"):
        make_bspline_surface(cp, clamped_uniform_knots(5), clamped_uniform_knots(4))
