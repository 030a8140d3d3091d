"""The filter's solves on two processors (`cam.denoise.columns`): bit for bit those of one, the child reaped.

The oracle is the factor's own solves, split as the child splits them (all columns but the last in one call,
the last alone: SuperLU's answer for a column can depend on the columns solved beside it); the whole filter is
compared with its one-process run on a noisy cube, and the child is checked to be gone after the block, after a
normal end and after a cancel.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import trimesh

from cam.denoise.columns import solves_in_two
from cam.denoise.mesh_tgv import denoise_mesh


def _children() -> set[int]:
    """Ids of this process's child processes (from /proc)."""
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == os.getpid() and fields[0] != "Z":
            out.add(int(stat.parent.name))
    return out


def _factors(rng: np.random.Generator):
    """Two SPD systems like the filter's: a grid Laplacian plus a diagonal, of two sizes."""
    out = []
    for n in (30, 45):
        lap = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
        K = (sp.kronsum(lap, lap) + sp.diags(rng.uniform(0.1, 1.0, n * n))).tocsc()
        out.append(spla.splu(K, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}))
    return out


def _split_reference(factor, rhs: np.ndarray) -> np.ndarray:
    """The factor's solve of rhs (n, k): columns 0..k-2 in one call, the last alone (k = 1: one call)."""
    if rhs.shape[1] == 1:
        return factor.solve(rhs)
    return np.column_stack([factor.solve(rhs[:, :-1]), factor.solve(rhs[:, -1])])


pytestmark = pytest.mark.skipif(not Path("/proc").is_dir() or not hasattr(os, "fork"),
                                reason="needs os.fork and /proc to see the child")


@pytest.mark.parametrize("processes", [1, 2])
def test_each_solve_is_the_factors_own_to_the_bit(processes):
    rng = np.random.default_rng(5)
    factors = _factors(rng)
    before = _children()
    with solves_in_two(factors, processes=processes) as solves:
        assert len(_children() - before) == (processes > 1)
        for _ in range(3):
            for factor, solve in zip(factors, solves, strict=True):
                for k in (3, 2, 1):
                    rhs = rng.standard_normal((factor.shape[0], k))
                    got, want = solve(rhs), _split_reference(factor, rhs)
                    assert got.shape == want.shape and np.array_equal(got, want)
                    assert got.flags.f_contiguous == factor.solve(rhs).flags.f_contiguous
                one = rng.standard_normal(factor.shape[0])
                assert np.array_equal(solve(one), factor.solve(one))
    assert _children() == before


def test_the_child_is_reaped_when_the_block_raises():
    factors = _factors(np.random.default_rng(6))
    before = _children()

    class Stop(Exception):
        pass

    with pytest.raises(Stop), solves_in_two(factors, processes=2) as solves:
        solves[0](np.ones((factors[0].shape[0], 3)))
        raise Stop
    assert _children() == before


def test_the_filter_on_two_processors_is_the_one_processor_filter():
    mesh = trimesh.creation.box(extents=(2.0, 1.5, 1.0)).subdivide().subdivide().subdivide()
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rng = np.random.default_rng(7)
    noisy = v + rng.normal(scale=0.03, size=v.shape)
    one = denoise_mesh(noisy, f, processes=1)
    two = denoise_mesh(noisy, f, processes=2)
    assert one.iterations == two.iterations > 1
    assert np.array_equal(one.face_normals, two.face_normals)
    assert np.array_equal(one.vertices, two.vertices)
