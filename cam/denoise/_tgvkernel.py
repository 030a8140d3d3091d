"""Compiled loops of the MeshTGV iteration (`cam.denoise.tgv`): sparse products and the edge updates.

Each loop runs over rows (edges, faces) in parallel and does, row by row, the arithmetic the numpy and
scipy code it replaced did, in the same order: a CSR product sums its row's terms in stored order starting
from zero (scipy's `csr_matvecs`), and a row's length is summed as `np.linalg.norm(axis=1)` sums it
(three terms in turn; nine as the first eight pairwise, then the ninth). So the normals are bit for bit
those of the vectorised iteration, which `tests/cam/test_denoise_kernel.py` keeps as the oracle.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from cam.mesh._compiled import KERNEL_LOCK, norm3

__all__ = ["CSR", "edge_updates", "jump_rhs", "matvec", "normal_rhs", "residual_jumps"]


class CSR:
    """A scipy CSR matrix's arrays for the kernels: its own (no copy), its indices in stored order."""

    def __init__(self, matrix) -> None:
        m = matrix.tocsr()
        self.indptr, self.indices = np.ascontiguousarray(m.indptr), np.ascontiguousarray(m.indices)
        self.data = np.ascontiguousarray(m.data, dtype=np.float64)
        self.shape = m.shape


@njit(cache=True, inline="always")
def _row3(indptr, indices, data, x, i):
    # Row i of a CSR product with x (cols, 3): the three components' sums in one pass over the row, each from
    # zero in stored order (scipy's `csr_matvecs`).
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for jj in range(indptr[i], indptr[i + 1]):
        k, d = indices[jj], data[jj]
        s0 += d * x[k, 0]
        s1 += d * x[k, 1]
        s2 += d * x[k, 2]
    return s0, s1, s2


@njit(cache=True, parallel=True)
def _matvec(indptr, indices, data, x, out):
    for i in prange(out.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _row3(indptr, indices, data, x, i)


@njit(cache=True, parallel=True)
def _normal_rhs(g_ptr, g_idx, g_val, dt_ptr, dt_idx, dt_val, G, P, lamP, fid, r1, t, out):
    # t = r1 (Gam G + P) + lamP on the edges, then out = fid + (D^T L) t on the faces.
    for e in prange(t.shape[0]):
        g0, g1, g2 = _row3(g_ptr, g_idx, g_val, G, e)
        t[e, 0] = r1 * (g0 + P[e, 0]) + lamP[e, 0]
        t[e, 1] = r1 * (g1 + P[e, 1]) + lamP[e, 1]
        t[e, 2] = r1 * (g2 + P[e, 2]) + lamP[e, 2]
    for f in prange(out.shape[0]):
        d0, d1, d2 = _row3(dt_ptr, dt_idx, dt_val, t, f)
        out[f, 0], out[f, 1], out[f, 2] = fid[f, 0] + d0, fid[f, 1] + d1, fid[f, 2] + d2


@njit(cache=True, parallel=True)
def _jump_rhs(gt_ptr, gt_idx, gt_val, lt_ptr, lt_idx, lt_val, DN, P, lamP, W, r1, a, out):
    # a = r1 (D N - P) - lamP on the edges; out = (Gam^T L) a + (Lam^T L) W, W = r0 Q + lamQ.
    for e in prange(a.shape[0]):
        for c in range(3):
            a[e, c] = r1 * (DN[e, c] - P[e, c]) - lamP[e, c]
    for i in prange(out.shape[0]):
        a0, a1, a2 = _row3(gt_ptr, gt_idx, gt_val, a, i)
        w0, w1, w2 = _row3(lt_ptr, lt_idx, lt_val, W, i)
        out[i, 0], out[i, 1], out[i, 2] = a0 + w0, a1 + w1, a2 + w2


@njit(cache=True, parallel=True)
def _residual_jumps(g_ptr, g_idx, g_val, l_ptr, l_idx, l_val, G, DN, AX1, AX0):
    # AX1 = D N - Gam G (edges), AX0 = Lam G (edge x axis rows).
    for e in prange(AX1.shape[0]):
        g0, g1, g2 = _row3(g_ptr, g_idx, g_val, G, e)
        AX1[e, 0], AX1[e, 1], AX1[e, 2] = DN[e, 0] - g0, DN[e, 1] - g1, DN[e, 2] - g2
    for i in prange(AX0.shape[0]):
        AX0[i, 0], AX0[i, 1], AX0[i, 2] = _row3(l_ptr, l_idx, l_val, G, i)


@njit(cache=True, inline="always")
def _shrink_q(AX0, lamQ, Q, e, r0, t0):
    # Q's 3x3 block of edge e as one vector of nine, shrunk; its length as np.linalg.norm(axis=1) sums a row
    # of nine: the first eight pairwise, then the ninth.
    i = 3 * e
    v0, v1, v2 = AX0[i, 0] - lamQ[i, 0] / r0, AX0[i, 1] - lamQ[i, 1] / r0, AX0[i, 2] - lamQ[i, 2] / r0
    v3, v4, v5 = AX0[i + 1, 0] - lamQ[i + 1, 0] / r0, AX0[i + 1, 1] - lamQ[i + 1, 1] / r0, AX0[i + 1, 2] - lamQ[i + 1, 2] / r0
    v6, v7, v8 = AX0[i + 2, 0] - lamQ[i + 2, 0] / r0, AX0[i + 2, 1] - lamQ[i + 2, 1] / r0, AX0[i + 2, 2] - lamQ[i + 2, 2] / r0
    length = math.sqrt((((v0 * v0 + v1 * v1) + (v2 * v2 + v3 * v3)) + ((v4 * v4 + v5 * v5) + (v6 * v6 + v7 * v7)))
                       + v8 * v8)
    scale = max(0.0, 1.0 - t0 / max(length, 1e-300))
    Q[i, 0], Q[i, 1], Q[i, 2] = v0 * scale, v1 * scale, v2 * scale
    Q[i + 1, 0], Q[i + 1, 1], Q[i + 1, 2] = v3 * scale, v4 * scale, v5 * scale
    Q[i + 2, 0], Q[i + 2, 1], Q[i + 2, 2] = v6 * scale, v7 * scale, v8 * scale


@njit(cache=True, parallel=True)
def _edge_updates(AX1, AX0, P, Q, lamP, lamQ, W, r0, r1, t1, t0):
    # The shrinkage of P (thresh t1) and Q (t0), the multipliers' step, and W = r0 Q + lamQ for the next
    # auxiliary right-hand side.
    for e in prange(AX1.shape[0]):
        v0 = AX1[e, 0] - lamP[e, 0] / r1
        v1 = AX1[e, 1] - lamP[e, 1] / r1
        v2 = AX1[e, 2] - lamP[e, 2] / r1
        scale = max(0.0, 1.0 - t1 / max(norm3(v0, v1, v2), 1e-300))
        P[e, 0], P[e, 1], P[e, 2] = v0 * scale, v1 * scale, v2 * scale
        for c in range(3):
            lamP[e, c] += r1 * (P[e, c] - AX1[e, c])
        _shrink_q(AX0, lamQ, Q, e, r0, t0)
        for i in range(3 * e, 3 * e + 3):
            for c in range(3):
                lamQ[i, c] += r0 * (Q[i, c] - AX0[i, c])
                W[i, c] = r0 * Q[i, c] + lamQ[i, c]


def matvec(a: CSR, x: np.ndarray, *, out: np.ndarray) -> np.ndarray:
    """a @ x for x (cols, 3) float64, into out (rows, 3)."""
    with KERNEL_LOCK:
        _matvec(a.indptr, a.indices, a.data, np.ascontiguousarray(x), out)
    return out


def normal_rhs(gam: CSR, dt_l: CSR, G, P, lamP, fid, r1: float, *, scratch: np.ndarray, out: np.ndarray
               ) -> np.ndarray:
    """fid + (D^T L) (r1 (Gam G + P) + lamP): the normal subproblem's right-hand side, into out (faces, 3);
    scratch (edges, 3) takes the edge term."""
    with KERNEL_LOCK:
        _normal_rhs(gam.indptr, gam.indices, gam.data, dt_l.indptr, dt_l.indices, dt_l.data, G, P, lamP, fid,
                    float(r1), scratch, out)
    return out


def jump_rhs(gamt_l: CSR, lamt_l: CSR, DN, P, lamP, W, r1: float, *, scratch: np.ndarray, out: np.ndarray
             ) -> np.ndarray:
    """(Gam^T L) (r1 (DN - P) - lamP) + (Lam^T L) W: the auxiliary subproblem's right-hand side, into out
    (2 faces, 3); scratch (edges, 3) takes the edge term."""
    with KERNEL_LOCK:
        _jump_rhs(gamt_l.indptr, gamt_l.indices, gamt_l.data, lamt_l.indptr, lamt_l.indices, lamt_l.data, DN, P,
                  lamP, W, float(r1), scratch, out)
    return out


def residual_jumps(gam: CSR, lam: CSR, G, DN, *, out1: np.ndarray, out0: np.ndarray) -> None:
    """out1 = DN - Gam G (edges, 3) and out0 = Lam G (3 edges, 3)."""
    with KERNEL_LOCK:
        _residual_jumps(gam.indptr, gam.indices, gam.data, lam.indptr, lam.indices, lam.data, G, DN, out1, out0)


def edge_updates(AX1, AX0, P, Q, lamP, lamQ, W, *, r0: float, r1: float, alpha0: float, alpha1: float) -> None:
    """Shrink P and Q, step lamP and lamQ, and set W = r0 Q + lamQ, all in place."""
    with KERNEL_LOCK:
        _edge_updates(AX1, AX0, P, Q, lamP, lamQ, W, float(r0), float(r1), float(alpha1 / r1), float(alpha0 / r0))
