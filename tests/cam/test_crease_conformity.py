"""Crease recall and quads straddling a crease, at 0.2 % of the diagonal: exact answers on a cube and a roof."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cam.remesh.creases import measure_crease_conformity
from tests.quadshapes import quad_box, quad_grid

SIDE = 12.0
TOL = 0.002 * SIDE * np.sqrt(3.0)  # 0.2 % of the cube's diagonal


def _cube_triangles(scale: float = 1.0):
    """The cube [0, 12]³ (× scale) in 12 triangles: its 12 edges are the creases, one triangle edge each."""
    mesh = trimesh.creation.box((SIDE * scale,) * 3)
    mesh.apply_translation([SIDE * scale / 2] * 3)
    return mesh.vertices, mesh.faces


def _cube_quads(shift: float = 0.0, scale: float = 1.0):
    """4 × 4 quads of 3 mm per side; with ``shift``, the three inner vertices of the edge y = 0, z = 12 are
    moved ``shift`` mm onto the top face, so the front face's top row of quads runs up onto the top face."""
    qv, qf = quad_box((4, 4, 4), size=(SIDE,) * 3)
    on_edge = (qv[:, 1] == 0) & (qv[:, 2] == SIDE) & (qv[:, 0] > 0) & (qv[:, 0] < SIDE)
    assert on_edge.sum() == 3
    qv[on_edge, 1] = shift
    return qv * scale, qf


def _front_top_row(qv, qf):
    """The four quads of the front face's top row: two vertices at y = 0, z = 9, two at z = 12."""
    corners = qv[qf]
    below = (corners[..., 1] == 0.0) & (corners[..., 2] == 9.0)
    return np.flatnonzero((below.sum(axis=1) == 2) & ((corners[..., 2] == SIDE).sum(axis=1) == 2))


def test_a_cube_with_quads_on_its_edges_has_recall_one_and_no_straddling_quad():
    tv, tf = _cube_triangles()
    qv, qf = _cube_quads()
    got = measure_crease_conformity(qv, qf, tv, tf)
    assert got.crease_length_mm == 12 * SIDE
    assert got.recall == 1.0 and got.followed_length_mm == got.crease_length_mm
    assert got.straddling.tolist() == []
    assert got.tolerance_mm == pytest.approx(TOL, rel=1e-15)
    assert got.as_dict() == {"crease_recall": 1.0, "crease_recall_length_mm": 144.0, "crease_recall_followed_mm": 144.0,
                             "crease_recall_tolerance_mm": got.tolerance_mm, "crease_recall_angle_deg": 50.0,
                             "straddling_quads": 0}


def test_quads_over_a_missed_edge_straddle_it_and_its_length_is_not_followed():
    tv, tf = _cube_triangles()
    qv, qf = _cube_quads(shift=2.0)
    got = measure_crease_conformity(qv, qf, tv, tf)
    # The edge's quad edges now run 2 mm from it (parallel) or end there at atan(2/3) = 33.7° to it, over the
    # 30° limit: none of its 12 mm is followed; the other 11 edges are.
    assert got.followed_length_mm == 11 * SIDE
    assert got.recall == 11 / 12
    # The front face's top row has two corners on the front face and two on the top face (or on the corner).
    assert got.straddling.tolist() == sorted(_front_top_row(qv, qf).tolist())
    assert len(got.straddling) == 4


def test_end_edges_within_the_turn_limit_follow_the_edge_near_the_corners():
    tv, tf = _cube_triangles()
    qv, qf = _cube_quads(shift=1.0)
    got = measure_crease_conformity(qv, qf, tv, tf)
    # The quad edges from the two cube corners to the moved vertices run at atan(1/3) = 18.4° to the edge:
    # a point x mm from the corner is x / √10 from such an edge, so √10·tol of the edge is followed at each end.
    assert got.followed_length_mm == pytest.approx(11 * SIDE + 2 * np.sqrt(10) * TOL, rel=1e-12)
    assert len(got.straddling) == 4


@pytest.mark.parametrize(("shift_in_tol", "straddling"), [(0.9, 0), (1.1, 4)])
def test_the_tolerance_is_a_fixed_share_of_the_diagonal(shift_in_tol, straddling):
    # The same layout and the same answers at ten times the size: the tolerance scales with the part, not
    # with the quads.
    for scale in (1.0, 10.0):
        tv, tf = _cube_triangles(scale)
        shift = shift_in_tol * TOL
        qv, qf = _cube_quads(shift=shift, scale=scale)
        got = measure_crease_conformity(qv, qf, tv, tf)
        assert got.tolerance_mm == pytest.approx(TOL * scale, rel=1e-15)
        assert len(got.straddling) == straddling
        if shift_in_tol < 1:
            assert got.recall == 1.0
        else:
            # Parallel quad edges 1.1·tol away do not follow; the end edges, at a slope shift/3 mm per mm,
            # follow the first tol·√(9 + shift²)/shift mm from each corner.
            ends = 2 * TOL * np.sqrt(9 + shift**2) / shift
            assert got.followed_length_mm == pytest.approx((11 * SIDE + ends) * scale, rel=1e-12)


def _roof(x, y):
    """A roof whose ridge is the line y = 5, slopes 0.05: its crease turns by 2·atan(0.05) ≈ 5.7°."""
    return -0.05 * np.abs(y - 5.0)


def _roof_meshes(turn_deg: float | None = None):
    """The roof in triangles over [0, 10]², and quads of 1 mm: over the same square (``turn_deg`` None), or
    over a 20 mm square round its centre turned by ``turn_deg``."""
    tv, tf = quad_grid(10, 10, size=(10.0, 10.0))
    tv[:, 2] = _roof(tv[:, 0], tv[:, 1])
    if turn_deg is None:
        qv, qf = quad_grid(10, 10, size=(10.0, 10.0))
    else:
        qv, qf = quad_grid(20, 20, size=(20.0, 20.0))
        c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
        qv[:, :2] = (qv[:, :2] - 10.0) @ np.array([[c, s], [-s, c]]) + [5.0, 5.0]
    qv[:, 2] = _roof(qv[:, 0], qv[:, 1])
    return qv, qf, tv, np.vstack([tf[:, [0, 1, 2]], tf[:, [0, 2, 3]]])


def test_quad_edges_that_cross_a_ridge_do_not_follow_it():
    qv, qf, tv, tf = _roof_meshes(turn_deg=45.0)
    got = measure_crease_conformity(qv, qf, tv, tf, crease_angle_deg=5.0)
    assert got.crease_length_mm == pytest.approx(10.0, rel=1e-12)
    assert got.recall == 0.0


def test_a_ridge_followed_to_halfway_is_followed_to_halfway_plus_the_tolerance():
    qv, qf, tv, tf = _roof_meshes()
    # Pull the row on the ridge 1 mm off it from x = 6 mm on: the edge from x = 5 to 6 then runs at 45°, so
    # the ridge is followed from x = 0 to 5 and, within the ball of tol round the vertex at x = 5, to 5 + tol.
    moved = (np.abs(qv[:, 1] - 5.0) < 1e-9) & (qv[:, 0] > 5.5)
    qv[moved, 1] += 1.0
    qv[:, 2] = _roof(qv[:, 0], qv[:, 1])
    got = measure_crease_conformity(qv, qf, tv, tf, crease_angle_deg=5.0)
    tol = 0.002 * float(np.linalg.norm(np.ptp(tv, axis=0)))
    assert got.followed_length_mm == pytest.approx(5.0 + tol, rel=1e-12)
    # From x = 5 to 10 the five quads below the moved row have corners at y = 4 and y = 6 (or on the ridge, at
    # x = 5): on both sides of it.
    assert len(got.straddling) == 5
    assert np.ptp(qv[qf[got.straddling]][..., 1], axis=1).tolist() == [2.0] * 5


def test_no_creases_and_bad_inputs():
    v, f = quad_grid(4, 4, size=(4.0, 4.0))
    tri = np.vstack([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
    got = measure_crease_conformity(v, f, v, tri)
    assert got.recall is None and got.crease_length_mm == 0.0 and got.straddling.tolist() == []
    with pytest.raises(ValueError, match=r"quads \(m, 4\)"):
        measure_crease_conformity(v, tri, v, tri)
    with pytest.raises(ValueError, match="tolerance_ratio > 0; got 50.0, 30.0, 0"):
        measure_crease_conformity(v, f, v, tri, tolerance_ratio=0)
    with pytest.raises(ValueError, match="quads index vertices 1..25 of 25"):
        measure_crease_conformity(v, f + 1, v, tri)
    with pytest.raises(ValueError, match="zero extent"):
        measure_crease_conformity(v, f, np.zeros_like(v), tri)
