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
