"""The grid field's start (cam.reconstruct.prior): the blended tangent-plane distance of oriented points.

Oracles: a sampled plane, whose distance is exact; and a sampled L-shaped solid (two boxes), whose inside is
known exactly, for the sign at its convex and concave edges and corners.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from cam.reconstruct.prior import plane_distance


def test_distance_to_a_sampled_plane_is_exact():
    g = np.arange(-10.0, 10.01, 0.25)
    x, y = np.meshgrid(g, g, indexing="ij")
    points = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    heights = np.array([-3.0, -1.0, -0.1, 0.0, 0.2, 1.5, 4.0])
    queries = np.column_stack([np.full(len(heights), 0.3), np.full(len(heights), -1.1), heights])
    got = plane_distance(queries, points, normals, spacing=0.25, k=16)
    np.testing.assert_allclose(got, heights, rtol=0, atol=1e-12)


def _l_solid() -> trimesh.Trimesh:
    Manifold = pytest.importorskip("manifold3d").Manifold

    m = (Manifold.cube([30.0, 20.0, 8.0]) + Manifold.cube([8.0, 20.0, 24.0])).to_mesh()
    return trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts))


def _inside_l(q: np.ndarray) -> np.ndarray:
    low = (q >= 0.0).all(axis=1)
    return low & (((q <= [30.0, 20.0, 8.0]).all(axis=1)) | ((q <= [8.0, 20.0, 24.0]).all(axis=1)))


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_sign_is_right_beyond_five_spacings_at_edges_and_corners(seed):
    """20,000 noisy samples (sigma 0.05 mm, a quarter of their spacing) with their faces' normals. Weights
    taken on squared distances shrink with the distance (their width in distance is spacing^2 / distance),
    so far out one point's plane decides, and near an edge it is as often the other face's: that gave
    the wrong side up to 7.5 spacings out. Within a few spacings an edge's two planes disagree by right."""
    mesh = _l_solid()
    rng = np.random.default_rng(seed)
    points, face = trimesh.sample.sample_surface(mesh, 20_000, seed=seed)
    points = points + rng.normal(size=points.shape) * 0.05
    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
    queries = rng.uniform([-4.0, -4.0, -4.0], [34.0, 24.0, 28.0], size=(400_000, 3))
    dist, _ = tree.query(queries)
    queries = queries[(dist > 5.0 * spacing) & (dist < 8.0 * spacing)]
    got = plane_distance(queries, points, mesh.face_normals[face], spacing=spacing, k=16, tree=tree)
    wrong = (got < 0.0) != _inside_l(queries)
    assert len(queries) > 20_000
    assert not wrong.any(), f"{int(wrong.sum())} queries on the wrong side, e.g. {queries[wrong][:3].round(2)}"


def _gapped_l_cloud(seed: int, centre: np.ndarray, radius: float, noise: float = 0.05):
    """40,000 samples of the L solid (Gaussian noise of sigma `noise` mm) with their faces' normals, none
    within `radius` of `centre`: random sampling leaves holes of a few spacings, and one beside an edge
    brings the other face's samples nearest to the face with the hole."""
    mesh = _l_solid()
    rng = np.random.default_rng(seed)
    points, face = trimesh.sample.sample_surface(mesh, 40_000, seed=seed)
    points = points + rng.normal(size=points.shape) * noise
    keep = np.linalg.norm(points - centre, axis=1) > radius
    return points[keep], mesh.face_normals[face][keep]


def _signed_distance_l(q: np.ndarray) -> np.ndarray:
    """The L solid's exact signed distance where the nearer box decides inside (true near its end face and
    its inner edge, where the tests ask): outside, the distance to the nearer box; inside, the depth in
    the box that holds the point deepest."""
    return _signed_distance_boxes(q, [((0.0, 0.0, 0.0), (30.0, 20.0, 8.0)), ((0.0, 0.0, 0.0), (8.0, 20.0, 24.0))])


@pytest.mark.parametrize(("centre", "outward", "hole"), [
    ((30.0, 10.0, 7.4), (1.0, 0.0, 0.0), 1.2),   # on the end face, 0.6 mm below its convex top edge
    ((8.6, 10.0, 8.0), (0.0, 0.0, 1.0), 1.2),    # on the low top, 0.6 mm from the concave inner edge
    ((30.0, 1.1, 7.4), (1.0, 0.0, 0.0), 0.5),    # the end face at its convex corner with the top and the side
    ((8.6, 1.1, 8.0), (0.0, 0.0, 1.0), 0.5),     # the low top where the inner edge meets the side
])
def test_a_hole_in_the_samples_beside_an_edge_keeps_its_face(centre, outward, hole):
    """A 1.2 mm hole in the samples of one face beside an edge brings the other face's samples nearest,
    and their planes put the hole's face 0.2-0.35 mm off (the field grew lumps of a mm out of a block's
    corners where such holes lay). The crease rule takes the larger of the two faces' distances at a
    convex edge and the smaller at a concave one, exact for planes, and at a corner of three faces what
    its creases say: within 3 sigma of the noise of the exact distance, 0.25 and 0.5 mm off the face on
    both sides, across the hole (at the corners, a smaller one 0.6-1.6 mm from the side face)."""
    centre, outward = np.asarray(centre), np.asarray(outward)
    points, normals = _gapped_l_cloud(5, centre, hole)
    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
    tangent = np.cross(outward, [0.0, 1.0, 0.0])
    on_face = centre + np.array([a * tangent + [0.0, b, 0.0] for a in (-0.5, 0.0, 0.5) for b in (-0.5, 0.0, 0.5)])
    queries = np.concatenate([on_face + off * outward for off in (-0.5, -0.25, 0.25, 0.5)])
    got = plane_distance(queries, points, normals, spacing=spacing, k=16, tree=tree)
    np.testing.assert_allclose(got, _signed_distance_l(queries), rtol=0, atol=0.15)


@pytest.mark.parametrize("corner", [(30.0, 0.0, 8.0), (0.0, 0.0, 0.0), (30.0, 20.0, 0.0), (0.0, 20.0, 24.0),
                                    (8.0, 0.0, 8.0), (8.0, 20.0, 8.0)])
def test_the_sign_at_corners_beside_a_hole(corner):
    """Exact samples of the L with a 0.7 mm hole within 0.8 mm of each axis of a corner (four convex
    ones, and the two where the concave inner edge meets a side), 4,000 queries within 1.2 mm of it:
    three faces' planes combined by their creases leave no query more than 0.4 mm off the surface on
    the wrong side (their mean left queries 0.44-0.64 mm off on three of the convex corners)."""
    corner = np.asarray(corner)
    rng = np.random.default_rng(1)
    worst = 0.0
    for seed in range(4):
        points, normals = _gapped_l_cloud(seed, corner + rng.uniform(-0.8, 0.8, 3), 0.7, noise=0.0)
        tree = cKDTree(points)
        spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
        queries = corner + rng.uniform(-1.2, 1.2, size=(4000, 3))
        exact = _signed_distance_l(queries)
        got = plane_distance(queries, points, normals, spacing=spacing, k=16, tree=tree)
        wrong = np.sign(got) != np.sign(exact)
        worst = max(worst, float(np.abs(exact[wrong]).max(initial=0.0)))
    assert worst <= 0.4, f"a query {worst:.2f} mm off the surface is on the wrong side"


@pytest.mark.parametrize("edge", [(30.0, 10.0, 8.0), (8.0, 10.0, 8.0), (30.0, 10.0, 0.0), (0.0, 10.0, 24.0)])
@pytest.mark.parametrize("creases", [True, False])
def test_the_sign_across_an_unscanned_band(edge, creases):
    """Exact samples of the L with no sample in an oblique band 3.5 mm wide (28 spacings; 7.5 mm along a
    face it crosses at a slant) across an edge (two convex, the concave inner one, the far top one):
    queries in the band within 3.5 mm of the edge are up to 5.8 mm from any sample, and their 16 nearest
    can all lie on one face, whose plane extended past that face's end across the band put queries 1.8-2.7 mm
    off the surface on the wrong side (a fin out of a convex crease of Fandisk with a band unscanned). Far
    queries blend samples all round them and combine the faces at creases, with or without the crease rule
    near the cloud: none more than 1 mm off the surface on the wrong side (0.69 mm at most)."""
    edge = np.asarray(edge)
    axis = np.array([1.0, 0.45, 0.3]) / np.linalg.norm([1.0, 0.45, 0.3])
    mesh = _l_solid()
    rng = np.random.default_rng(0)
    points, face = trimesh.sample.sample_surface(mesh, 40_000, seed=0)
    keep = np.abs((points - edge) @ axis) > 1.75
    points, normals = points[keep], mesh.face_normals[face][keep]
    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
    queries = edge + rng.uniform(-3.5, 3.5, size=(20_000, 3))
    queries = queries[np.abs((queries - edge) @ axis) < 1.75]
    exact = _signed_distance_l(queries)
    got = plane_distance(queries, points, normals, spacing=spacing, k=16, tree=tree, creases=creases)
    wrong = np.sign(got) != np.sign(exact)
    worst = float(np.abs(exact[wrong]).max(initial=0.0))
    assert worst <= 1.0, f"a query {worst:.2f} mm off the surface is on the wrong side"


@pytest.mark.parametrize("seed", [0, 1])
def test_a_far_query_is_not_misled_by_a_thin_wall_s_other_side(seed):
    """Exact samples of a tray (50 x 40 x 20 mm, walls and floor 2 mm) with a 4 mm band across it unscanned;
    200,000 queries in its box grown by 5 mm, those over six spacings from any sample (145,000): seen from
    afar, a wall's two faces are both among the neighbours, and the outer face's planes put a query in the
    cavity inside the part (blending them filled the cavity: queries 17.6 mm off the surface on the wrong
    side). The far face hidden behind the near one, and faces told apart by their planes as well as their
    normals (the floor and the walls' rims are parallel), none is more than 1 mm off on the wrong side
    (0.75 mm at most, in the band beside the floor's concave edge)."""
    Manifold = pytest.importorskip("manifold3d").Manifold
    solid = Manifold.cube([50.0, 40.0, 20.0]) - Manifold.cube([46.0, 36.0, 20.0]).translate([2.0, 2.0, 2.0])
    solid = solid.to_mesh()
    mesh = trimesh.Trimesh(np.asarray(solid.vert_properties)[:, :3], np.asarray(solid.tri_verts))
    axis = np.array([1.0, 0.45, 0.3]) / np.linalg.norm([1.0, 0.45, 0.3])
    points, face = trimesh.sample.sample_surface(mesh, 40_000, seed=seed)
    keep = np.abs((points - [25.0, 20.0, 10.0]) @ axis) > 2.0
    points, normals = points[keep], mesh.face_normals[face][keep]
    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
    queries = np.random.default_rng(seed).uniform([-5.0, -5.0, -5.0], [55.0, 45.0, 25.0], size=(200_000, 3))
    queries = queries[tree.query(queries)[0] > 6.0 * spacing]
    got = plane_distance(queries, points, normals, spacing=spacing, k=16, tree=tree)
    floor_and_walls = [((0.0, 0.0, 0.0), (50.0, 40.0, 2.0)), ((0.0, 0.0, 0.0), (2.0, 40.0, 20.0)),
                       ((48.0, 0.0, 0.0), (50.0, 40.0, 20.0)), ((0.0, 0.0, 0.0), (50.0, 2.0, 20.0)),
                       ((0.0, 38.0, 0.0), (50.0, 40.0, 20.0))]
    exact = _signed_distance_boxes(queries, floor_and_walls)
    wrong = np.sign(got) != np.sign(exact)
    assert len(queries) > 100_000
    worst = float(np.abs(exact[wrong]).max(initial=0.0))
    assert worst <= 1.0, f"a query {worst:.2f} mm off the surface is on the wrong side"


def _signed_distance_boxes(q: np.ndarray, boxes) -> np.ndarray:
    """A union of boxes' signed distance where the nearer box decides inside: outside, the distance to the
    nearer box; inside, the depth in the box that holds the point deepest. boxes: ((lo xyz), (hi xyz))."""
    lo, hi = (np.array([b[i] for b in boxes]) for i in (0, 1))
    outside = np.min([np.linalg.norm(np.maximum(np.maximum(a - q, q - b), 0.0), axis=1) for a, b in zip(lo, hi)],
                     axis=0)
    depth = np.max([np.where(((q >= a) & (q <= b)).all(axis=1), np.minimum(q - a, b - q).min(axis=1), 0.0)
                    for a, b in zip(lo, hi)], axis=0)
    return np.where(depth > 0.0, -depth, outside)


def test_a_bound_on_the_distance_only_picks_the_queries():
    """A query with a sample within max_distance gets the same value as without the bound (the bound says
    which queries are answered, not which samples count: near its rim it kept one face of an edge and
    dropped the other); the rest get NaN."""
    points, normals = _gapped_l_cloud(6, np.array([30.0, 10.0, 7.4]), 1.2)
    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
    rng = np.random.default_rng(0)
    queries = rng.uniform([-2.0, -2.0, -2.0], [32.0, 22.0, 26.0], size=(20_000, 3))
    bound = 4.0 * spacing
    got = plane_distance(queries, points, normals, spacing=spacing, k=16, tree=tree, max_distance=bound)
    full = plane_distance(queries, points, normals, spacing=spacing, k=16, tree=tree)
    near = tree.query(queries)[0] <= bound
    assert 1000 < near.sum() < len(queries)
    np.testing.assert_array_equal(np.isnan(got), ~near)
    np.testing.assert_array_equal(got[near], full[near])
