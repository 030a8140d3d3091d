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
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.sparse.linalg import splu, spsolve

from cam.fit._gramkernel import accumulate_grams, band_slot
from cam.fit.param import Anchors
from cam.spline.basis import (
    evaluate_surface,
    gram_matrix,
    span_params,
    surface_rows,
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


# The six coordinate pairs (i, j), i ≤ j, of the symmetric 3 x 3 block structure, and the pair of each (i, j).
_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
_PAIR_OF = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])


class NormalEquations:
    """Normal equations of one knot layout: thin-plate matrix, free/fixed split and the sparse pattern built once.

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

    Notes
    -----
    The Gram blocks are summed in band storage (`cam.fit._gramkernel`); the matrix of the free control
    points is gathered from it straight into the banded Cholesky's storage, its pattern (every pair of free
    control points whose basis functions overlap, for each coordinate pair) fixed here once per layout.
    """

    def __init__(self, knots_u: np.ndarray, knots_v: np.ndarray, fixed: np.ndarray, *,
                 lengths_mm: tuple[float, float], degree: tuple[int, int]) -> None:
        p, q = degree
        self.degree, self.ncp, self.width = (int(p), int(q)), fixed.size, (2 * p + 1) * (2 * q + 1)
        h_band = _thin_plate_band(knots_u, knots_v, fixed.shape, degree, lengths_mm)
        free = np.flatnonzero(~fixed.ravel())
        nf = free.size
        self.free3 = np.concatenate([free + k * self.ncp for k in range(3)])
        self.fixed3 = np.concatenate([np.flatnonzero(fixed.ravel()) + k * self.ncp for k in range(3)])
        index = np.full(self.ncp, -1)
        index[free] = np.arange(nf)
        c, c2, at, h_at = _band_entries(fixed.shape, degree)
        coupled = index[c] >= 0
        ff, fx = coupled & (index[c2] >= 0), coupled & (index[c2] < 0)
        hv = h_band.ravel()[h_at]
        # Free-free pairs (row, column, band entry, thin-plate value) and free-fixed ones, for one coordinate
        # pair; the nine blocks offset them.
        r_ff, c_ff, at_ff, h_ff = index[c[ff]], index[c2[ff]], at[ff] * len(_PAIRS), hv[ff]
        r_fx, at_fx, h_fx, v_fx = index[c[fx]], at[fx] * len(_PAIRS), hv[fx], c2[fx]
        rows, cols, src, h = [], [], [], []
        rows_x, src_x, h_x, value_x = [], [], [], []
        for i in range(3):
            for j in range(3):
                pair = _PAIR_OF[i, j]
                rows.append(i * nf + r_ff)
                cols.append(j * nf + c_ff)
                src.append(at_ff + pair)
                h.append(h_ff if i == j else np.zeros(h_ff.size))
                rows_x.append(i * nf + r_fx)
                src_x.append(at_fx + pair)
                h_x.append(h_fx if i == j else np.zeros(h_fx.size))
                value_x.append(j * self.ncp + v_fx)
        # The entries stay in the order made here (coordinate pair by pair, control point by point): the band
        # solve places each where it belongs, and the diagonal comes out in the unknowns' order (x, y, z
        # blocks, each by control point), which the damping's mean sums in.
        self.rows, self.cols = np.concatenate(rows), np.concatenate(cols)
        self.src, self.h = np.concatenate(src), np.concatenate(h)
        self.diagonal = np.flatnonzero(self.rows == self.cols)
        self.band_at, self.band_width, self.band_src, self.band_dest = _band_layout(
            fixed.shape, free, self.rows, self.cols)
        self.rows_x, self.src_x = np.concatenate(rows_x), np.concatenate(src_x)
        self.h_x, self.value_x = np.concatenate(h_x), np.concatenate(value_x)

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
        return self.solve_gram(self.gram(rows), lam, cp_current, damping)

    def gram(self, rows: list) -> tuple[np.ndarray, np.ndarray]:
        """The row sets' Gram blocks and right-hand side, what `solve_gram` solves with any lam and damping.

        Parameters
        ----------
        rows : list
            Row sets, as `solve` takes them.

        Returns
        -------
        band : ndarray, shape (nu nv, (2p + 1)(2q + 1), 6), float64
            The six coordinate-pair blocks in band storage (`cam.fit._gramkernel`).
        rhs : ndarray, shape (3 nu nv,), float64
            Σ w target e_i B per coordinate i, x then y then z.
        """
        size = self.ncp
        band = np.zeros((size, self.width, len(_PAIRS)))
        rhs = np.zeros(3 * size)
        for (cols, vals), terms in rows:
            for i in range(3):
                ri = sum(w * e[:, i] * t for e, w, t in terms)
                rhs[i * size:(i + 1) * size] += np.bincount(cols.ravel(), weights=(vals * ri[:, None]).ravel(),
                                                            minlength=size)
            weights = np.stack([sum(w * e[:, i] * e[:, j] for e, w, _ in terms) for i, j in _PAIRS], axis=1)
            accumulate_grams(cols, vals, weights, self.degree, band)
        return band, rhs

    def solve_gram(self, gram: tuple[np.ndarray, np.ndarray], lam: float, cp_current: np.ndarray,
                   damping: float = 0.0) -> np.ndarray:
        """`solve` from the row sets' `gram` (unchanged): a step taken again with other weights reuses it."""
        band, rhs = gram
        flat = band.ravel()
        data = flat[self.src] + lam * self.h
        c_all = cp_current.reshape(-1, 3).T.ravel()  # [x..., y..., z...]
        r = rhs[self.free3]
        if self.fixed3.size:
            coupling = (flat[self.src_x] + lam * self.h_x) * c_all[self.value_x]
            r = r - np.bincount(self.rows_x, weights=coupling, minlength=r.size)
        # A vanishing diagonal is a control point nothing reaches (no sample, no bending): keep it.
        diag = data[self.diagonal]
        scale = max(float(diag.max(initial=0.0)), 1e-300)
        weak = diag < 1e-14 * scale
        if weak.any():
            data[self.diagonal] += np.where(weak, scale * 1e-10, 0.0)
            r = r + np.where(weak, scale * 1e-10, 0.0) * c_all[self.free3]
        if damping > 0:
            # Levenberg-Marquardt: moving a control point from cp_current costs damping times the
            # problem's curvature along it, floored so that points little data reaches are held too.
            d = damping * np.maximum(diag, 1e-3 * float(diag.mean()))
            data[self.diagonal] += d
            r = r + d * c_all[self.free3]
        c_all = c_all.copy()
        c_all[self.free3] = self._solve_spd(data, r)
        return c_all.reshape(3, -1).T.reshape(cp_current.shape)

    def _solve_spd(self, data: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Solve M x = r, M the pattern's symmetric positive definite matrix with values `data`: a banded
        Cholesky factor in the band order (`_band_layout`). A sparse LU with a fill-reducing order filled most
        of the band anyway and took five times as long in all on the 50k-point Fandisk cloud's fit (26 s
        against 5 s, summed). Should the factor break down (a pivot not positive), that LU's fallbacks."""
        n = r.size
        ab = np.zeros((self.band_width + 1, n))
        ab.ravel()[self.band_dest] = data[self.band_src]
        rhs = np.empty(n)
        rhs[self.band_at] = r
        try:
            y = cho_solve_banded((cholesky_banded(ab, lower=True, check_finite=False), True), rhs, check_finite=False)
        except np.linalg.LinAlgError:
            M = sp.csc_matrix((data, (self.rows, self.cols)), shape=(n, n))
            M.sort_indices()
            M.eliminate_zeros()  # in place; pairs of the pattern that nothing coupled would only add fill
            return _solve_sparse_spd(M, r)
        return y[self.band_at]


def _thin_plate_band(knots_u: np.ndarray, knots_v: np.ndarray, shape: tuple[int, int], degree: tuple[int, int],
                     lengths_mm: tuple[float, float]) -> np.ndarray:
    """The thin-plate matrix of the layout in band storage: (nu nv, (2p + 1)(2q + 1)) float64.

    Entry (i nv + j, slot of (di, dj)) is `thin_plate_matrix`'s between control points (i, j) and (i + di, j + dj),
    from the same products of the one-dimensional Gram matrices with the same operations, without the sparse
    Kronecker products (basis functions that do not overlap bend nothing together, so the band holds them all).
    """
    p, q = degree
    (nu, nv), (lu, lv) = shape, (float(lengths_mm[0]), float(lengths_mm[1]))
    gu = [gram_matrix(knots_u, p, d) for d in range(3)]
    gv = [gram_matrix(knots_v, q, d) for d in range(3)]
    i, j = np.divmod(np.arange(nu * nv), nv)
    band = np.zeros((nu * nv, (2 * p + 1) * (2 * q + 1)))
    for di in range(-p, p + 1):
        for dj in range(-q, q + 1):
            ok = (i + di >= 0) & (i + di < nu) & (j + dj >= 0) & (j + dj < nv)
            a, b, a2, b2 = i[ok], j[ok], i[ok] + di, j[ok] + dj
            # As `thin_plate_matrix` sums them, (G2u ⊗ G0v / Lu⁴ + 2 G1u ⊗ G1v / (Lu² Lv²) + G0u ⊗ G2v / Lv⁴) Lu Lv,
            # a sparse matrix divided by a number being multiplied by its reciprocal.
            value = (gu[2][a, a2] * gv[0][b, b2] * (1 / lu**4)
                     + 2.0 * (gu[1][a, a2] * gv[1][b, b2]) * (1 / (lu**2 * lv**2))
                     + gu[0][a, a2] * gv[2][b, b2] * (1 / lv**4)) * (lu * lv)
            band[ok, int(band_slot(di, dj, degree))] = value
    return band


def _band_entries(shape: tuple[int, int], degree: tuple[int, int]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every pair (c, c2) of control points whose basis functions overlap: c, c2, where the pair's value is in
    the upper-triangle band (flat index c' width + slot', the mirror (c2, c) when c2 < c) and where its
    thin-plate value is in the full band (c width + slot). All int64 (k,)."""
    (nu, nv), (p, q) = shape, degree
    width = (2 * p + 1) * (2 * q + 1)
    c = np.repeat(np.arange(nu * nv), width)
    slot = np.tile(np.arange(width), nu * nv)
    i2 = c // nv + slot // (2 * q + 1) - p
    j2 = c % nv + slot % (2 * q + 1) - q
    inside = (i2 >= 0) & (i2 < nu) & (j2 >= 0) & (j2 < nv)
    c, slot, c2 = c[inside], slot[inside], (i2 * nv + j2)[inside]
    at = np.where(c2 < c, c2 * width + (width - 1 - slot), c * width + slot)
    return c, c2, at, c * width + slot


def _band_layout(shape: tuple[int, int], free: np.ndarray, rows: np.ndarray, cols: np.ndarray
                 ) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    """Band storage of the normal equations: each control point's three coordinates side by side, the points
    row by row along the net's shorter side, so that coupled unknowns lie within 3 (p n + q) + 2 of each other
    (n the shorter side's count).

    Parameters
    ----------
    shape : tuple of int
        (nu, nv), the net's control points.
    free : ndarray, shape (nf,), int
        Flat ids (i nv + j) of the free control points, increasing.
    rows, cols : ndarray, shape (k,), int
        The pattern's entries, unknowns numbered [x of the free points, y..., z...].

    Returns
    -------
    at : ndarray, shape (3 nf,), int64
        Each unknown's place in the band order.
    width : int
        The band's half width.
    src : ndarray, int64
        The entries on or below the diagonal in the band order.
    dest : ndarray, int64
        Where each of them goes in the lower band storage (width + 1, 3 nf), flat.
    """
    nu, nv = shape
    nf = free.size
    key = free if nv <= nu else (free % nv) * nu + free // nv  # row by row along the shorter side
    rank = np.empty(nf, dtype=np.int64)
    rank[np.argsort(key, kind="stable")] = np.arange(nf)
    at = 3 * np.tile(rank, 3) + np.repeat(np.arange(3), nf)
    r, c = at[rows], at[cols]
    src = np.flatnonzero(r >= c)
    return at, int((r - c).max(initial=0)), src, (r - c)[src] * (3 * nf) + c[src]


def _solve_sparse_spd(M: sp.csc_matrix, r: np.ndarray) -> np.ndarray:
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
