"""Quad patches as vertex grids, and the boundary layout between them (shared segments, curves, T-junctions)."""

from __future__ import annotations

import numpy as np
import pytest

from cam import GeometryError
from cam.fit.boundary import PatchLayoutError, boundary_layout, side_vertices
from cam.fit.grid import PatchGridError, orient_grid, patch_grid
from tests.cam.test_fit_shapes import quads_of


def test_patch_grid_walks_the_faces_from_a_corner_in_quad_order():
    ids = np.arange(5 * 4).reshape(5, 4)  # 4 x 3 quads
    quads = quads_of(ids)
    rng = np.random.default_rng(0)
    faces = rng.permutation(len(quads))
    g = patch_grid(quads, faces, corner=0, rows=4, cols=3)
    # From vertex 0 the quad order goes to ids[1, 0] first: that becomes [1, 0], so g equals ids.
    np.testing.assert_array_equal(g, ids)
    g = patch_grid(quads, faces, corner=int(ids[-1, -1]))
    assert g[0, 0] == ids[-1, -1] and g.shape == (5, 4)
    np.testing.assert_array_equal(orient_grid(quads, ids.T), ids)


def test_patch_grid_rejects_what_is_not_a_grid():
    # A patch that is no grid is the layout's fault, which the user can change: a GeometryError.
    ids = np.arange(4 * 4).reshape(4, 4)
    quads = quads_of(ids)
    with pytest.raises(PatchGridError, match="corner"):
        patch_grid(quads, np.arange(9), corner=int(ids[1, 1]))
    with pytest.raises(PatchGridError, match="rectangular|corner"):
        patch_grid(quads, [0, 1, 2, 3, 6], corner=0)  # an L shape
    with pytest.raises(PatchGridError, match="says 2 x 2"):
        patch_grid(quads, np.arange(9), corner=0, rows=2, cols=2)
    with pytest.raises(PatchGridError, match="face ids"):
        patch_grid(quads, [99])
    with pytest.raises(PatchGridError, match="first cell"):
        orient_grid(quads, ids[1:, :][::-1][[0, 2]])  # its first cell is no quad
    with pytest.raises(PatchGridError, match="in no quad"):
        orient_grid(quads, np.vstack([ids, [99, 99, 99, 99]]))
    with pytest.raises(PatchGridError, match="shape"):
        orient_grid(quads, ids[:1])
    assert issubclass(PatchGridError, GeometryError)
    # Quads of the wrong shape are a caller's bug, not the user's.
    with pytest.raises(ValueError, match="shape") as err:
        patch_grid(quads[:, :3], [0])
    assert not isinstance(err.value, GeometryError)


def test_layout_of_a_t_junction_takes_the_long_side_as_one_curve():
    ids = np.arange(11 * 6).reshape(11, 6)
    a, b, c = ids[0:11, 0:4], ids[0:5, 3:6], ids[4:11, 3:6]
    layout = boundary_layout([a, b, c])
    assert layout.neighbours == [(1, 2), (0, 2), (0, 1)]
    assert layout.side_neighbours[(0, "v1")] == (1, 2)
    pieces = layout.sides[(0, "v1")]
    assert len(pieces) == 2 and pieces[0].curve == pieces[1].curve  # one smooth curve, two neighbours
    host = layout.curves[pieces[0].curve]
    assert (host.host_patch, host.host_side, host.start, host.end) == (0, "v1", 0, 10)
    (pb,) = layout.sides[(1, "v0")]
    (pc,) = layout.sides[(2, "v0")]
    assert (pb.curve, pb.host, pb.side) == (pieces[0].curve, (0, 4), (0, 4))
    assert (pc.curve, pc.host, pc.side) == (pieces[0].curve, (4, 10), (0, 6))
    assert len(layout.shared) == 3


def test_layout_follows_reversed_neighbours_and_refuses_non_manifold_borders():
    ids = np.arange(5 * 3).reshape(5, 3)
    a, b = ids[0:3], ids[2:5][::-1, ::-1]  # b runs the other way round
    layout = boundary_layout([a, b])
    (seg,) = layout.shared
    assert seg.reversed
    assert np.array_equal(side_vertices(a, seg.a[1]), side_vertices(b, seg.b[1])[::-1])
    with pytest.raises(PatchLayoutError, match="at most two"):
        boundary_layout([a, ids[2:5], ids[2:5][::-1]])
    assert issubclass(PatchLayoutError, GeometryError)
