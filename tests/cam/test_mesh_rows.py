"""`unique_pairs` against numpy's `unique(axis=0)` (the oracle): the same rows, order and counts."""

from __future__ import annotations

import numpy as np
import pytest

from cam.mesh.rows import unique_pairs


@pytest.mark.parametrize("high", [1, 50, 97_000, 2**40])
def test_unique_pairs_are_numpys(high):
    rng = np.random.default_rng(high % 1000)
    pairs = rng.integers(0, high, size=(5000, 2))
    pairs[1::2] = pairs[::2]  # every pair twice at least
    want, counts = np.unique(pairs, axis=0, return_counts=True)
    got, got_counts = unique_pairs(pairs, return_counts=True)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(got_counts, counts)
    np.testing.assert_array_equal(unique_pairs(pairs), want)


def test_unique_pairs_of_nothing_and_of_a_mesh_closed_or_not():
    assert unique_pairs(np.zeros((0, 2), dtype=np.int64)).shape == (0, 2)
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]])  # a tetrahedron: each edge twice
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = unique_pairs(edges, return_counts=True)
    assert len(unique) == 6 and np.all(counts == 2)
    _, counts = unique_pairs(edges[:-1], return_counts=True)
    assert sorted(counts) == [1] + [2] * 5
