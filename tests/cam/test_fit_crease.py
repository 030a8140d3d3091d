"""Crease lines of the triangle mesh and moving points of sharp quad edges onto them."""

from __future__ import annotations

import numpy as np
import trimesh

from cam.fit.crease import edge_keys, snap_points, vertex_positions
from cam.mesh.closest import mesh_index
from cam.mesh.creases import closest_on_creases, mesh_creases


def _box_creases():
    # A 10 x 10 x 10 mm box: its twelve edges are its creases (90 degrees).
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    return mesh_creases(box.vertices, box.faces, angle_deg=40.0)


def test_a_point_snaps_to_the_crease_beside_it():
    cr = _box_creases()
    p = np.array([[0.0, 4.7, 5.0]])  # on the top face, 0.3 mm from its edge y = 5 (which runs along x)
    q, d = closest_on_creases(cr, p)
    np.testing.assert_allclose(q, [[0.0, 5.0, 5.0]], atol=1e-12)
    assert np.isclose(d[0], 0.3, rtol=0, atol=1e-12)
    # Along the same direction as that edge (x) it still snaps, either sense.
    q, d = closest_on_creases(cr, p, directions=np.array([[-1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(q, [[0.0, 5.0, 5.0]], atol=1e-12)


def test_a_point_on_an_edge_running_across_a_crease_is_not_pulled_onto_it():
    cr = _box_creases()
    # On the face x = 5, 0.4 mm below its top edge (which runs along y), on a sharp edge running along z.
    p = np.array([[5.0, 0.0, 4.6]])
    _, d = closest_on_creases(cr, p)
    assert np.isclose(d[0], 0.4)
    _, d = closest_on_creases(cr, p, directions=np.array([[0.0, 0.0, 1.0]]))
    assert np.isclose(d[0], 5.0, rtol=0, atol=1e-12)  # only creases along z count: the vertical edges, 5 mm away
    pts, moved = snap_points(cr, p, np.array([1.0]), directions=np.array([[0.0, 0.0, 1.0]]))
    assert not moved[0] and np.array_equal(pts, p)
    # Without a direction (a corner of the sharp-edge network) it goes as before.
    assert snap_points(cr, p, np.array([1.0]))[1][0]


def test_a_point_past_the_end_of_a_crease_stays_off_it():
    # Two triangles folded by 90 degrees along x in [0, 4]; the crease ends at x = 4. A sharp quad
    # edge that runs on along x past it keeps its points where they are.
    V = np.array([[0, 0, 0], [4, 0, 0], [2, 3, 0], [2, 0, 3]], dtype=np.float64)
    F = np.array([[0, 1, 2], [1, 0, 3]])
    cr = mesh_creases(V, F, angle_deg=40.0)
    p = np.array([[4.5, 0.0, 0.0], [3.5, 0.05, 0.0]])
    x = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    pts, moved = snap_points(cr, p, np.array([1.0, 1.0]), directions=x)
    assert moved.tolist() == [False, True]
    np.testing.assert_allclose(pts, [[4.5, 0.0, 0.0], [3.5, 0.0, 0.0]], atol=1e-12)
    assert snap_points(cr, p[:1], np.array([1.0]))[1][0]  # without the direction it would go to the end


def test_boundary_curve_data_leave_a_vertex_off_the_crease_where_it_is():
    # The curve passes through its vertices; data a crease away from one of them would make it swing.
    from cam.fit.borders import _crease_samples

    V = np.array([[0, 0, 0], [4, 0, 0], [2, 3, 0], [2, 0, 3]], dtype=np.float64)
    F = np.array([[0, 1, 2], [1, 0, 3]])
    cr = mesh_creases(V, F, angle_deg=40.0)
    pts = np.array([[1.0, 0.0, 0.8], [3.0, 0.0, 0.0]])  # the first vertex 0.8 mm up the face y = 0
    q, h = _crease_samples(pts, np.array([5.0, 6.0]), cr, mesh_index(V, F))
    assert h[0] == 5.0 and h[-1] == 6.0
    np.testing.assert_allclose(q[0], pts[0], atol=1e-12)
    np.testing.assert_allclose(q[-1], pts[1], atol=1e-12)
    mid = np.flatnonzero(h == 5.5)[0]
    np.testing.assert_allclose(q[mid], [2.0, 0.0, 0.0], atol=1e-12)  # halfway, the crease takes it


def test_a_vertex_where_a_crease_bends_keeps_off_the_corner_where_it_ends():
    # A roof whose ridge (s = 15) waves in z, so the sharp row turns 31 degrees at its last inner
    # vertex: that vertex counts as a corner, and the crease's end on the border (a crease corner,
    # 2.14 mm away, within the snap radius) is its neighbour's place, not its own. Every vertex
    # of the ridge row lies on the crease already and stays where it is.
    from tests.cam.test_fit_shapes import case

    def roof(s, t):
        return np.stack([s, t, 0.8 * (15.0 - np.abs(s - 15.0)) + 3.0 * np.sin(t / 3.0)], axis=-1)

    V, ids, MV, MF = case(roof, (30, 15), (14, 7), refine=6)
    sharp = np.stack([ids[7, :-1], ids[7, 1:]], 1)
    cr = mesh_creases(MV, MF, angle_deg=40.0)
    assert len(cr.corners) == 2  # the ridge's two ends on the border
    pos = vertex_positions(V, [ids[:8], ids[7:]], mesh_index(MV, MF), sharp=edge_keys(sharp), creases=cr)
    np.testing.assert_allclose(pos[ids[7]], V[ids[7]], atol=1e-12)


def test_crease_data_next_to_a_jump_are_not_held_exact():
    # Crease data 0.1 mm apart that leave one crease for a parallel one 0.3 mm away (a bevelled
    # edge): the two samples either side of the jump, and one more each way, are not data a curve
    # can pass through; the rest are.
    from cam.fit.borders import _near_jumps

    x = 0.1 * np.arange(12)
    q = np.stack([x, np.where(np.arange(12) < 6, 0.0, 0.3), np.zeros(12)], 1)
    np.testing.assert_array_equal(np.flatnonzero(_near_jumps(q)), [4, 5, 6, 7])
    assert not _near_jumps(q[:6]).any()


def test_a_junction_takes_the_crease_corner_a_bend_beside_it_is_nearer_to():
    # The corner of a box (three creases meet at the origin). The quad mesh's junction J of three
    # sharp edges sits 0.55 mm up the y crease; a sharp edge runs from it to B, 0.36 mm along the x
    # crease, where the sharp row bends on along that crease. B is nearer the crease corner, but
    # only J has three sharp edges for the corner's three creases: J goes there, B stays.
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    MV, MF = np.asarray(box.vertices) + 5.0, np.asarray(box.faces)
    V = np.array([[0, 0.55, 0], [0.36, 0, 0], [0, 3, 0], [3, 3, 0], [3, 0, 0], [0, 0.55, 3], [0, 3, 3]], dtype=float)
    J, B, N1, X, C, N2, Z = range(7)
    grids = [np.array([[J, N1], [B, X]]), np.array([[B, X], [C, X]]), np.array([[J, N1], [N2, Z]])]
    sharp = edge_keys(np.array([[J, N1], [J, N2], [J, B], [B, C]]))
    cr = mesh_creases(MV, MF)
    pos = vertex_positions(V, grids, mesh_index(MV, MF), sharp=sharp, creases=cr)
    np.testing.assert_allclose(pos[J], [0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(pos[B], V[B], atol=1e-12)


def test_a_curve_slides_on_the_mesh_off_creases_and_at_jumps_of_its_crease_data():
    from cam.fit.borders import _slide_ranges

    on = np.array([False, True, True])  # vertices at 0, 1, 2, 3: a smooth edge, then two sharp ones
    h = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0])
    exact = np.array([False, False, True, False, True, True, True])  # 1.5 is next to a jump
    assert _slide_ranges(on, np.arange(4.0), h, exact) == [(0.0, 1.0), (1.375, 1.625)]
