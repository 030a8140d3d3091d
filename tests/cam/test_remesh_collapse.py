"""Tests for cam.remesh.collapse: quads removed by merging two opposite corners."""

from __future__ import annotations

import numpy as np
import pytest

from cam.remesh.check import inspect_quad_mesh
from cam.remesh.collapse import collapse_diagonals
from tests.quadshapes import quad_box, quad_grid


def _valence(quads: np.ndarray, n: int) -> np.ndarray:
    sides = np.sort(np.stack([quads, np.roll(quads, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    edges = np.unique(sides, axis=0)
    return np.bincount(edges.ravel(), minlength=n)


def test_the_middle_quad_of_a_grid_collapses_into_a_vertex_of_valence_six():
    gv, gf = quad_grid(3, 3)  # vertex (i, j) is 4 i + j; the middle quad is 4: corners 5, 9, 10, 6
    assert gf[4].tolist() == [5, 9, 10, 6]
    verts, quads = collapse_diagonals(gv, gf, [(4, 5, 10)])
    # one quad and one vertex fewer; the others keep their order, and vertex 10's place is vertex 5's
    assert quads.shape == (8, 4) and verts.shape == (15, 3)
    np.testing.assert_array_equal(verts, np.delete(gv, 10, axis=0))
    renumber = np.r_[np.arange(10), 5, np.arange(10, 15)]  # old id -> new id, 10 -> 5
    np.testing.assert_array_equal(quads, renumber[np.delete(gf, 4, axis=0)])
    # the merged vertex has both corners' other edges, the two corners beside the diagonal lose one each
    valence = _valence(quads, len(verts))
    before = _valence(gf, len(gv))
    assert valence[5] == before[5] + before[10] - 2 == 6
    assert valence[renumber[9]] == before[9] - 1 == 3 and valence[renumber[6]] == before[6] - 1 == 3
    check = inspect_quad_mesh(verts, quads, expected_boundary_loops=1)
    assert check.problems == () and check.euler_characteristic == 1


def test_collapses_on_a_closed_box_keep_it_closed():
    qv, qf = quad_box((4, 4, 4))
    # two quads far apart on the box, each collapsed along one diagonal
    first, second = 5, len(qf) - 6
    collapses = [(first, int(qf[first, 0]), int(qf[first, 2])), (second, int(qf[second, 1]), int(qf[second, 3]))]
    verts, quads = collapse_diagonals(qv, qf, collapses)
    assert len(quads) == len(qf) - 2 and len(verts) == len(qv) - 2
    check = inspect_quad_mesh(verts, quads)
    assert check.problems == () and check.euler_characteristic == 2


def test_bad_collapses_name_what_is_wrong():
    gv, gf = quad_grid(3, 3)
    with pytest.raises(ValueError, match="not opposite corners"):
        collapse_diagonals(gv, gf, [(4, 5, 9)])
    with pytest.raises(ValueError, match="out of range"):
        collapse_diagonals(gv, gf, [(9, 5, 10)])
    with pytest.raises(ValueError, match="collapsed twice"):
        collapse_diagonals(gv, gf, [(4, 5, 10), (4, 9, 6)])
    with pytest.raises(ValueError, match="dropped or kept by another collapse"):
        collapse_diagonals(gv, gf, [(4, 5, 10), (0, 0, 5)])  # 5 is kept by the first and dropped by the second
