"""ride_over: a feed link between two passes that rides over the part where the straight move would cut.

A 10 mm cube with a corner at the origin on the table; ball r = 3 mm. A link from above the top face to
beside the wall x = 0 must roll over the top edge (x = 0, z = 10): in the plane y = 5 its shortest clear
path is the top face, a quarter circle of radius r round the edge and the wall, 3 + 3π/2 + 4 mm long.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cam.gcode.setup import Setup
from cam.plan.lines import GOUGE_TOL_MM, ride_over
from cam.plan.part import setup_part

R = 3.0
A = np.array([3.0, 5.0, 13.0])  # ball centre on the top face
B = np.array([-3.001, 5.0, 6.0])  # ball centre beside the wall x = 0 (1 µm off it), 4 mm below its top
OVER_THE_EDGE = 3.0 + 1.5 * np.pi + 4.0


@pytest.fixture(scope="module")
def part():
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((5.0, 5.0, 5.0))
    return setup_part(box.vertices, box.faces, Setup(1, np.eye(3), np.zeros(3)), tool_radius_mm=R)


def _length(a, pts) -> float:
    return float(np.linalg.norm(np.diff(np.vstack([a, pts]), axis=0), axis=1).sum())


def test_a_link_over_an_edge_rolls_round_it_and_cuts_nothing(part):
    assert not part.clear_between(A, B, tol_mm=GOUGE_TOL_MM)  # the straight move cuts the edge
    ride = ride_over(part, A, B, budget_mm=OVER_THE_EDGE + 1.0)
    assert ride is not None and np.allclose(ride[-1], B)
    path = np.vstack([A, ride])
    assert part.clear_moves(path[:-1], path[1:], tol_mm=GOUGE_TOL_MM).all()
    # Exact: no centre over the top face lower than r above it, none beside the wall nearer the edge than r,
    # and no longer than the shortest clear path.
    beside = path[:, 0] < 0.0
    assert np.all(path[~beside, 2] >= 13.0 - 2 * GOUGE_TOL_MM)
    assert np.all(np.hypot(path[beside, 0], np.maximum(path[beside, 2] - 10.0, 0.0)) >= R - 2 * GOUGE_TOL_MM)
    assert _length(A, ride) == pytest.approx(OVER_THE_EDGE + 0.001, abs=0.005)


def test_a_link_longer_than_its_budget_is_refused(part):
    assert ride_over(part, A, B, budget_mm=OVER_THE_EDGE - 0.5) is None


def test_a_clear_straight_move_stays_straight(part):
    a, b = np.array([2.0, 3.0, 13.0]), np.array([8.0, 7.0, 13.0])  # across the top face
    ride = ride_over(part, a, b, budget_mm=100.0)
    assert ride is not None and np.allclose(ride[-1], b)
    assert _length(a, ride) == pytest.approx(float(np.linalg.norm(b - a)), rel=1e-9)
