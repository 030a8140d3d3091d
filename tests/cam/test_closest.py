"""The compiled closest-point search against a plain reference: every piece of the mesh tested with
`closest_on_triangles` (numpy), the documented tie rule applied to all of them at once. Bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from cam.mesh.closest import TIE_MM, closest_on_triangles, closest_points, mesh_index  # noqa: E402


def _reference(index, P):
    """Per point: the nearest piece; among those within TIE_MM of it, the nearest face centroid, then the lower
    face index, then the lower piece index."""
    c = index.piece_corners
    out = (np.empty((len(P), 3)), np.empty(len(P)), np.empty(len(P), dtype=np.int64), np.empty((len(P), 3)))
    for i, p in enumerate(P):
        pp = np.broadcast_to(p, (len(c), 3))
        q, bary = closest_on_triangles(pp, c[:, 0], c[:, 1], c[:, 2])
        d = np.linalg.norm(q - pp, axis=1)
        face = index.piece_face
        centre = np.linalg.norm(index.centroids[face] - pp, axis=1)
        tied = np.nonzero(d <= d.min() + TIE_MM)[0]
        k = tied[np.lexsort((tied, face[tied], centre[tied]))[0]]
        out[0][i], out[1][i], out[2][i] = q[k], d[k], face[k]
        out[3][i] = np.einsum("ij,ijk->ik", bary[k:k + 1], index.piece_bary[k:k + 1])[0]
    return out


def _queries(V, F, rng, n, spread):
    tri = rng.integers(0, len(F), n)
    w = rng.dirichlet([1.0, 1.0, 1.0], n)
    P = np.einsum("ij,ijk->ik", w, V[F[tri]]) + rng.normal(0.0, spread, (n, 3))
    P[: n // 5] = V[F[tri[: n // 5], 0]]  # on vertices: exact ties between the triangles around them
    P[n // 5: 2 * n // 5] = 0.5 * (V[F[tri[n // 5: 2 * n // 5], 0]] + V[F[tri[n // 5: 2 * n // 5], 1]])
    return P


@pytest.mark.parametrize("shape", ["sphere", "cad"])
def test_closest_points_equal_the_reference_bit_for_bit(shape):
    rng = np.random.default_rng(7)
    if shape == "sphere":
        m = trimesh.creation.icosphere(3, radius=10.0)
    else:
        # Whole-face triangles beside fine ones: the large ones are cut into pieces in the index.
        m = trimesh.util.concatenate([trimesh.creation.box([40.0, 30.0, 10.0]),
                                      trimesh.creation.icosphere(2, radius=4.0)])
    V, F = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
    index = mesh_index(V, F)
    P = np.vstack([_queries(V, F, rng, 400, 0.5), rng.uniform(-200.0, 200.0, (40, 3))])  # and far away
    got, want = closest_points(index, P), _reference(index, P)
    for name, a, b in zip(("closest", "distance", "triangle", "barycentric"), got, want):
        np.testing.assert_array_equal(a, b, err_msg=name)
    if shape == "cad":
        assert len(index.piece_face) > len(F)  # the test did meet cut pieces


def test_closest_points_refuses_points_that_are_not_finite():
    index = mesh_index(np.eye(3), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="finite"):
        closest_points(index, np.array([[0.0, np.nan, 0.0]]))
