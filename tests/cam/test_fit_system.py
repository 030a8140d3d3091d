"""The normal equations of the squared-distance step against a plain dense assembly and solve."""

from __future__ import annotations

import numpy as np
import pytest

import cam.fit.system as system_module
from cam.fit._gramkernel import accumulate_grams, band_slot
from cam.fit.system import NormalEquations, _thin_plate_band
from cam.spline.basis import surface_matrix, surface_rows, thin_plate_matrix
from cam.spline.surface import clamped_uniform_knots

KU = np.array([0, 0, 0, 0, 0.2, 0.5, 0.5, 0.5, 0.8, 1, 1, 1, 1.0])  # a C0 line at 0.5
KV = clamped_uniform_knots(6)


def _row_sets(rng, n=300):
    """Two row sets: points with three directions each, and S_u rows with one."""
    sets = []
    for du in (0, 1):
        u, v = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
        terms = [(e / np.linalg.norm(e, axis=1)[:, None], rng.uniform(0, 2, n), rng.normal(size=n))
                 for e in rng.normal(size=(3 - 2 * du, n, 3))]
        sets.append(((u, v, du), terms))
    return sets


def _dense_solution(sets, fixed, lam, cp, damping, knots=(KU, KV)):
    """min Σ w (e · S - t)² + lam c·H3c over the free points, assembled and solved densely."""
    ku, kv = knots
    ncp = fixed.size
    M, rhs = np.zeros((3 * ncp, 3 * ncp)), np.zeros(3 * ncp)
    for (u, v, du), terms in sets:
        B = surface_matrix(ku, kv, u, v, du=du).toarray()
        for i in range(3):
            rhs[i * ncp:(i + 1) * ncp] += B.T @ sum(w * e[:, i] * t for e, w, t in terms)
            for j in range(3):
                M[i * ncp:(i + 1) * ncp, j * ncp:(j + 1) * ncp] += B.T @ (
                    sum(w * e[:, i] * e[:, j] for e, w, _ in terms)[:, None] * B)
    H = thin_plate_matrix(ku, kv, length_u=30.0, length_v=20.0).toarray()
    for i in range(3):
        M[i * ncp:(i + 1) * ncp, i * ncp:(i + 1) * ncp] += lam * H
    c = cp.reshape(-1, 3).T.ravel()
    free = np.concatenate([np.flatnonzero(~fixed.ravel()) + k * ncp for k in range(3)])
    held = np.setdiff1d(np.arange(3 * ncp), free)
    A, r = M[np.ix_(free, free)], rhs[free] - M[np.ix_(free, held)] @ c[held]
    if damping:
        d = damping * np.maximum(np.diag(A), 1e-3 * np.diag(A).mean())
        A, r = A + np.diag(d), r + d * c[free]
    out = c.copy()
    out[free] = np.linalg.solve(A, r)
    return out.reshape(3, -1).T.reshape(cp.shape)


@pytest.mark.parametrize("border_fixed", [False, True])
@pytest.mark.parametrize("damping", [0.0, 0.3])
@pytest.mark.parametrize("knots", [(KU, KV), (KV, KU)], ids=["more-u", "more-v"])
def test_solution_matches_the_dense_normal_equations(border_fixed, damping, knots):
    # Both ways round: the band order runs along the net's shorter side, whichever that is.
    ku, kv = knots
    rng = np.random.default_rng(4)
    nu, nv = ku.size - 4, kv.size - 4
    fixed = np.zeros((nu, nv), dtype=bool)
    if border_fixed:
        fixed[0], fixed[:, -1] = True, True
    cp = rng.normal(size=(nu, nv, 3))
    sets = _row_sets(rng)
    rows = [(surface_rows(ku, kv, u, v, du=du), terms) for (u, v, du), terms in sets]
    system = NormalEquations(ku, kv, fixed, lengths_mm=(30.0, 20.0), degree=(3, 3))
    got = system.solve(rows, 0.05, cp, damping)
    want = _dense_solution(sets, fixed, 0.05, cp, damping, knots)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
    np.testing.assert_array_equal(got[fixed], cp[fixed])


def test_one_gram_serves_steps_of_any_smoothing_and_damping():
    # fit_surface takes a folded step again from the same fit with the Gram blocks of the last: each solve
    # from them must be the one the rows themselves give, and leave them as it found them.
    rng = np.random.default_rng(5)
    nu, nv = KU.size - 4, KV.size - 4
    fixed = np.zeros((nu, nv), dtype=bool)
    fixed[0] = True
    cp = rng.normal(size=(nu, nv, 3))
    rows = [(surface_rows(KU, KV, u, v, du=du), terms) for (u, v, du), terms in _row_sets(rng)]
    system = NormalEquations(KU, KV, fixed, lengths_mm=(30.0, 20.0), degree=(3, 3))
    gram = system.gram(rows)
    kept = [a.copy() for a in gram]
    for lam, damping in ((0.05, 0.0), (0.005, 1.0), (0.005, 10.0)):
        np.testing.assert_array_equal(system.solve_gram(gram, lam, cp, damping), system.solve(rows, lam, cp, damping))
    for a, b in zip(gram, kept):
        np.testing.assert_array_equal(a, b)


def test_the_thin_plate_band_holds_the_thin_plate_matrix_to_the_bit():
    # Built straight into band storage from the one-dimensional Gram matrices, with the sparse products' own
    # operations: every entry as `thin_plate_matrix` has it, nothing outside the basis functions' overlap.
    nu, nv = KU.size - 4, KV.size - 4
    band = _thin_plate_band(KU, KV, (nu, nv), (3, 3), (30.0, 20.0))
    H = thin_plate_matrix(KU, KV, length_u=30.0, length_v=20.0).toarray()
    want = np.zeros_like(band)
    for c in range(nu * nv):
        for c2 in range(nu * nv):
            di, dj = c2 // nv - c // nv, c2 % nv - c % nv
            if abs(di) <= 3 and abs(dj) <= 3:
                want[c, int(band_slot(di, dj, (3, 3)))] = H[c, c2]
            else:
                assert H[c, c2] == 0.0
    np.testing.assert_array_equal(band, want)


def test_a_matrix_the_banded_factor_refuses_is_solved_by_the_sparse_fallback(monkeypatch):
    rng = np.random.default_rng(6)
    nu, nv = KU.size - 4, KV.size - 4
    fixed = np.zeros((nu, nv), dtype=bool)
    fixed[:, 0] = True
    cp = rng.normal(size=(nu, nv, 3))
    sets = _row_sets(rng)
    rows = [(surface_rows(KU, KV, u, v, du=du), terms) for (u, v, du), terms in sets]
    system = NormalEquations(KU, KV, fixed, lengths_mm=(30.0, 20.0), degree=(3, 3))

    def refuse(*args, **kwargs):
        raise np.linalg.LinAlgError("not positive definite")

    monkeypatch.setattr(system_module, "cholesky_banded", refuse)
    got = system.solve(rows, 0.05, cp)
    want = _dense_solution(sets, fixed, 0.05, cp, 0.0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())


def test_a_control_point_nothing_reaches_keeps_its_value():
    # Rows only on u < 0.2 and no bending: the control points whose functions live on u > 0.5 see
    # nothing, so the weak-diagonal hold keeps them where they were.
    rng = np.random.default_rng(2)
    nu, nv = KU.size - 4, KV.size - 4
    cp = rng.normal(size=(nu, nv, 3))
    u, v = rng.uniform(0, 0.2, 200), rng.uniform(0, 1, 200)
    terms = [(np.eye(3)[k][None].repeat(200, 0), np.ones(200), rng.normal(size=200)) for k in range(3)]
    system = NormalEquations(KU, KV, np.zeros((nu, nv), dtype=bool), lengths_mm=(30.0, 20.0), degree=(3, 3))
    got = system.solve([(surface_rows(KU, KV, u, v), terms)], 0.0, cp)
    np.testing.assert_allclose(got[6:], cp[6:], atol=1e-9)


def test_one_system_solves_many_times_alike():
    # The pattern is built once per layout; a solve must leave it as it found it.
    rng = np.random.default_rng(7)
    nu, nv = KU.size - 4, KV.size - 4
    cp = rng.normal(size=(nu, nv, 3))
    system = NormalEquations(KU, KV, np.zeros((nu, nv), dtype=bool), lengths_mm=(30.0, 20.0), degree=(3, 3))
    sparse = [(surface_rows(KU, KV, u, v, du=du), terms) for (u, v, du), terms in _row_sets(rng, n=20)]
    dense = [(surface_rows(KU, KV, u, v, du=du), terms) for (u, v, du), terms in _row_sets(rng)]
    first = system.solve(dense, 0.05, cp)
    system.solve(sparse, 0.0, cp)  # few rows, no bending: most pairs of the pattern stay zero
    np.testing.assert_array_equal(system.solve(dense, 0.05, cp), first)


def test_gram_blocks_sum_each_cells_rows_in_order_to_the_bit():
    """`accumulate_grams` against plain loops: per knot cell (rows in stable order of their first column),
    each entry summed from zero row by row, then added to the band."""
    rng = np.random.default_rng(4)
    u, v = rng.uniform(0, 1, 400), rng.uniform(0, 1, 400)
    cols, vals = surface_rows(KU, KV, u, v)
    weights = rng.normal(size=(400, 6))
    band = np.zeros(((KU.size - 4) * (KV.size - 4), 49, 6))
    accumulate_grams(cols, vals, weights, (3, 3), band)
    want = np.zeros_like(band)
    order = np.argsort(cols[:, 0], kind="stable")
    for cell in np.unique(cols[:, 0]):
        rows = order[cols[order, 0] == cell]
        for a in range(16):
            for b in range(a, 16):
                slot = int(band_slot(b // 4 - a // 4, b % 4 - a % 4, (3, 3)))
                for k in range(6):
                    acc = 0.0
                    for r in rows:
                        acc += weights[r, k] * (vals[r, a] * vals[r, b])
                    want[cols[rows[0], a], slot, k] += acc
    np.testing.assert_array_equal(band, want)
