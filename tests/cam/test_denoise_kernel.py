"""The compiled MeshTGV iteration against the numpy iteration it replaced (kept here as the oracle): the
filtered normals bit for bit, on a noisy mesh, after many iterations."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cam.denoise import tgv


def numpy_shrink(v: np.ndarray, thresh: float) -> np.ndarray:
    """Row-wise vectorial soft thresholding: max(0, 1 - t/|v|) v."""
    nrm = np.linalg.norm(v, axis=1)
    scale = np.maximum(0.0, 1.0 - thresh / np.maximum(nrm, 1e-300))
    return v * scale[:, None]


def numpy_iterate(split, solve_n, solve_g, *, alpha0, alpha1, r0, r1, max_iterations, tolerance, on_iteration,
                  check_cancel):
    """`tgv._iterate` before its loops were compiled: scipy products and numpy updates."""
    D, Gam, Lam = split.D, split.Gam, split.Lam
    E, m = D.shape
    N = split.n0.copy()
    fidN = split.area[:, None] * split.n0
    G = np.zeros((2 * m, 3))
    P = np.zeros((E, 3))
    Q = np.zeros((3 * E, 3))
    lamP = np.zeros_like(P)
    lamQ = np.zeros_like(Q)
    rel = float("inf")
    k = 0
    for k in range(1, max_iterations + 1):
        N_new = solve_n(fidN + split.DT_L @ (r1 * (Gam @ G + P) + lamP))
        nrm = np.linalg.norm(N_new, axis=1)
        N_new = N_new / np.where(nrm > 0, nrm, 1.0)[:, None]
        N_new[nrm == 0] = N[nrm == 0]
        DN = D @ N_new
        G = solve_g(split.GamT_L @ (r1 * (DN - P) - lamP) + split.LamT_L @ (r0 * Q + lamQ))
        AX1 = DN - Gam @ G
        AX0 = Lam @ G
        P = numpy_shrink(AX1 - lamP / r1, alpha1 / r1)
        Q = numpy_shrink((AX0 - lamQ / r0).reshape(E, 9), alpha0 / r0).reshape(3 * E, 3)
        lamP += r1 * (P - AX1)
        lamQ += r0 * (Q - AX0)
        dN = N_new - N
        rel = float(np.sqrt(np.einsum("ij,ij->", dN, dN) / max(np.einsum("ij,ij->", N, N), 1e-300)))
        N = N_new
        if rel < tolerance:
            return N, k, rel, True
    return N, k, rel, False


@pytest.fixture(scope="module")
def noisy_sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4)
    rng = np.random.default_rng(3)
    v = mesh.vertices * 20.0 + rng.normal(scale=0.3, size=mesh.vertices.shape)
    v /= np.mean(mesh.edges_unique_length) * 20.0  # in mean edge lengths, as the filter takes it
    return v, np.asarray(mesh.faces, dtype=np.int64)


def test_compiled_iteration_is_bit_for_bit_the_numpy_one(noisy_sphere, monkeypatch):
    v, f = noisy_sphere
    topo = tgv.face_topology(f, len(v))
    kw = {"alpha0": 0.05, "alpha1": 0.2, "r0": 2.0, "r1": 2.0, "max_iterations": 40, "tolerance": 0.0}
    compiled = tgv.tgv_filter_normals(v, f, topo, **kw)
    monkeypatch.setattr(tgv, "_iterate", numpy_iterate)
    reference = tgv.tgv_filter_normals(v, f, topo, **kw)
    assert compiled.iterations == reference.iterations == 40
    np.testing.assert_array_equal(compiled.normals, reference.normals)
    assert compiled.relative_change == reference.relative_change
