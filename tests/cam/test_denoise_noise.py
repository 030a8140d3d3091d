"""Tests for cam.denoise.noise (the noise estimate) and cam.denoise.weights (weights chosen from it),
and that weights set by hand reach the filter as given."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from cam.denoise import mesh_tgv, noise
from cam.denoise.mesh_tgv import denoise_mesh
from cam.denoise.noise import NoiseEstimate, estimate_noise, normal_residuals
from cam.denoise.weights import weights_for_noise
from cam.params import DenoiseParams


def _mean_edge(v, f):
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    return float(np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1).mean())


def _plane(n: int = 60):
    """A flat sheet of nearly equilateral triangles, n x n vertices, edge length about 1."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v = np.stack([i.ravel() + 0.5 * (j.ravel() % 2), j.ravel() * np.sqrt(3) / 2, np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    return v.astype(float), np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _sphere():
    s = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


SHAPES = {"plane": _plane, "sphere": _sphere}


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("sigma", [0.02, 0.1, 0.3, 0.5])
def test_estimate_recovers_known_gaussian_noise(shape, sigma):
    # Isotropic Gaussian noise of sigma mean edge lengths on every coordinate: only its normal part
    # moves a vertex off the surface, and that part has standard deviation sigma. Measured: within
    # 4 % on both shapes over 0.02-0.5 and two seeds; 10 % is the stated tolerance.
    v, f = SHAPES[shape]()
    h = _mean_edge(v, f)
    noisy = v + np.random.default_rng(11).normal(scale=sigma * h, size=v.shape)
    est = estimate_noise(noisy / h, f)
    assert abs(est.sigma - sigma) < 0.10 * sigma, (est.sigma, sigma)
    # every vertex has a fit but a few at the sheet's corners (under ten vertices within two rings)
    assert est.vertices_measured == len(v) - (8 if shape == "plane" else 0)
    assert est.correlation < 1.1  # white noise reads the same at both radii


@pytest.mark.parametrize("shape", SHAPES)
def test_clean_surfaces_read_near_zero(shape):
    v, f = SHAPES[shape]()
    h = _mean_edge(v, f)
    est = estimate_noise(v / h, f)
    # a quadric fits a plane exactly and a sphere to third order: far below any noise worth filtering
    assert est.sigma < 1e-3, est.sigma


def test_estimate_is_in_the_units_of_the_input():
    v, f = _sphere()
    noisy = v + np.random.default_rng(3).normal(scale=0.01, size=v.shape)
    a = estimate_noise(noisy, f).sigma
    b = estimate_noise(noisy * 1000.0, f).sigma
    assert b == pytest.approx(1000.0 * a, rel=1e-6)


def test_correlated_noise_reads_a_higher_ratio():
    # Noise smoothed over about two edges (neighbours move together, like the Kinect scan's): the
    # 2-ring quadric absorbs part of it, the 3-ring one less, so the ratio rises. White noise of the
    # same amplitude stays near 1. (Noise smoother still is absorbed at both radii and reads as shape.)
    v, f = _plane()
    n = len(v)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    adj = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    adj.data[:] = 1.0
    deg = np.asarray(adj.sum(axis=1)).ravel()
    z = np.random.default_rng(0).normal(size=n)
    white = v.copy()
    white[:, 2] += 0.1 * z
    for _ in range(2):
        z = (z + adj @ z) / (1 + deg)
    smooth = v.copy()
    smooth[:, 2] += 0.1 * z / z.std()
    h = _mean_edge(v, f)
    assert estimate_noise(white / h, f).correlation < 1.1
    assert estimate_noise(smooth / h, f).correlation > 1.3  # measured 1.35


def _reference_rings(x, faces, rings, max_neighbours):
    """Sparse powers of the adjacency, then a sort by distance: (n, K) neighbours and their counts."""
    n = len(x)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    reach = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    reach = reach + sp.identity(n, format="csr")
    step = reach.copy()
    for _ in range(rings - 1):
        reach = (reach @ step).tocsr()
    reach = reach.tocoo()
    d = np.einsum("ij,ij->i", x[reach.row] - x[reach.col], x[reach.row] - x[reach.col])
    order = np.lexsort((reach.col, d, reach.row))  # equal distances in vertex order
    row, col = reach.row[order], reach.col[order]
    rank = np.arange(len(row)) - np.searchsorted(row, np.arange(n))[row]
    keep = rank < max_neighbours
    idx = np.zeros((n, max_neighbours), dtype=np.int64)
    idx[row[keep], rank[keep]] = col[keep]
    return idx, np.minimum(np.bincount(row, minlength=n), max_neighbours)


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize(("rings", "max_neighbours"), [(1, 24), (2, 24), (3, 48), (3, 10)])
def test_ring_neighbourhoods_match_sparse_powers(shape, rings, max_neighbours):
    v, f = SHAPES[shape]()
    x = v + np.random.default_rng(5).normal(scale=0.01, size=v.shape)
    idx, got_count = noise._ring_neighbourhoods(x, f, rings, max_neighbours)
    mask = np.arange(idx.shape[1])[None, :] < got_count[:, None]
    want, count = _reference_rings(x, f, rings, max_neighbours)
    np.testing.assert_array_equal(got_count, count)
    np.testing.assert_array_equal(np.where(mask, idx, 0), want[:, :idx.shape[1]])
    assert not want[:, idx.shape[1]:].any()  # the returned width is the widest neighbourhood's


def _reference_residuals(x, faces, rings, max_neighbours):
    """The vectorised quadric fits the compiled loop replaced: every vertex at once, numpy's solvers."""
    idx, count = _reference_rings(x, faces, rings, max_neighbours)
    mask = np.arange(max_neighbours)[None, :] < count[:, None]
    out = np.full(len(x), np.nan)
    enough = mask.sum(axis=1) >= 10
    idx, mask = idx[enough], mask[enough]
    w = mask.astype(np.float64)
    p = x[idx] - x[np.flatnonzero(enough)][:, None, :]
    cnt = w.sum(axis=1)
    centroid = np.einsum("kj,kji->ki", w, p) / cnt[:, None]
    q = (p - centroid[:, None, :]) * w[..., None]
    evals, evecs = np.linalg.eigh(np.einsum("kji,kjl->kil", q, q))
    normal, t2, t1 = evecs[:, :, 0], evecs[:, :, 1], evecs[:, :, 2]
    s = np.sqrt(np.maximum(evals[:, 2], 1e-300) / cnt)[:, None]
    u, v = np.einsum("kji,ki->kj", p, t1) / s, np.einsum("kji,ki->kj", p, t2) / s
    h = np.einsum("kji,ki->kj", p, normal)
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1) * w[..., None]
    ata = np.einsum("kja,kjb->kab", design, design)
    atb = np.einsum("kja,kj->ka", design, h * w)
    cond_ok = np.linalg.cond(ata) < 1e12
    ata[~cond_ok] = np.eye(6)
    coef = np.linalg.solve(ata, atb[..., None])[..., 0]
    leverage = np.linalg.inv(ata)[:, 0, 0]
    resid = -coef[:, 0] / np.sqrt(np.clip(1.0 - leverage, 1e-6, None))
    resid[~cond_ok] = np.nan
    out[np.flatnonzero(enough)] = resid
    return out


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize(("rings", "max_neighbours"), [(2, 24), (3, 48)])
def test_residuals_match_the_vectorised_fits(shape, rings, max_neighbours):
    # The sign of a residual follows the sign the eigen-solver gives the normal: compare magnitudes.
    v, f = SHAPES[shape]()
    x = (v + np.random.default_rng(3).normal(scale=0.1 * _mean_edge(v, f), size=v.shape)) / _mean_edge(v, f)
    got = normal_residuals(x, f, rings, max_neighbours)
    want = _reference_residuals(x, f, rings, max_neighbours)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    np.testing.assert_allclose(np.abs(got[ok]), np.abs(want[ok]), rtol=1e-9, atol=1e-12)


def test_residuals_are_nan_where_a_fit_is_impossible():
    # a single triangle: no vertex has ten neighbours
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    assert np.all(np.isnan(normal_residuals(v, f, 2, 24)))
    est = estimate_noise(v, f)
    assert est.sigma == 0.0 and est.vertices_measured == 0 and est.correlation == 1.0


@pytest.mark.parametrize(("x", "faces", "match"), [
    (np.zeros((4, 2)), np.array([[0, 1, 2]]), r"x must have shape \(n, 3\), got \(4, 2\)"),
    (np.array([[0.0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), np.array([[0, 1, 2]]), "1 non-finite"),
    (np.zeros((3, 3), dtype=complex), np.array([[0, 1, 2]]), "real numbers, got dtype complex128"),
    (np.eye(3), np.array([[0, 1, 3]]), r"face indices must lie in \[0, 2\], got \[0, 3\]"),
    (np.eye(3), np.array([[0.0, 1, 2]]), "integer vertex indices, got dtype float64"),
    (np.eye(3), np.array([0, 1, 2]), r"faces must have shape \(m, 3\), got \(3,\)"),
])
def test_bad_input_names_what_it_saw(x, faces, match):
    with pytest.raises(ValueError, match=match):
        estimate_noise(x, faces)


def test_bad_ring_arguments():
    v, f = _plane(8)
    with pytest.raises(ValueError, match="rings must be at least 1, got 0"):
        normal_residuals(v, f, 0, 24)
    with pytest.raises(ValueError, match="max_neighbours must be at least 10, got 5"):
        normal_residuals(v, f, 2, 5)


def _noise(sigma, correlation=1.0):
    return NoiseEstimate(sigma=sigma, sigma_coarse=sigma * correlation, correlation=correlation,
                         vertices_measured=100)


def test_weights_follow_the_noise():
    # within the band the base weights were tuned at they apply unchanged
    for sigma in (0.18, 0.22, 0.26):
        w = weights_for_noise(_noise(sigma))
        assert (w.alpha0, w.alpha1, w.correlated_share) == (0.15, 0.4, 0.0)
    # more noise: a stronger first-order term; less: both weaker; none: nearly nothing
    sigmas = [0.0, 0.01, 0.05, 0.1, 0.18, 0.3, 0.5, 0.7]
    a1 = [weights_for_noise(_noise(s)).alpha1 for s in sigmas]
    assert all(b >= a for a, b in itertools.pairwise(a1))
    assert a1[0] < 1e-5 and a1[-1] > 1.0
    # correlated noise at the Kinect scan's level gets the correlated-noise weights
    w = weights_for_noise(_noise(0.072, 1.36))
    assert (w.alpha0, w.alpha1, w.correlated_share) == (0.6, 1.0, 1.0)


def test_vertex_iterations_follow_how_correlated_the_noise_is():
    # white noise at any level: the paper's 20
    for sigma in (0.0, 0.05, 0.22, 0.7):
        assert weights_for_noise(_noise(sigma)).vertex_iterations == 20
    # correlated at the Kinect scan's level: 300; halfway up the correlation ramp, halfway between
    assert weights_for_noise(_noise(0.072, 1.36)).vertex_iterations == 300
    assert weights_for_noise(_noise(0.072, 1.25)).vertex_iterations == 160
    # weaker correlated noise: fewer; a reconstruction's faint ripple (up to half the scan's level) keeps 20
    sigmas = (0.0, 0.006, 0.02, 0.035, 0.05, 0.0525, 0.07, 0.2)
    iterations = [weights_for_noise(_noise(s, 1.5)).vertex_iterations for s in sigmas]
    assert iterations == [20, 20, 20, 20, 20 + round(280 * 0.15 / 0.35), 160, 300, 300]


def test_weights_reject_a_bad_estimate():
    with pytest.raises(ValueError, match="sigma=-0.1"):
        weights_for_noise(_noise(-0.1))
    with pytest.raises(ValueError, match="correlation=nan"):
        weights_for_noise(_noise(0.1, float("nan")))


@pytest.fixture(scope="module")
def noisy_sphere():
    v, f = _sphere()
    h = _mean_edge(v, f)
    return v + np.random.default_rng(5).normal(scale=0.25 * h, size=v.shape), f


def _capture_weights(monkeypatch):
    seen = {}
    real = mesh_tgv.tgv_filter_normals

    def spy(*args, **kwargs):
        seen["alpha0"], seen["alpha1"] = kwargs["alpha0"], kwargs["alpha1"]
        return real(*args, **kwargs)

    monkeypatch.setattr(mesh_tgv, "tgv_filter_normals", spy)
    return seen


def test_hand_set_weights_are_used_as_given(noisy_sphere, monkeypatch):
    v, f = noisy_sphere
    seen = _capture_weights(monkeypatch)
    res = denoise_mesh(v, f, DenoiseParams(alpha0=0.33, alpha1=0.77, max_iterations=5))
    assert seen == {"alpha0": 0.33, "alpha1": 0.77}
    w = res.report["weights"]
    assert (w["alpha0"], w["alpha1"], w["alpha0_from"], w["alpha1_from"]) == (0.33, 0.77, "parameter", "parameter")
    # the noise is still measured and reported, with what it would have chosen
    assert res.report["noise"]["sigma"] > 0.2
    assert w["for_the_noise"]["alpha1"] != 0.77


def test_unset_weights_come_from_the_noise(noisy_sphere, monkeypatch):
    v, f = noisy_sphere
    seen = _capture_weights(monkeypatch)
    res = denoise_mesh(v, f, DenoiseParams(max_iterations=5))
    chosen = res.report["weights"]["for_the_noise"]
    assert seen == {"alpha0": chosen["alpha0"], "alpha1": chosen["alpha1"]}
    assert res.report["weights"]["alpha0_from"] == res.report["weights"]["alpha1_from"] == "noise"
    # one weight by hand, the other from the noise
    res = denoise_mesh(v, f, DenoiseParams(alpha1=0.5, max_iterations=5))
    assert seen == {"alpha0": res.report["weights"]["for_the_noise"]["alpha0"], "alpha1": 0.5}
    assert (res.report["weights"]["alpha0_from"], res.report["weights"]["alpha1_from"]) == ("noise", "parameter")


def test_vertex_iterations_by_hand_or_from_the_noise(noisy_sphere, monkeypatch):
    v, f = noisy_sphere
    seen = []
    real = mesh_tgv.update_vertices

    def spy(x, faces, normals, iterations, repair_rounds, **kwargs):
        seen.append(iterations)
        return real(x, faces, normals, iterations, repair_rounds, **kwargs)

    monkeypatch.setattr(mesh_tgv, "update_vertices", spy)
    res = denoise_mesh(v, f, DenoiseParams(max_iterations=5))
    w = res.report["weights"]
    assert seen == [w["vertex_iterations"]] == [w["for_the_noise"]["vertex_iterations"]] == [20]  # white noise
    assert w["vertex_iterations_from"] == "noise"
    res = denoise_mesh(v, f, DenoiseParams(max_iterations=5, vertex_iterations=7))
    assert seen[-1] == res.report["weights"]["vertex_iterations"] == 7
    assert res.report["weights"]["vertex_iterations_from"] == "parameter"
