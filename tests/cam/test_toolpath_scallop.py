"""Exact scallop relations against brute-force circle geometry and the paper's approximation."""

from __future__ import annotations

import numpy as np
import pytest

from cam.plan.scallop import (
    approximate_spacing,
    arc_gap,
    fits_concave,
    flat_spacing,
    half_chord,
    scallop_from_arc_gap,
    scallop_from_half_chord,
)

R_TOOL = 3.0


def brute_scallop(a: float, r: float, kappa: float) -> float:
    """Cusp of two ball circles 2a apart, by plain 2D circle intersection about the curvature centre."""
    if abs(kappa) < 1e-6:
        return r - np.sqrt(r * r - a * a)
    big = 1 / abs(kappa)
    rc = big + r if kappa > 0 else big - r
    phi = np.arcsin(a / rc)
    root = np.sqrt(r * r - (rc * np.sin(phi)) ** 2)
    if kappa > 0:  # the surface is the circle of radius big; the cusp is the intersection nearer the centre
        return float(rc * np.cos(phi) - root - big)
    return float(big - (rc * np.cos(phi) + root))


@pytest.mark.parametrize("kappa", [0.0, 1 / 20, -1 / 20, 1 / 4, -1 / 4, -1 / 3.5, 1e-9])
@pytest.mark.parametrize("h", [0.02, 0.16, 0.5])
def test_half_chord_inverts_and_matches_circles(kappa, h):
    a = float(half_chord(h, R_TOOL, kappa))
    assert scallop_from_half_chord(a, R_TOOL, kappa) == pytest.approx(h, rel=1e-12)
    assert brute_scallop(a, R_TOOL, kappa) == pytest.approx(h, rel=1e-8)
    w = arc_gap(h, R_TOOL, kappa)
    assert scallop_from_arc_gap(w, R_TOOL, kappa) == pytest.approx(h, rel=1e-10)


def test_flat_relation_and_curvature_order():
    h = 0.16
    assert flat_spacing(h, R_TOOL) == pytest.approx(2 * np.sqrt(2 * R_TOOL * h - h * h))
    assert 2 * half_chord(h, R_TOOL, 0.0) == pytest.approx(flat_spacing(h, R_TOOL))
    # On the surface, bulges need closer passes and hollows allow wider ones (w ≈ √(8hrR/(R ± r)));
    # the ball centres, on the offset circle, go the other way.
    assert arc_gap(h, R_TOOL, 0.05) < arc_gap(h, R_TOOL, 0.0) < arc_gap(h, R_TOOL, -0.05)
    assert half_chord(h, R_TOOL, 0.05) > half_chord(h, R_TOOL, 0.0) > half_chord(h, R_TOOL, -0.05)


def test_approximation_overshoots_the_target():
    # At h/r = 1/60 the usual √(8rh) spacing leaves more than h; the exact one does not.
    r, h = 3.0, 0.05
    for kappa in (0.0, 0.1, -0.1):
        over = scallop_from_half_chord(approximate_spacing(h, r, kappa) / 2 * (1 + r * kappa) if kappa else
                                       approximate_spacing(h, r, kappa) / 2, r, kappa)
        assert over > h
    assert scallop_from_arc_gap(approximate_spacing(h, r, 0.0), r, 0.0) / h - 1 == pytest.approx(0.0084, abs=5e-4)


def test_tool_too_large_for_hollow():
    assert not fits_concave(-1 / 2.5, R_TOOL)
    assert fits_concave(-1 / 3.5, R_TOOL)
    assert np.isnan(half_chord(0.16, R_TOOL, -1 / 2.5))
    with pytest.raises(ValueError, match="scallop heights"):
        half_chord(0.0, R_TOOL, 0.0)


def test_a_hollow_barely_wider_than_the_ball_takes_any_spacing_up_to_its_centre_circle():
    # R = 3.07 mm, r = 3 mm: the centres lie on a circle of radius 0.07 mm and no two balls on it
    # leave 0.144 mm (the deepest cusp, balls on opposite ends, is the brute-force value below).
    k = -1 / 3.07
    a = float(half_chord(0.144, R_TOOL, k))
    assert a == pytest.approx(0.07, rel=1e-12)
    deepest = float(scallop_from_half_chord(a, R_TOOL, k))
    # The brute force is taken a hair inside the circle (at its edge arcsin's argument may round past 1),
    # where the cusp moves with the square root of that hair: 1e-12 of a moves it by about 1e-6.
    assert deepest == pytest.approx(brute_scallop(0.07 * (1 - 1e-12), R_TOOL, k), rel=1e-5) and deepest < 0.144
    assert scallop_from_arc_gap(arc_gap(0.144, R_TOOL, k), R_TOOL, k) == pytest.approx(deepest, rel=1e-9)
    # Past the centre circle's diameter the section model does not hold: no value is made up there.
    assert np.isnan(scallop_from_half_chord(0.08, R_TOOL, k))
