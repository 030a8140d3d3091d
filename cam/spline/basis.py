"""B-spline basis functions as arrays and sparse matrices: the linear algebra behind every fit.

`basis_functions` gives the p + 1 non-zero basis functions (or their derivatives)
at many parameters at once; `surface_matrix` turns them into the sparse design
matrix of a tensor-product surface, `evaluate_surface` evaluates a control net
with all derivatives up to second order in one pass (foot points and curvature
need them together), and `gram_matrix` / `thin_plate_matrix` give the exact
quadratic forms of the bending energy.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["find_spans", "basis_functions", "curve_matrix", "surface_rows", "surface_matrix", "weighted_grams",
           "weighted_rhs", "evaluate_curve", "evaluate_surface", "span_params", "gram_matrix", "thin_plate_matrix"]


def find_spans(knots: np.ndarray, degree: int, t: np.ndarray) -> np.ndarray:
    """Index i of the knot span [k_i, k_(i+1)) holding each t: int64 (n,), in [degree, count - 1].

    The right end of a clamped vector belongs to the last non-empty span.
    """
    count = knots.size - degree - 1
    spans = np.searchsorted(knots, t, side="right") - 1
    return np.clip(spans, degree, count - 1).astype(np.int64)


def _values(knots: np.ndarray, degree: int, t: np.ndarray, spans: np.ndarray) -> list[np.ndarray]:
    """Non-zero basis values of every degree 0..degree at the spans: list of (n, d + 1) arrays."""
    n = t.size
    tables = [np.ones((n, 1))]
    left = np.empty((n, degree + 1))
    right = np.empty((n, degree + 1))
    for j in range(1, degree + 1):
        left[:, j] = t - knots[spans + 1 - j]
        right[:, j] = knots[spans + j] - t
        prev = tables[-1]
        new = np.zeros((n, j + 1))
        saved = np.zeros(n)
        for r in range(j):
            denom = right[:, r + 1] + left[:, j - r]
            # A zero denominator only occurs for an empty span, where the value is zero anyway.
            temp = np.divide(prev[:, r], denom, out=np.zeros(n), where=denom != 0)
            new[:, r] = saved + right[:, r + 1] * temp
            saved = left[:, j - r] * temp
        new[:, j] = saved
        tables.append(new)
    return tables


def basis_functions(knots: np.ndarray, degree: int, t: np.ndarray, *, derivative: int = 0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Spans and the non-zero basis functions (or their `derivative`-th derivatives) at `t`.

    knots: float64 (count + degree + 1,), clamped; t: float64 (n,) inside the knot span.
    Returns spans int64 (n,) and values float64 (n, degree + 1): column r belongs to
    control point spans - degree + r.
    """
    knots = np.asarray(knots, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).ravel()
    if derivative < 0 or derivative > degree:
        raise ValueError(f"derivative must be in 0..{degree}, got {derivative}")
    spans = find_spans(knots, degree, t)
    tables = _values(knots, degree, t, spans)
    return spans, _derivative(knots, tables, spans, degree, derivative)


def _derivative(knots: np.ndarray, tables: list[np.ndarray], spans: np.ndarray, degree: int, order: int
                ) -> np.ndarray:
    """D^order of the degree-`degree` functions from the lower-degree tables (de Boor's recursion)."""
    if order == 0:
        return tables[degree]
    lower = _derivative(knots, tables, spans, degree - 1, order - 1)
    n = spans.size
    ext = np.zeros((n, degree + 2))
    ext[:, 1:-1] = lower  # functions i - degree .. i + 1 of degree - 1; the outer two are zero here
    m = np.arange(degree + 1)
    a = spans[:, None] - degree + m[None, :]
    d1 = knots[a + degree] - knots[a]
    d2 = knots[a + degree + 1] - knots[a + 1]
    t1 = np.divide(ext[:, :-1], d1, out=np.zeros_like(d1), where=d1 != 0)
    t2 = np.divide(ext[:, 1:], d2, out=np.zeros_like(d2), where=d2 != 0)
    return degree * (t1 - t2)


def curve_matrix(knots: np.ndarray, degree: int, t: np.ndarray, *, derivative: int = 0) -> sp.csr_matrix:
    """Sparse (n, count) matrix B with B @ control_points = C^(derivative)(t)."""
    knots = np.asarray(knots, dtype=np.float64)
    count = knots.size - degree - 1
    spans, vals = basis_functions(knots, degree, t, derivative=derivative)
    cols = spans[:, None] - degree + np.arange(degree + 1)[None, :]
    rows = np.repeat(np.arange(spans.size), degree + 1)
    return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(spans.size, count))


def surface_rows(knots_u: np.ndarray, knots_v: np.ndarray, u: np.ndarray, v: np.ndarray, *,
                 degree: tuple[int, int] = (3, 3), du: int = 0, dv: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The non-zero entries of each row of the design matrix: columns int64 (n, m) and values float64 (n, m),
    m = (p + 1)(q + 1); column index i * nv + j follows control_points.reshape(-1, 3)."""
    p, q = degree
    ku = np.asarray(knots_u, dtype=np.float64)
    kv = np.asarray(knots_v, dtype=np.float64)
    nv = kv.size - q - 1
    su, bu = basis_functions(ku, p, u, derivative=du)
    sv, bv = basis_functions(kv, q, v, derivative=dv)
    n = su.size
    iu = su[:, None] - p + np.arange(p + 1)[None, :]
    iv = sv[:, None] - q + np.arange(q + 1)[None, :]
    m = (p + 1) * (q + 1)
    cols = (iu[:, :, None] * nv + iv[:, None, :]).reshape(n, m)
    vals = (bu[:, :, None] * bv[:, None, :]).reshape(n, m)
    return cols, vals


def surface_matrix(knots_u: np.ndarray, knots_v: np.ndarray, u: np.ndarray, v: np.ndarray, *,
                   degree: tuple[int, int] = (3, 3), du: int = 0, dv: int = 0) -> sp.csr_matrix:
    """Sparse (n, nu * nv) design matrix of ∂^(du+dv)S/∂u^du∂v^dv at (u, v).

    Columns follow control_points.reshape(-1, 3), i.e. index i * nv + j.
    """
    p, q = degree
    size = (len(knots_u) - p - 1) * (len(knots_v) - q - 1)
    cols, vals = surface_rows(knots_u, knots_v, u, v, degree=degree, du=du, dv=dv)
    rows = np.repeat(np.arange(len(cols)), cols.shape[1])
    return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(len(cols), size))


def weighted_grams(cols: np.ndarray, vals: np.ndarray, weights: list[np.ndarray], size: int) -> list[sp.csr_matrix]:
    """B^T diag(w) B for each w in `weights`, B given by its rows (see `surface_rows`): sparse (size, size) each.

    Rows in one knot cell share their columns, so products are summed per cell (one sparse
    product with the row-to-cell incidence) and one small block per cell is scattered.
    """
    n, m = cols.shape
    cells, first, inverse = np.unique(cols[:, 0], return_index=True, return_inverse=True)
    incidence = sp.csr_matrix((np.ones(n), (inverse.ravel(), np.arange(n))), shape=(len(cells), n))
    outer = (vals[:, :, None] * vals[:, None, :]).reshape(n, m * m)
    cc = cols[first]
    r = np.repeat(cc, m, axis=1).ravel()
    c = np.tile(cc, (1, m)).ravel()
    out = []
    for w in weights:
        blocks = (incidence @ sp.diags(w)) @ outer
        out.append(sp.coo_matrix((np.asarray(blocks).ravel(), (r, c)), shape=(size, size)).tocsr())
    return out


def weighted_rhs(cols: np.ndarray, vals: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """B^T values for the design matrix given by its rows: float64 (size,)."""
    return np.bincount(cols.ravel(), weights=(vals * values[:, None]).ravel(), minlength=size)


def evaluate_curve(knots: np.ndarray, control_points: np.ndarray, t: np.ndarray, *, degree: int = 3,
                   derivatives: int = 0) -> list[np.ndarray]:
    """[C(t), C'(t), ...] up to `derivatives`, each float64 (n, dim)."""
    cp = np.asarray(control_points, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).ravel()
    out = []
    for d in range(derivatives + 1):
        spans, vals = basis_functions(knots, degree, t, derivative=d)
        idx = spans[:, None] - degree + np.arange(degree + 1)[None, :]
        out.append(np.einsum("nr,nrk->nk", vals, cp[idx]))
    return out


def evaluate_surface(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray,
                     u: np.ndarray, v: np.ndarray, *, degree: tuple[int, int] = (3, 3), order: int = 2
                     ) -> dict[tuple[int, int], np.ndarray]:
    """Points and partial derivatives up to total `order` (≤ 2): {(du, dv): float64 (n, 3)}."""
    p, q = degree
    cp = np.asarray(control_points, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64).ravel()
    v = np.asarray(v, dtype=np.float64).ravel()
    ku = np.asarray(knots_u, dtype=np.float64)
    kv = np.asarray(knots_v, dtype=np.float64)
    su = find_spans(ku, p, u)
    sv = find_spans(kv, q, v)
    tu, tv = _values(ku, p, u, su), _values(kv, q, v, sv)
    bu = [_derivative(ku, tu, su, p, d) for d in range(min(order, p) + 1)]
    bv = [_derivative(kv, tv, sv, q, d) for d in range(min(order, q) + 1)]
    iu = su[:, None] - p + np.arange(p + 1)[None, :]
    iv = sv[:, None] - q + np.arange(q + 1)[None, :]
    n = u.size
    flat = (iu[:, :, None] * cp.shape[1] + iv[:, None, :]).reshape(n, (p + 1) * (q + 1))
    net = cp.reshape(-1, cp.shape[-1]).T[:, flat]  # (3, n, (p + 1)(q + 1)); per-coordinate gathers are fastest
    out = {}
    for a in range(order + 1):
        for b in range(order + 1 - a):
            if a < len(bu) and b < len(bv):
                w = (bu[a][:, :, None] * bv[b][:, None, :]).reshape(n, -1)
                out[(a, b)] = np.stack([np.einsum("nm,nm->n", w, net[k]) for k in range(len(net))], axis=1)
            else:
                out[(a, b)] = np.zeros((n, cp.shape[-1]))
    return out


def span_params(knots: np.ndarray, per_span: int) -> np.ndarray:
    """`per_span` evenly spaced parameters in every non-empty knot span, and the end: float64 (k,)."""
    breaks = np.unique(np.asarray(knots, dtype=np.float64))
    inner = [np.linspace(a, b, per_span, endpoint=False) for a, b in zip(breaks[:-1], breaks[1:])]
    return np.concatenate(inner + [breaks[-1:]])


def gram_matrix(knots: np.ndarray, degree: int, derivative: int) -> np.ndarray:
    """G[r, s] = ∫ N_r^(d) N_s^(d) dt over the knot span, exact by Gauss–Legendre: float64 (count, count)."""
    knots = np.asarray(knots, dtype=np.float64)
    count = knots.size - degree - 1
    xg, wg = np.polynomial.legendre.leggauss(degree + 1)  # exact up to degree 2 * degree + 1
    breaks = np.unique(knots)
    a, b = breaks[:-1], breaks[1:]
    t = (0.5 * (b - a)[:, None] * (xg[None, :] + 1) + a[:, None]).ravel()
    w = (0.5 * (b - a)[:, None] * wg[None, :]).ravel()
    B = curve_matrix(knots, degree, t, derivative=derivative).toarray()
    G = (B * w[:, None]).T @ B
    return G.reshape(count, count)


def thin_plate_matrix(knots_u: np.ndarray, knots_v: np.ndarray, *, degree: tuple[int, int] = (3, 3),
                      length_u: float = 1.0, length_v: float = 1.0) -> sp.csr_matrix:
    """Sparse (nu * nv, nu * nv) H with c·Hc = ∫∫ |S_xx|² + 2|S_xy|² + |S_yy|² dx dy per coordinate.

    x = u * length_u and y = v * length_v (mm): scaling the parameters by the patch's side lengths
    makes the energy a bending energy of the part, independent of how long the patch is in
    parameter space, so one smoothing weight suits every patch.
    """
    p, q = degree
    G0u, G1u, G2u = (sp.csr_matrix(gram_matrix(knots_u, p, d)) for d in range(3))
    G0v, G1v, G2v = (sp.csr_matrix(gram_matrix(knots_v, q, d)) for d in range(3))
    Lu, Lv = float(length_u), float(length_v)
    H = (sp.kron(G2u, G0v) / Lu**4 + 2.0 * sp.kron(G1u, G1v) / (Lu**2 * Lv**2) + sp.kron(G0u, G2v) / Lv**4)
    return (H * (Lu * Lv)).tocsr()
