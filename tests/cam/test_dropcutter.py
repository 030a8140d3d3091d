"""Ball drop-cutter on a mesh: exact answers on a box and a sphere, and never below a dense sampling of the part."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from cam.mesh.dropcutter import drop_ball, drop_index


def test_box_facet_edge_corner_and_outside():
    box = trimesh.creation.box(extents=(20, 10, 6))  # top at z = 3, x in [-10, 10], y in [-5, 5]
    index = drop_index(box.vertices, box.faces, radius_mm=3.0, closed=True)
    xy = np.array([[0, 0], [9, 4], [11, 0], [12.9, 0], [13.1, 0], [11.5, 5.5]])
    z, contact = drop_ball(index, xy, contact=True)
    want = [6.0, 6.0, 3 + np.sqrt(8.0), 3 + np.sqrt(9 - 2.9 ** 2), -np.inf, 3 + np.sqrt(9 - 1.5 ** 2 - 0.5 ** 2)]
    assert z == pytest.approx(want, abs=1e-12)
    assert contact[2] == pytest.approx([10.0, 0.0, 3.0]) and contact[5] == pytest.approx([10.0, 5.0, 3.0])
    assert np.isnan(contact[4]).all()


def test_sphere_is_met_where_the_offset_sphere_is_and_never_above_it():
    R, r = 10.0, 3.0
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=R)
    q = np.random.default_rng(0).uniform(-12, 12, (4000, 2))
    rho = np.hypot(q[:, 0], q[:, 1])
    on = rho < 12.5
    exact = np.sqrt((R + r) ** 2 - rho[on] ** 2)
    for closed in (False, True):
        z, contact = drop_ball(drop_index(sphere.vertices, sphere.faces, radius_mm=r, closed=closed), q, contact=True)
        # The mesh is inscribed in the sphere: at most its sag (R (1 - cos(edge / 2R)) < 0.01 mm) lower.
        assert np.all(z[on] <= exact + 1e-9) and np.all(z[on] >= exact - 0.01)
        centre = np.column_stack([q[on], z[on]])
        assert np.linalg.norm(centre - contact[on], axis=1) == pytest.approx(r, abs=1e-9)


def test_exact_heights_are_never_below_a_dense_sampling_of_the_part():
    # A tilted ring: sloped facets, outer and inner walls, edges of every direction.
    part = trimesh.creation.annulus(r_min=2.0, r_max=8.0, height=4.0)
    part.apply_transform(trimesh.transformations.rotation_matrix(0.4, [1.0, 0.3, 0.0]))
    r = 2.0
    rng = np.random.default_rng(1)
    q = rng.uniform(-9, 9, (1500, 2))
    z = drop_ball(drop_index(part.vertices, part.faces, radius_mm=r, closed=True), q)
    points, _ = trimesh.sample.sample_surface_even(part, 200_000, seed=1)
    points = np.vstack([points, part.vertices])
    ref = np.full(len(q), -np.inf)
    for i, near in enumerate(cKDTree(points[:, :2]).query_ball_point(q, r)):
        if near:
            d2 = ((points[near, :2] - q[i]) ** 2).sum(axis=1)
            ref[i] = (points[near, 2] + np.sqrt(np.maximum(r * r - d2, 0.0))).max()
    assert np.array_equal(np.isfinite(z), np.isfinite(ref))
    fin = np.isfinite(ref)
    # Every sampled point is a valid lower bound; 200k samples leave at most a few hundredths of a mm.
    assert np.all(z[fin] >= ref[fin] - 1e-9) and np.max(z[fin] - ref[fin]) < 0.06


def test_a_ball_set_at_the_height_clears_the_part():
    # Where the ball stops, its distance to the part is the radius: no triangle is closer.
    from cam.mesh.closest import closest_points, mesh_index

    part = trimesh.creation.annulus(r_min=2.0, r_max=8.0, height=4.0)
    part.apply_transform(trimesh.transformations.rotation_matrix(0.7, [0.2, 1.0, 0.0]))
    q = np.random.default_rng(2).uniform(-9, 9, (800, 2))
    z = drop_ball(drop_index(part.vertices, part.faces, radius_mm=1.5, closed=True), q)
    fin = np.isfinite(z)
    _, dist, _ = closest_points(mesh_index(part.vertices, part.faces), np.column_stack([q[fin], z[fin]]))[:3]
    assert dist == pytest.approx(1.5, abs=1e-9)


def test_buckets_list_every_box_in_every_cell_it_meets_in_box_order():
    # Against a plain double loop over the boxes: cell c holds exactly the boxes whose ranges contain it.
    from cam.mesh._dropkernel import bucket_boxes

    rng = np.random.default_rng(3)
    shape = (7, 5)
    i0, j0 = rng.integers(0, 7, 60), rng.integers(0, 5, 60)
    i1, j1 = np.minimum(i0 + rng.integers(0, 3, 60), 6), np.minimum(j0 + rng.integers(0, 4, 60), 4)
    starts, members = bucket_boxes(i0, j0, i1, j1, shape)
    for c in range(shape[0] * shape[1]):
        i, j = divmod(c, shape[1])
        want = [t for t in range(60) if i0[t] <= i <= i1[t] and j0[t] <= j <= j1[t]]
        assert members[starts[c]:starts[c + 1]].tolist() == want
    assert starts[-1] == members.size == int(((i1 - i0 + 1) * (j1 - j0 + 1)).sum())


def test_ball_clears_answers_what_the_drop_height_answers():
    # A bumpy closed part: random limits around the drop heights, some exactly at them, and points off the part.
    from cam.mesh.dropcutter import ball_clears

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    rng = np.random.default_rng(12)
    vertices = mesh.vertices * (1 + 0.1 * rng.random((len(mesh.vertices), 1)))
    index = drop_index(vertices, mesh.faces, radius_mm=2.0)
    xy = rng.uniform(-14, 14, (4000, 2))
    height = drop_ball(index, xy)
    limit = np.where(np.isfinite(height), height, 0.0) + rng.choice([-0.5, -1e-9, 0.0, 1e-9, 0.5], size=4000)
    clear = ball_clears(index, xy, limit)
    np.testing.assert_array_equal(clear, height <= limit)
    assert 0.2 < clear.mean() < 0.8


def test_the_clear_queries_buckets_hold_each_cells_triangles_highest_first():
    # `ball_clears` stops a query at the first triangle of its cell too low to reach the limit: the second
    # bucketing must hold the same triangles per cell as the first, highest first.
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    rng = np.random.default_rng(5)
    index = drop_index(mesh.vertices * (1 + 0.1 * rng.random((len(mesh.vertices), 1))), mesh.faces, radius_mm=2.0)
    assert index.by_top.size == index.members.size
    for c in range(len(index.starts) - 1):
        cell = slice(index.starts[c], index.starts[c + 1])
        assert sorted(index.by_top[cell].tolist()) == index.members[cell].tolist()
        assert np.all(np.diff(index.top[index.by_top[cell]]) <= 0)


def test_an_index_for_heights_alone_gives_the_same_heights_and_refuses_clear_queries():
    from cam.mesh.dropcutter import ball_clears

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    full = drop_index(mesh.vertices, mesh.faces, radius_mm=2.0)
    lean = drop_index(mesh.vertices, mesh.faces, radius_mm=2.0, cell_mm=2.0, clears=False)
    xy = np.random.default_rng(8).uniform(-13, 13, (3000, 2))
    np.testing.assert_array_equal(drop_ball(lean, xy), drop_ball(full, xy))
    assert lean.by_top is None
    with pytest.raises(ValueError, match="drop heights alone"):
        ball_clears(lean, xy, np.zeros(len(xy)))
