"""Links of whole-part programs against the part: where a lift leaves the part, and rapids that keep the margin."""

from __future__ import annotations

import numpy as np
import pytest

manifold3d = pytest.importorskip("manifold3d")

from cam.gcode.moves import FEED, PLUNGE, RAPID
from cam.gcode.setup import Setup
from cam.params import ToolpathParams
from cam.plan.link_part import link_setup
from cam.plan.part import setup_part

R = 3.0


@pytest.fixture(scope="module")
def box_part():
    # 30 x 30 x 20 mm, top at z = 10, standing on the table at z = -10.
    m = manifold3d.Manifold.cube([30.0, 30.0, 20.0], center=True).to_mesh()
    vertices = np.asarray(m.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(m.tri_verts, dtype=np.int64)
    return setup_part(vertices, faces, Setup(1, np.eye(3), np.zeros(3)), tool_radius_mm=R)


def _line(a, b, n=20) -> np.ndarray:
    return np.asarray(a, float) + np.linspace(0.0, 1.0, n)[:, None] * (np.asarray(b, float) - np.asarray(a, float))


def _feed_after(moves, tip: np.ndarray) -> float:
    """Feed length from the move that reaches `tip` to the next rapid."""
    k = int(np.argmin(np.linalg.norm(moves.points - tip, axis=1)))
    length, here = 0.0, moves.points[k]
    for p, kind in zip(moves.points[k + 1:], moves.kind[k + 1:]):
        if kind == RAPID:
            return length
        length += float(np.linalg.norm(p - here))
        here = p
    return length


def _clearance(part, moves, *, rapid: bool = True) -> float:
    """Least distance (mm) from the ball to the part on any rapid (or any feed) move, sampled every 0.05 mm."""
    centres, here = [], None
    for p, kind in zip(moves.points, moves.kind):
        if (kind == RAPID) == rapid and here is not None:
            n = max(int(np.ceil(np.linalg.norm(p - here) / 0.05)), 1)
            centres.append(_line(here, p, n + 1))
        here = p
    c = np.vstack(centres) + np.array([0.0, 0.0, R])
    return float(part.nearest(c)[0].min() - R)


def test_beside_a_wall_a_lift_leaves_along_the_wall_normal_not_up_the_wall(box_part):
    tp = ToolpathParams()
    # Two waterline-like passes low on opposite walls (ball centre r off the wall, 5 mm above the table).
    east = _line([15.0 + R, -10.0, -8.0], [15.0 + R, 0.0, -8.0])
    west = _line([-15.0 - R, 0.0, -8.0], [-15.0 - R, 10.0, -8.0])
    moves = link_setup(box_part, [east, west], tp, top_z=10.0)
    # Straight up would feed 18.5 mm up the wall to its top; off the wall it is retract_mm, then rapid.
    assert _feed_after(moves, east[-1]) == pytest.approx(tp.retract_mm, abs=1e-9)
    assert _clearance(box_part, moves) >= tp.rapid_margin_mm - 1e-6
    # The way onto the next pass is the same, reversed, at the plunge feed.
    k = int(np.argmin(np.linalg.norm(moves.points - west[0], axis=1)))
    assert moves.kind[k] == PLUNGE and moves.kind[k - 1] == RAPID
    assert np.linalg.norm(moves.points[k - 1] - west[0]) == pytest.approx(tp.retract_mm, abs=1e-9)
    # Nothing the tool feeds along cuts the part.
    assert _clearance(box_part, moves, rapid=False) >= -1e-9


def test_on_a_floor_a_lift_goes_straight_up_by_the_retract(box_part):
    tp = ToolpathParams()
    a = _line([-10.0, -5.0, 10.0], [10.0, -5.0, 10.0])
    b = _line([10.0, 8.0, 10.0], [-10.0, 8.0, 10.0])
    moves = link_setup(box_part, [a, b], tp, top_z=10.0)
    k = int(np.argmin(np.linalg.norm(moves.points - a[-1], axis=1)))
    assert moves.kind[k + 1] == FEED and moves.kind[k + 2] == RAPID
    np.testing.assert_allclose(moves.points[k + 1], a[-1] + [0.0, 0.0, tp.retract_mm], atol=1e-12)
    assert _clearance(box_part, moves) >= tp.rapid_margin_mm - 1e-6
