"""MeshTGV normal filtering: second-order total generalized variation of the face normal field.

Model (Liu, Li, Wang, Liu, Chen, "Mesh total generalized variation for denoising", IEEE TVCG 2022),
written in our own discretisation. All lengths are in units of the mean edge length (the caller
normalises the mesh first), which makes every parameter scale invariant; every quantity below is
built from dot products, lengths and areas, so the model is rotation invariant by construction.

Unknowns
    N   face normals, one unit 3-vector per face (piecewise constant field on faces).
    G   the auxiliary first-order field of TGV: per face a 3x2 matrix, the derivative of N along the
        face's two orthonormal tangent directions (t1, t2), i.e. the ambient 3x3 tensor G T^T.

Energy
    E(N, G) = 1/2 sum_f  s_f |N_f - N0_f|^2                                (fidelity, area weighted)
            + alpha1 sum_e l_e | (N_f - N_g) - 1/2 (G_f T_f^T + G_g T_g^T) (c_f - c_g) |
                                                                          (first order: the jump
                                                      across e minus the jump G predicts)
            + alpha0 sum_e l_e | G_f T_f^T - G_g T_g^T |_F                 (second order: jump of G)
    subject to |N_f| = 1, sums over interior edges e = (f, g), l_e edge length, c_f centroids,
    s_f face areas. Where the normal field varies linearly the first-order term vanishes with
    G = dN and the second-order term is zero as well, so smooth curved regions carry no
    staircase; at a crease the first-order jump is cheap in the L1 (not squared) sense and is kept.

Solver: variable splitting P = D N - Gamma G (edges x 3), Q = Lambda G (edges x 3 x 3), augmented
Lagrangian with penalties r1, r0 (inner products weighted by edge length). Each outer iteration
    1. N <- the normal subproblem (fidelity + r1 coupling to P): a sparse SPD system, then N is
       projected onto unit length (the |N| = 1 constraint, as in the TV normal filters this
       family of methods builds on);
    2. G <- the auxiliary subproblem (r1 coupling to P, r0 coupling to Q): a sparse SPD system;
    3. P, Q <- closed-form vectorial shrinkage (thresholds alpha1/r1, alpha0/r0);
    4. multipliers <- multipliers + r (split variable - operator);
until the relative change of N is below the tolerance. The two system matrices never change: each
is factored once (SuperLU, scipy.sparse.linalg.splu) and solved for the three normal components
at once (with two processors, the third in a forked child: `cam.denoise.columns`).

Inconsistently oriented neighbours are compared with a sign flip; edges with more than two faces are
treated like boundary edges (no coupling across them).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.sparse.csgraph import reverse_cuthill_mckee

from cam import CheckCancel
from cam.denoise._tgvkernel import (
    CSR,
    edge_updates,
    jump_rhs,
    matvec,
    normal_rhs,
    residual_jumps,
)
from cam.denoise.columns import solves_in_two

__all__ = ["FaceTopology", "TGVResult", "face_topology", "tgv_filter_normals"]


@dataclass(frozen=True)
class FaceTopology:
    """Edge structure of the valid (non-degenerate) faces, in valid-face indices."""

    edge_faces: np.ndarray  # (E, 2) int, the two faces across each interior manifold edge
    edge_sign: np.ndarray  # (E,) +1 consistently oriented neighbours, -1 flipped
    edge_vertices: np.ndarray  # (E, 2) vertex ids of each interior edge
    n_boundary_edges: int
    n_nonmanifold_edges: int
    n_flipped_edges: int


def face_topology(faces: np.ndarray, n_vertices: int) -> FaceTopology:
    """Interior edges of a triangle list and the faces across each.

    Parameters
    ----------
    faces : ndarray, shape (m, 3), integer dtype
        Triangles, already filtered to the valid (non-degenerate) ones.
    n_vertices : int
        Number of vertices the indices refer to.

    Returns
    -------
    FaceTopology
        ``edge_faces`` (E, 2) int64 and ``edge_sign`` (E,) float64 (+1 consistently oriented, -1
        flipped) of the E edges with exactly two faces, their ``edge_vertices`` (E, 2) int64, and
        the counts of boundary, non-manifold and inconsistently oriented edges.
    """
    m = len(faces)
    a = faces.reshape(-1)
    b = np.roll(faces, -1, axis=1).reshape(-1)
    lo = np.minimum(a, b).astype(np.int64)
    hi = np.maximum(a, b).astype(np.int64)
    key = lo * np.int64(n_vertices) + hi
    order = np.argsort(key, kind="stable")
    key_s = key[order]
    starts = np.flatnonzero(np.r_[True, key_s[1:] != key_s[:-1]])
    counts = np.diff(np.r_[starts, len(key_s)])
    face_of = np.repeat(np.arange(m), 3)[order]
    fwd = (a < b)[order]  # direction of the half edge relative to (lo, hi)
    interior = counts == 2
    s0 = starts[interior]
    f1 = face_of[s0]
    f2 = face_of[s0 + 1]
    same_dir = fwd[s0] == fwd[s0 + 1]
    sign = np.where(same_dir, -1.0, 1.0)
    ev = np.stack([lo[order][s0], hi[order][s0]], axis=1)
    return FaceTopology(
        edge_faces=np.stack([f1, f2], axis=1),
        edge_sign=sign,
        edge_vertices=ev,
        n_boundary_edges=int(np.sum(counts == 1)),
        n_nonmanifold_edges=int(np.sum(counts > 2)),
        n_flipped_edges=int(np.sum(same_dir)),
    )


@dataclass(frozen=True)
class TGVResult:
    """Filtered normals and how the filter went (times in seconds)."""

    normals: np.ndarray  # (m, 3) float64 unit, in the input's face order
    iterations: int
    relative_change: float
    converged: bool
    setup_seconds: float
    factor_seconds: float
    iterate_seconds: float
    n_edges: int


def tgv_filter_normals(
    vertices: np.ndarray,
    faces: np.ndarray,
    topo: FaceTopology,
    *,
    alpha0: float,
    alpha1: float,
    r0: float,
    r1: float,
    max_iterations: int,
    tolerance: float,
    on_iteration: Callable[[int, float], None] | None = None,
    check_cancel: CheckCancel | None = None,
    processes: int = 1,
) -> TGVResult:
    """Filter the face normals of a triangle mesh with MeshTGV.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3), float64
        Positions in units of the mean edge length (the caller normalises the mesh).
    faces : ndarray, shape (m, 3), int64
        Triangles of non-zero area, indices into ``vertices``.
    topo : FaceTopology
        ``face_topology(faces, n)``.
    alpha0, alpha1 : float
        Weights of the second- and first-order TGV terms (dimensionless); ``alpha1 <= 0`` returns
        the input normals unfiltered.
    r0, r1 : float
        Augmented-Lagrangian penalties of the two split variables.
    max_iterations : int
        Cap on the outer iterations.
    tolerance : float
        Stop when the relative change of the normals (Frobenius norms) falls below it.
    on_iteration : callable, optional
        ``on_iteration(k, relative_change)``, called after outer iteration k.
    check_cancel : callable, optional
        Called after each outer iteration, before ``on_iteration``; it stops the work by raising.
    processes : int
        Processors to use: with 2 or more, each solve's last component runs in a forked child
        (`cam.denoise.columns`); the normals are bit for bit those of one.

    Returns
    -------
    TGVResult
        ``normals`` float64 (m, 3), unit, in the order of ``faces``, with the iteration count,
        the last relative change and the time each phase took (s).
    """
    t_start = time.perf_counter()
    if alpha1 <= 0.0:
        return _unfiltered(vertices, faces, topo, t_start)
    faces, topo, inv = _renumber_faces(faces, topo)
    split = _assemble(vertices, faces, topo, r0=r0, r1=r1)
    t_setup = time.perf_counter()
    lu_n, lu_g = _factor(split.KN), _factor(split.KG)
    t_factor = time.perf_counter()
    with solves_in_two([lu_n, lu_g], processes=processes) as (solve_n, solve_g):
        normals, k, rel, converged = _iterate(split, solve_n, solve_g, alpha0=alpha0, alpha1=alpha1, r0=r0, r1=r1,
                                              max_iterations=max_iterations, tolerance=tolerance,
                                              on_iteration=on_iteration, check_cancel=check_cancel)
    t_end = time.perf_counter()
    return TGVResult(
        normals=normals[inv],
        iterations=k,
        relative_change=rel,
        converged=converged,
        setup_seconds=t_setup - t_start,
        factor_seconds=t_factor - t_setup,
        iterate_seconds=t_end - t_factor,
        n_edges=split.D.shape[0],
    )


def _unfiltered(vertices, faces, topo: FaceTopology, t_start: float) -> TGVResult:
    # Without the first-order term the fidelity alone is minimised, by the input normals.
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    c = np.cross(p1 - p0, p2 - p0)
    return TGVResult(normals=c / np.linalg.norm(c, axis=1)[:, None], iterations=0,
                     relative_change=0.0, converged=True, setup_seconds=0.0,
                     factor_seconds=0.0, iterate_seconds=time.perf_counter() - t_start,
                     n_edges=len(topo.edge_faces))


def _renumber_faces(faces, topo: FaceTopology):
    """Faces and topology along a reverse Cuthill-McKee order of the face graph, and the inverse order.

    With a local numbering SuperLU's minimum-degree ordering gives a much faster factorisation and
    solve (Block: 0.2 s / 13 ms instead of 1.8 s / 34 ms for the auxiliary system).
    """
    m = len(faces)
    ef = topo.edge_faces
    adj = sp.csr_matrix((np.ones(len(ef)), (ef[:, 0], ef[:, 1])), shape=(m, m))
    perm = reverse_cuthill_mckee((adj + adj.T).tocsr(), symmetric_mode=True)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(m)
    return faces[perm], replace(topo, edge_faces=inv[ef]), inv


@dataclass(frozen=True)
class _Splitting:
    """The operators of the split problem (one normal component; the same for x, y and z)."""

    D: sp.csr_matrix  # (E, m) jump of N across each edge
    Gam: sp.csr_matrix  # (E, 2m) the jump the auxiliary field G predicts
    Lam: sp.csr_matrix  # (3E, 2m) jump of G across each edge (ambient 3x3, row per axis)
    DT_L: sp.csr_matrix
    GamT_L: sp.csr_matrix
    LamT_L: sp.csr_matrix
    KN: sp.csc_matrix  # system matrix of the normal subproblem
    KG: sp.csc_matrix  # system matrix of the auxiliary subproblem
    area: np.ndarray  # (m,)
    n0: np.ndarray  # (m, 3) input unit normals


def _assemble(vertices, faces, topo: FaceTopology, *, r0: float, r1: float) -> _Splitting:
    m = len(faces)
    A1, A0, area, length, n0 = _operators(vertices, faces, topo)
    L1 = sp.diags(length)
    L0 = sp.diags(np.repeat(length, 3))
    D = A1[:, :m].tocsr()
    Gam = (-A1[:, m:]).tocsr()
    Lam = A0[:, m:].tocsr()
    # Normal subproblem: (S + r1 D^T L D) N = S N0 + D^T L (r1 (Gam G + P) + lamP)
    KN = (sp.diags(area) + r1 * (D.T @ L1 @ D)).tocsc()
    # Auxiliary subproblem: (r1 Gam^T L Gam + r0 Lam^T L Lam) G = Gam^T L (r1 (D N - P) - lamP)
    #                                                                + Lam^T L (r0 Q + lamQ)
    # (a 1e-10 Tikhonov term keeps it definite for faces without interior edges)
    KG = (r1 * (Gam.T @ L1 @ Gam) + r0 * (Lam.T @ L0 @ Lam)
          + 1e-10 * max(r0, r1) * sp.eye(2 * m)).tocsc()
    return _Splitting(D=D, Gam=Gam, Lam=Lam, DT_L=(D.T @ L1).tocsr(), GamT_L=(Gam.T @ L1).tocsr(),
                      LamT_L=(Lam.T @ L0).tocsr(), KN=KN, KG=KG, area=area, n0=n0)


def _factor(matrix: sp.csc_matrix):
    # Both matrices are fixed (symmetric positive definite): factor once, reuse every iteration.
    # Minimum degree on A^T + A, symmetric mode (diagonal pivots): about half the fill of COLAMD.
    return spla.splu(matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})


def _iterate(split: _Splitting, solve_n, solve_g, *, alpha0, alpha1, r0, r1, max_iterations, tolerance,
             on_iteration, check_cancel):
    """The augmented-Lagrangian iterations: (normals (m, 3), iterations, relative change, converged).

    The products and the edge updates are compiled loops (`cam.denoise._tgvkernel`), each row's arithmetic
    that of the numpy expressions in the comments, in the same order.
    """
    D, Gam, Lam = CSR(split.D), CSR(split.Gam), CSR(split.Lam)
    DT_L, GamT_L, LamT_L = CSR(split.DT_L), CSR(split.GamT_L), CSR(split.LamT_L)
    E, m = split.D.shape
    N = split.n0.copy()
    fidN = split.area[:, None] * split.n0
    G = np.zeros((2 * m, 3))  # column c: component c; rows [t1 derivative (m), t2 derivative (m)]
    # split variables start at zero: the first normal solve is then a smoothing of the input,
    # which pulls folded (reversed) noisy faces towards their neighbours instead of keeping them
    P = np.zeros((E, 3))
    Q = np.zeros((3 * E, 3))  # rows (edge, ambient axis), columns: normal component
    lamP = np.zeros_like(P)
    lamQ = np.zeros_like(Q)
    W = np.zeros_like(Q)  # r0 Q + lamQ
    # Work arrays made once: with a fresh set every iteration more of the heap stayed resident after the
    # filter (on a 194k-face mesh, 64-94 MB over its start once they were reused).
    rhs_n, rhs_g, edge_term = np.empty_like(fidN), np.empty_like(G), np.empty_like(P)
    DN, AX1, AX0 = np.empty_like(P), np.empty_like(P), np.empty_like(Q)
    rel = float("inf")
    k = 0
    for k in range(1, max_iterations + 1):
        # 1. normal subproblem: solve fidN + D^T L (r1 (Gam G + P) + lamP), then |N| = 1 by projection
        N_new = solve_n(normal_rhs(Gam, DT_L, G, P, lamP, fidN, r1, scratch=edge_term, out=rhs_n))
        nrm = np.linalg.norm(N_new, axis=1)
        N_new = N_new / np.where(nrm > 0, nrm, 1.0)[:, None]
        N_new[nrm == 0] = N[nrm == 0]
        matvec(D, N_new, out=DN)
        # 2. auxiliary subproblem: solve Gam^T L (r1 (DN - P) - lamP) + Lam^T L (r0 Q + lamQ)
        G = np.ascontiguousarray(solve_g(jump_rhs(GamT_L, LamT_L, DN, P, lamP, W, r1, scratch=edge_term, out=rhs_g)))
        # 3. AX1 = DN - Gam G, AX0 = Lam G; closed-form shrinkage of P and of Q (each edge's 3x3 tensor
        # (ambient axis, component) as one vector: Frobenius); 4. the multipliers
        residual_jumps(Gam, Lam, G, DN, out1=AX1, out0=AX0)
        edge_updates(AX1, AX0, P, Q, lamP, lamQ, W, r0=r0, r1=r1, alpha0=alpha0, alpha1=alpha1)
        dN = N_new - N
        rel = float(np.sqrt(np.einsum("ij,ij->", dN, dN) / max(np.einsum("ij,ij->", N, N), 1e-300)))
        N = N_new
        if check_cancel is not None:
            check_cancel()
        if on_iteration is not None:
            on_iteration(k, rel)
        if rel < tolerance:
            return N, k, rel, True
    return N, k, rel, False


def _operators(vertices, faces, topo: FaceTopology):
    """Sparse operators, per normal component (the same for x, y and z).

    Unknown vector per component: x = [N (m), G[:, 0] (m), G[:, 1] (m)].
    Returns A1 (E x 3m): jump minus predicted jump; A0 (3E x 3m): jump of G in ambient coordinates;
    plus areas, edge lengths, input normals.
    """
    m = len(faces)
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    cross = np.cross(p1 - p0, p2 - p0)
    dbl = np.linalg.norm(cross, axis=1)
    area = 0.5 * dbl
    n0 = cross / dbl[:, None]
    t1 = p1 - p0
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(n0, t1)
    cent = (p0 + p1 + p2) / 3.0

    f, g = topo.edge_faces[:, 0], topo.edge_faces[:, 1]
    s = topo.edge_sign
    E = len(f)
    ev = topo.edge_vertices
    length = np.linalg.norm(vertices[ev[:, 0]] - vertices[ev[:, 1]], axis=1)
    d = cent[f] - cent[g]
    rows = np.arange(E)

    # A1: N_f - s N_g - 1/2 (G_f T_f^T d + s G_g T_g^T d)
    a1_rows = np.concatenate([rows] * 6)
    a1_cols = np.concatenate([f, g, m + f, 2 * m + f, m + g, 2 * m + g])
    a1_vals = np.concatenate([
        np.ones(E), -s,
        -0.5 * np.einsum("ij,ij->i", t1[f], d), -0.5 * np.einsum("ij,ij->i", t2[f], d),
        -0.5 * s * np.einsum("ij,ij->i", t1[g], d), -0.5 * s * np.einsum("ij,ij->i", t2[g], d),
    ])
    A1 = sp.csr_matrix((a1_vals, (a1_rows, a1_cols)), shape=(E, 3 * m))

    # A0: G_f T_f^T - s G_g T_g^T, one row per (edge, ambient axis j)
    r_list, c_list, v_list = [], [], []
    for j in range(3):
        rj = 3 * rows + j
        r_list += [rj, rj, rj, rj]
        c_list += [m + f, 2 * m + f, m + g, 2 * m + g]
        v_list += [t1[f, j], t2[f, j], -s * t1[g, j], -s * t2[g, j]]
    A0 = sp.csr_matrix(
        (np.concatenate(v_list), (np.concatenate(r_list), np.concatenate(c_list))), shape=(3 * E, 3 * m)
    )
    return A1, A0, area, length, n0
