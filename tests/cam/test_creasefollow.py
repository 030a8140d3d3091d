"""How much of a triangle mesh's creases a quad mesh's edges follow: exact answers on a box and a roof."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cam.remesh.creases import measure_crease_following
from tests.quadshapes import quad_box, quad_grid


def test_a_box_remeshed_on_its_own_edges_follows_every_crease():
    tri = trimesh.creation.box((40.0, 30.0, 20.0)).subdivide()
    qv, qf = quad_box((8, 6, 4), size=(40.0, 30.0, 20.0), origin=(-20.0, -15.0, -10.0))
    got = measure_crease_following(qv, qf, tri.vertices, tri.faces)
    assert got.crease_length_mm == pytest.approx(4 * (40 + 30 + 20), rel=1e-12)
    assert got.missed_length_mm == 0.0
    assert got.tolerance_mm == pytest.approx(0.5, rel=1e-12)  # a tenth of the 5 mm quad edges


def _roof(x, y):
    """A roof whose ridge is the line y = 5, slopes 0.05: its crease turns by 2·atan(0.05) ≈ 5.7°."""
    return -0.05 * np.abs(y - 5.0)


def _roof_triangles():
    v, f = quad_grid(10, 10, size=(10.0, 10.0))
    v[:, 2] = _roof(v[:, 0], v[:, 1])
    return v, np.vstack([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])


def _roof_quads(shift_y: float = 0.0, turn_deg: float = 0.0):
    v, f = quad_grid(20, 20, size=(20.0, 20.0))
    v[:, :2] -= 10.0
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    v[:, :2] = v[:, :2] @ np.array([[c, s], [-s, c]]) + [5.0, 5.0 + shift_y]
    v[:, 2] = _roof(v[:, 0], v[:, 1])
    return v, f


@pytest.mark.parametrize(("shift_y", "turn_deg", "missed_mm"), [
    (0.0, 0.0, 0.0),     # a row of quad edges on the ridge
    (0.5, 0.0, 10.0),    # rows half a quad beside it: only crossing edges reach it
    (0.0, 45.0, 10.0),   # every quad edge crosses it at 45°
    (0.0, 90.0, 0.0),    # turned a quarter: rows along it again
])
def test_a_ridge_is_followed_only_by_edges_along_it(shift_y, turn_deg, missed_mm):
    tv, tf = _roof_triangles()
    qv, qf = _roof_quads(shift_y, turn_deg)
    got = measure_crease_following(qv, qf, tv, tf, crease_angle_deg=5.0)
    assert got.crease_length_mm == pytest.approx(10.0, rel=1e-12)
    assert got.missed_length_mm == pytest.approx(missed_mm, abs=1e-12)


def test_a_ridge_followed_along_part_of_its_length():
    tv, tf = _roof_triangles()
    qv, qf = _roof_quads()
    # Pull the row on the ridge 1 mm off it from x = 6 mm on: the edge from x = 5 to 6 then runs at 45°,
    # so the ridge is missed from x = 5 mm on, 5 of its 10 mm.
    moved = (np.abs(qv[:, 1] - 5.0) < 1e-9) & (qv[:, 0] > 5.5)
    qv[moved, 1] += 1.0
    qv[:, 2] = _roof(qv[:, 0], qv[:, 1])
    got = measure_crease_following(qv, qf, tv, tf, crease_angle_deg=5.0)
    assert got.missed_length_mm == pytest.approx(5.0, abs=1e-12)


def test_no_creases_and_bad_inputs():
    v, f = quad_grid(4, 4, size=(4.0, 4.0))
    tri = np.vstack([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
    got = measure_crease_following(v, f, v, tri)
    assert (got.crease_length_mm, got.missed_length_mm) == (0.0, 0.0)
    with pytest.raises(ValueError, match=r"quads \(m, 4\)"):
        measure_crease_following(v, tri, v, tri)
    with pytest.raises(ValueError, match="crease_angle_deg"):
        measure_crease_following(v, f, v, tri, crease_angle_deg=0.0)
