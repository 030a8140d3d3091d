"""SetupPart.clear_between: may the ball centre move straight from a to b without cutting the part?

A 10 mm cube with a corner at the origin, standing on the table (z = 0); ball r = 3 mm. Along its top
edge at x = 0, z = 10 the answer is exact: the ball cuts exactly where its centre comes nearer than r.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cam.gcode.setup import Setup
from cam.plan.part import setup_part

R = 3.0


@pytest.fixture(scope="module")
def part():
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((5.0, 5.0, 5.0))
    return setup_part(box.vertices, box.faces, Setup(1, np.eye(3), np.zeros(3)), tool_radius_mm=R)


def _depth_past_edge(a, b, n=100001) -> float:
    """Reference: how deep the ball passes inside the top edge (x = 0, z = 10) along a → b, mm."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    c = np.asarray(a) + t * (np.asarray(b) - np.asarray(a))
    return float(np.max(R - np.hypot(c[:, 0], c[:, 2] - 10.0)))


def test_a_steep_move_past_a_wall_top_is_caught_between_its_ends(part):
    # Both ends are clear and 0.15 mm apart in xy; on the way down, the ball passes 0.018 mm inside the edge.
    a, b = np.array([-2.9, 5.0, 12.5]), np.array([-3.05, 5.0, 8.0])
    assert part.drop(a[None, :2])[0] <= a[2] and part.drop(b[None, :2])[0] <= b[2]
    assert 0.015 < _depth_past_edge(a, b) < 0.02
    assert not part.clear_between(a, b, tol_mm=1e-4)
    assert not part.clear_between(b, a, tol_mm=1e-4)
    # The same move 0.1 mm farther out is clear.
    shift = np.array([-0.1, 0.0, 0.0])
    assert _depth_past_edge(a + shift, b + shift) < 0
    assert part.clear_between(a + shift, b + shift, tol_mm=1e-4)


def test_riding_the_top_face_is_clear_and_dipping_into_it_is_not(part):
    # The ball resting on the top face (its centre exactly r above it) all the way across.
    assert part.clear_between(np.array([2.0, 5.0, 13.0]), np.array([8.0, 3.0, 13.0]), tol_mm=1e-4)
    assert not part.clear_between(np.array([2.0, 5.0, 13.0]), np.array([8.0, 5.0, 12.99]), tol_mm=1e-4)
    # Down beside the wall to the table: clear only while the ball keeps r from the wall and the table.
    assert part.clear_between(np.array([-3.01, 5.0, 14.0]), np.array([-3.01, 5.0, 3.0]), tol_mm=1e-4)
    assert not part.clear_between(np.array([-3.01, 5.0, 14.0]), np.array([-3.01, 5.0, 2.9]), tol_mm=1e-4)
    assert not part.clear_between(np.array([-2.99, 5.0, 14.0]), np.array([-2.99, 5.0, 3.0]), tol_mm=1e-4)


def test_a_piece_whose_triangles_face_inwards_is_still_met_from_above():
    # A mesh from a scan can hold a fold or a piece turned inside out; its top then faces down. The ball
    # must still stop on it: every triangle counts, whatever way it faces.
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((5.0, 5.0, 5.0))
    small = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    small.apply_translation((-8.0, 5.0, 1.0))
    vertices = np.vstack([box.vertices, small.vertices])
    faces = np.vstack([box.faces, small.faces[:, ::-1] + len(box.vertices)])  # the small box inside out
    part = setup_part(vertices, faces, Setup(1, np.eye(3), np.zeros(3)), tool_radius_mm=R)
    np.testing.assert_allclose(part.drop(np.array([[-8.0, 5.0], [-8.5, 4.5]])), [2.0 + R, 2.0 + R])


def test_a_part_made_for_reach_alone_reaches_the_same_and_refuses_closest_points(part):
    # The setup choice asks reach of a dozen candidate axes; a part made without the closest-point index
    # answers it the same, and says so when asked for what needs that index.
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((5.0, 5.0, 5.0))
    lean = setup_part(box.vertices, box.faces, Setup(1, np.eye(3), np.zeros(3)), tool_radius_mm=R, closest=False)
    points, face = trimesh.sample.sample_surface_even(box, 2000, seed=1)
    normals = box.face_normals[face]
    np.testing.assert_array_equal(lean.reaches(points, normals), part.reaches(points, normals))
    assert part.reaches(points, normals).any() and not part.reaches(points, normals).all()
    with pytest.raises(ValueError, match="reach alone"):
        lean.nearest(np.array([[5.0, 5.0, 20.0]]))


def test_reach_and_heights_do_not_depend_on_the_bucket_size():
    # The setup choice scores its candidates with buckets a radius wide (they build faster): the same
    # answers, bit for bit, as the default quarter radius, on a part with a pocket and a slanted face.
    import manifold3d as mf

    solid = mf.Manifold.cube([20.0, 16.0, 10.0]) - mf.Manifold.cube([8.0, 6.0, 6.0]).translate([4.0, 5.0, 5.0])
    solid = solid - mf.Manifold.cube([30.0, 30.0, 30.0]).rotate([0.0, 35.0, 0.0]).translate([14.0, -5.0, 6.0])
    mesh = solid.to_mesh()
    V, F = np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts)
    shape = trimesh.Trimesh(V, F)
    points, face = trimesh.sample.sample_surface_even(shape, 3000, seed=2)
    normals = shape.face_normals[face]
    rng = np.random.default_rng(3)
    xy = rng.uniform([-4.0, -4.0], [24.0, 20.0], (4000, 2))
    setup = Setup(1, np.eye(3), np.zeros(3))
    fine = setup_part(V, F, setup, tool_radius_mm=R, closest=False)
    reaches = fine.reaches(points, normals)
    assert reaches.any() and not reaches.all()
    for cell in (R, 2.5 * R):
        coarse = setup_part(V, F, setup, tool_radius_mm=R, closest=False, cell_mm=cell)
        assert coarse.index.members.size < fine.index.members.size
        np.testing.assert_array_equal(coarse.reaches(points, normals), reaches)
        np.testing.assert_array_equal(coarse.drop(xy), fine.drop(xy))
