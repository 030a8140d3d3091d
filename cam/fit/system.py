"""The linear least-squares problem of one squared-distance step, and its normal equations.

Each step of `cam.fit.solve.fit_surface` replaces the squared distance of every sample by its
local quadratic approximation (Wang, Pottmann and Liu 2006: full weight along the normal,
d/(d - ρ) along each principal direction, ρ the signed radius of curvature, negative weights
dropped: `sdm_weights`), adds the feature-sensitive normal term (the surface's tangents should be
orthogonal to the mesh normal, which is linear in the control points: `normal_rows`), the G1 term
across C0 knot lines (`kink_rows`), the anchors that hold the parameterisation (`anchor_rows`) and a
thin-plate energy, and solves the resulting sparse problem for the free control points
(`NormalEquations`). Fixed control points (a shared border) stay exactly as given.

Every term is a row set: ((cols, vals), [(e (n, 3), w (n,), target (n,)), ...]), the surface point
or derivative that `cam.spline.basis.surface_rows` evaluates at n parameters, and weighted
projections of it onto directions e with their targets: Σ w (e · S - target)².
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu, spsolve

from cam.fit.param import Anchors
from cam.spline.basis import (
    evaluate_surface,
    span_params,
    surface_rows,
    thin_plate_matrix,
    weighted_grams,
    weighted_rhs,
)
from cam.spline.pieces import c0_knots

__all__ = ["NormalEquations", "anchor_rows", "dot_rows", "kink_rows", "normal_rows", "sdm_weights",
           "tangent_plane"]


def sdm_weights(signed_distance: np.ndarray, curvature: np.ndarray, *, cap: float = 100.0) -> np.ndarray:
    """Tangential weight d/(d - ρ) = dκ/(dκ - 1) of the squared-distance error term.

    Parameters
    ----------
    signed_distance : ndarray, shape (n,), float64
        d: the sample's offset from its foot point along the surface normal, mm.
    curvature : ndarray, shape (n,), float64
        κ: the surface's curvature along one principal direction there, 1/mm (positive towards +N).
    cap : float
        The largest weight kept.

    Returns
    -------
    ndarray, shape (n,), float64
        The weights in [0, cap]: negative ones dropped (0), infinite and larger ones capped.
    """
    dk = signed_distance * curvature
    with np.errstate(divide="ignore", invalid="ignore"):
        w = dk / (dk - 1.0)
    return np.clip(np.nan_to_num(w, nan=0.0, posinf=cap, neginf=0.0), 0.0, cap)


class NormalEquations:
    """Normal equations of one knot layout: thin-plate matrix and free/fixed split built once.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's clamped knot vectors, parameter units.
    fixed : ndarray, shape (nu, nv), bool
        Control points that keep their values.
    lengths_mm : tuple of float
        mm per parameter unit along u and v (scales the thin-plate energy to the part).
    degree : tuple of int
        (p, q), the surface's degrees.
    """

    def __init__(self, knots_u: np.ndarray, knots_v: np.ndarray, fixed: np.ndarray, *,
                 lengths_mm: tuple[float, float], degree: tuple[int, int]) -> None:
        self.ncp = fixed.size
        H = thin_plate_matrix(knots_u, knots_v, degree=degree, length_u=lengths_mm[0], length_v=lengths_mm[1])
        self.H3 = sp.block_diag([H, H, H]).tocsr()
        free = np.flatnonzero(~fixed.ravel())
        self.free3 = np.concatenate([free + k * self.ncp for k in range(3)])
        self.fixed3 = np.concatenate([np.flatnonzero(fixed.ravel()) + k * self.ncp for k in range(3)])

    def solve(self, rows: list, lam: float, cp_current: np.ndarray, damping: float = 0.0) -> np.ndarray:
        """Minimise Σ w (e · S(u) - target)² over the row sets plus lam · thin-plate, free points only.

        Parameters
        ----------
        rows : list
            Row sets ((cols, vals), [(e (n, 3), w (n,), target (n,)), ...]), see the module docstring.
        lam : float
            Weight of the thin-plate energy, mm².
        cp_current : ndarray, shape (nu, nv, 3), float64
            The current control net, mm: the fixed points' values, and where damping holds the free ones.
        damping : float
            Levenberg-Marquardt damping; 0: none.

        Returns
        -------
        ndarray, shape (nu, nv, 3), float64
            The new control net, mm; fixed points as in `cp_current`.
        """
        size = self.ncp
        blocks = [[None] * 3 for _ in range(3)]
        rhs = np.zeros(3 * size)
        pairs = [(i, j) for i in range(3) for j in range(i, 3)]
        for (cols, vals), terms in rows:
            for i in range(3):
                ri = sum(w * e[:, i] * t for e, w, t in terms)
                rhs[i * size:(i + 1) * size] += weighted_rhs(cols, vals, ri, size)
            grams = weighted_grams(cols, vals, [sum(w * e[:, i] * e[:, j] for e, w, _ in terms) for i, j in pairs],
                                   size)
            for (i, j), g in zip(pairs, grams):
                blocks[i][j] = g if blocks[i][j] is None else blocks[i][j] + g
        for i in range(3):
            for j in range(i):
                blocks[i][j] = blocks[j][i].T
        M = (sp.bmat(blocks, format="csr") + lam * self.H3).tocsr()
        c_all = cp_current.reshape(-1, 3).T.ravel()  # [x..., y..., z...]
        M_ff = M[self.free3][:, self.free3]
        r = rhs[self.free3]
        if self.fixed3.size:
            r = r - M[self.free3][:, self.fixed3] @ c_all[self.fixed3]
        # A vanishing diagonal is a control point nothing reaches (no sample, no bending): keep it.
        diag = M_ff.diagonal()
        scale = max(float(diag.max(initial=0.0)), 1e-300)
        weak = diag < 1e-14 * scale
        if weak.any():
            M_ff = M_ff + sp.diags(np.where(weak, scale * 1e-10, 0.0))
            r = r + np.where(weak, scale * 1e-10, 0.0) * c_all[self.free3]
        if damping > 0:
            # Levenberg-Marquardt: moving a control point from cp_current costs damping times the
            # problem's curvature along it, floored so that points little data reaches are held too.
            d = damping * np.maximum(diag, 1e-3 * float(diag.mean()))
            M_ff = M_ff + sp.diags(d)
            r = r + d * c_all[self.free3]
        c_all = c_all.copy()
        c_all[self.free3] = _solve_spd(M_ff.tocsc(), r)
        return c_all.reshape(3, -1).T.reshape(cp_current.shape)


def _solve_spd(M: sp.csc_matrix, r: np.ndarray) -> np.ndarray:
    """Solve M x = r for symmetric positive definite M (every weight here is >= 0 and the thin plate
    and the weak-point terms make it definite): an LU with a symmetric fill-reducing order and no
    pivoting, about 4 times faster here than the general default. Falls back to that default if the
    factor breaks down (a pivot of zero)."""
    try:
        return splu(M, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}).solve(r)
    except RuntimeError:
        return spsolve(M, r)


def anchor_rows(anchors: Anchors, knots_u: np.ndarray, knots_v: np.ndarray, t1: np.ndarray, t2: np.ndarray, *,
                degree: tuple[int, int], border_weight: float, param_weight: float,
                extra: tuple[tuple[np.ndarray, float], ...] = ()) -> tuple:
    """The anchors' row set: across the border (exact, `border_weight` in all) and tangential (`param_weight`).

    Parameters
    ----------
    anchors : Anchors
        The quad grid's vertices on the mesh (`cam.fit.param.grid_anchors`), m of them.
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's knot vectors, grid-index units.
    t1, t2 : ndarray, shape (m, 3), float64
        Unit tangents at the anchors along which the targets hold them (`param_weight` in all).
    degree : tuple of int
        (p, q), the surface's degrees.
    border_weight : float
        Weight in all of the offsets across the patch border.
    param_weight : float
        Weight in all of the tangential offsets from the targets.
    extra : tuple of (ndarray, shape (m, 3), float64; float) pairs
        Further directions, each with the weight of every anchor, holding the anchors' points.

    Returns
    -------
    tuple
        One row set (see the module docstring).
    """
    ap = anchors.points
    m = len(ap)
    on_border = sum(int((np.linalg.norm(a, axis=1) > 0).sum()) for a in (anchors.across_u, anchors.across_v))
    wb = border_weight / max(int(on_border), 1)
    wp = np.full(m, param_weight / m)
    terms = [(t1, wp, dot_rows(t1, anchors.targets)), (t2, wp, dot_rows(t2, anchors.targets))]
    for across in (anchors.across_u, anchors.across_v):
        mask = np.linalg.norm(across, axis=1) > 0
        terms.append((across, wb * mask, dot_rows(across, anchors.targets)))
    terms += [(e, np.broadcast_to(w, (m,)), dot_rows(e, ap)) for e, w in extra]
    return surface_rows(knots_u, knots_v, anchors.u, anchors.v, degree=degree), terms


def kink_rows(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, *, degree: tuple[int, int],
              weight_mm: float, lengths_mm: tuple[float, float] = (1.0, 1.0), per_span: int = 4) -> list:
    """Rows that hold both sides of every C0 knot line tangent to one plane (G1 across it).

    Along a line u = c, S_u just before and at c (the two pieces' own derivatives) should be
    orthogonal to the mean of the two pieces' normals there; likewise across v = c.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's knot vectors, parameter units; C0 knot lines are knots of multiplicity p (q).
    control_points : ndarray, shape (nu, nv, 3), float64
        The current control net, mm.
    degree : tuple of int
        (p, q), the surface's degrees.
    weight_mm : float
        An angle error of ε costs as much as a distance of ε · weight_mm over all the samples.
    lengths_mm : tuple of float
        mm per parameter unit along u and v (floors the tangents' length).
    per_span : int
        Points per knot span along each line.

    Returns
    -------
    list
        Row sets (see the module docstring), two per direction that has C0 knot lines; empty without any.
    """
    ku, kv, cp = knots_u, knots_v, control_points
    out = []
    for axis, (knots, deg) in enumerate(((ku, degree[0]), (kv, degree[1]))):
        lines = c0_knots(knots, deg)
        if not lines.size:
            continue
        other = span_params(kv if axis == 0 else ku, per_span)
        c = np.repeat(lines, other.size)
        t = np.tile(other, lines.size)
        before = np.nextafter(c, -np.inf)
        sides = [(before, t), (c, t)] if axis == 0 else [(t, before), (t, c)]
        ders = [evaluate_surface(ku, kv, cp, a, b, degree=degree, order=1) for a, b in sides]
        normals = [np.cross(d[(1, 0)], d[(0, 1)]) for d in ders]
        n = sum(x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-300) for x in normals)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        key, du, dv = ((1, 0), 1, 0) if axis == 0 else ((0, 1), 0, 1)
        for (a, b), d in zip(sides, ders):
            w = weight_mm**2 / (2 * c.size) / _speed2(d[key], lengths_mm[axis])
            out.append((surface_rows(ku, kv, a, b, degree=degree, du=du, dv=dv), [(n, w, np.zeros(c.size))]))
    return out


def _speed2(tangent: np.ndarray, length_mm: float) -> np.ndarray:
    """|S_u|² of tangents (n, 3), floored at a tenth of the mean grid step `length_mm` squared.

    Dividing S_u · n by |S_u| makes it the sine of an angle, but where S_u nearly vanishes (a
    collapsed corner, a short piece of a border) the angle is undefined, and the unfloored weight
    reached 1e9 times the data's: the normal equations lost every digit and the step was garbage.
    """
    return np.maximum(np.einsum("ij,ij->i", tangent, tangent), (0.1 * length_mm) ** 2)


def normal_rows(knots_u: np.ndarray, knots_v: np.ndarray, u: np.ndarray, v: np.ndarray, normals: np.ndarray,
                su: np.ndarray, sv: np.ndarray, weights: np.ndarray, *, degree: tuple[int, int], weight_mm: float,
                lengths_mm: tuple[float, float]) -> list:
    """The normal term's rows: S_u · n = 0 and S_v · n = 0, scaled by |S_u|, |S_v| (the sine of the normal error).

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's knot vectors, parameter units.
    u, v : ndarray, shape (n,), float64
        The samples' foot parameters.
    normals : ndarray, shape (n, 3), float64
        The mesh's unit normals at the samples.
    su, sv : ndarray, shape (n, 3), float64
        The surface's derivatives at the feet, mm per parameter unit.
    weights : ndarray, shape (n,), float64
        Each sample's weight (that of its distance term).
    degree : tuple of int
        (p, q), the surface's degrees.
    weight_mm : float
        An angle error of ε rad costs as much as a distance of ε · weight_mm.
    lengths_mm : tuple of float
        mm per parameter unit along u and v (floors the tangents' length).

    Returns
    -------
    list
        Two row sets (see the module docstring), along u and along v.
    """
    out = []
    for du, dv, tangent, length in ((1, 0, su, lengths_mm[0]), (0, 1, sv, lengths_mm[1])):
        w = weight_mm**2 * weights / _speed2(tangent, length)
        out.append((surface_rows(knots_u, knots_v, u, v, degree=degree, du=du, dv=dv),
                    [(normals, w, np.zeros(len(normals)))]))
    return out


def tangent_plane(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents spanning the plane orthogonal to each normal.

    Parameters
    ----------
    normals : ndarray, shape (n, 3), float64
        Unit normals.

    Returns
    -------
    t1, t2 : ndarray, shape (n, 3), float64
        Unit tangents, t2 = normal x t1.
    """
    helper = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(normals, helper)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
    return t1, np.cross(normals, t1)


def dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products.

    Parameters
    ----------
    a, b : ndarray, shape (n, k), float64

    Returns
    -------
    ndarray, shape (n,), float64
    """
    return np.einsum("ij,ij->i", a, b)
