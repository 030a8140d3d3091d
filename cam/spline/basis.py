"""B-spline basis functions as arrays and sparse matrices: the linear algebra behind every fit.

`basis_functions` gives the p + 1 non-zero basis functions (or their derivatives)
at many parameters at once; `surface_matrix` turns them into the sparse design
matrix of a tensor-product surface, `evaluate_surface` evaluates a control net
with all derivatives up to second order in one pass (foot points and curvature
need them together; compiled, by the same recursions: `cam.spline._compiled`), and `gram_matrix` / `thin_plate_matrix` give the exact
quadratic forms of the bending energy.

The fit evaluates the nets it solves for with these basis functions, the same as
its design matrices'; a finished surface (`cam.spline.surface.BSplineSurface`) is
evaluated by SciPy's compiled `NdBSpline`.

Units: knots and parameters are in parameter units, control points and evaluated
values in mm, and k-th derivatives in mm per parameter unit^k.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from cam.spline._compiled import design_rows, evaluate_net

__all__ = ["find_spans", "basis_functions", "curve_matrix", "surface_rows", "surface_matrix", "evaluate_curve",
           "evaluate_surface", "span_params", "gram_matrix", "thin_plate_matrix"]


def find_spans(knots: np.ndarray, degree: int, t: np.ndarray) -> np.ndarray:
    """Find the index i of the knot span [k_i, k_(i+1)) holding each parameter.

    The right end of a clamped vector belongs to the last non-empty span.

    Parameters
    ----------
    knots : (count + degree + 1,) float64
        Clamped knot vector, in parameter units.
    degree : int
        Degree p of the basis.
    t : (n,) float64
        Parameters, in parameter units.

    Returns
    -------
    spans : (n,) int64
        Span index i for each ``t``, clipped to [degree, count - 1].
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
    """Compute the spans and the non-zero basis functions (or their `derivative`-th derivatives) at `t`.

    Parameters
    ----------
    knots : (count + degree + 1,) float64
        Clamped knot vector, in parameter units.
    degree : int
        Degree p of the basis.
    t : (n,) float64
        Parameters inside the knot span, in parameter units; any shape is flattened.
    derivative : int, optional
        Order k of the derivative, 0..degree (default 0: the functions themselves).

    Returns
    -------
    spans : (n,) int64
        Knot span index of each parameter (see `find_spans`).
    values : (n, degree + 1) float64
        The non-zero basis functions' k-th derivatives, in parameter units^-k (dimensionless for
        k = 0); column r belongs to control point spans - degree + r.

    Raises
    ------
    ValueError
        If `derivative` is not in 0..degree.
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
    """Build the sparse curve design matrix B with B @ control_points = C^(derivative)(t).

    Parameters
    ----------
    knots : (count + degree + 1,) float64
        Clamped knot vector, in parameter units.
    degree : int
        Degree p of the curve.
    t : (n,) float64
        Parameters, in parameter units; any shape is flattened.
    derivative : int, optional
        Order k of the derivative, 0..degree (default 0).

    Returns
    -------
    B : (n, count) scipy.sparse.csr_matrix of float64
        Design matrix in parameter units^-k; with control points (count, dim) in mm,
        ``B @ control_points`` is the k-th derivative (n, dim) in mm per parameter unit^k.
        Row r holds degree + 1 non-zeros.

    Raises
    ------
    ValueError
        If `derivative` is not in 0..degree.
    """
    knots = np.asarray(knots, dtype=np.float64)
    count = knots.size - degree - 1
    spans, vals = basis_functions(knots, degree, t, derivative=derivative)
    cols = spans[:, None] - degree + np.arange(degree + 1)[None, :]
    rows = np.repeat(np.arange(spans.size), degree + 1)
    return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(spans.size, count))


def surface_rows(knots_u: np.ndarray, knots_v: np.ndarray, u: np.ndarray, v: np.ndarray, *,
                 degree: tuple[int, int] = (3, 3), du: int = 0, dv: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Give the non-zero entries of each row of the surface design matrix of ∂^(du+dv)S/∂u^du∂v^dv.

    Parameters
    ----------
    knots_u : (nu + p + 1,) float64
        Clamped knot vector in u, in parameter units.
    knots_v : (nv + q + 1,) float64
        Clamped knot vector in v, in parameter units.
    u, v : (n,) float64
        Parameters of the n rows, in parameter units; any shape is flattened.
    degree : tuple of (int, int), optional
        The degrees (p, q) in u and v (default (3, 3)).
    du, dv : int, optional
        Derivative orders in u (0..p) and v (0..q) (default 0).

    Returns
    -------
    cols : (n, m) int64
        Column indices, m = (p + 1)(q + 1); column index i * nv + j follows
        control_points.reshape(-1, 3).
    vals : (n, m) float64
        Products of the basis function derivatives, in parameter units^-(du + dv).

    Raises
    ------
    ValueError
        If `du` is not in 0..p or `dv` is not in 0..q.
    """
    p, q = degree
    if 0 <= du <= min(p, 2) and 0 <= dv <= min(q, 2):
        return design_rows(knots_u, knots_v, u, v, degree, du, dv)  # compiled, the same bits
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
    """Build the sparse design matrix of ∂^(du+dv)S/∂u^du∂v^dv at (u, v).

    Parameters
    ----------
    knots_u : (nu + p + 1,) float64
        Clamped knot vector in u, in parameter units.
    knots_v : (nv + q + 1,) float64
        Clamped knot vector in v, in parameter units.
    u, v : (n,) float64
        Parameters of the n rows, in parameter units; any shape is flattened.
    degree : tuple of (int, int), optional
        The degrees (p, q) in u and v (default (3, 3)).
    du, dv : int, optional
        Derivative orders in u (0..p) and v (0..q) (default 0).

    Returns
    -------
    B : (n, nu * nv) scipy.sparse.csr_matrix of float64
        Design matrix in parameter units^-(du + dv); columns follow control_points.reshape(-1, 3),
        i.e. index i * nv + j, so ``B @ control_points.reshape(-1, 3)`` is the derivative (n, 3) in
        mm per parameter unit^(du + dv).

    Raises
    ------
    ValueError
        If `du` is not in 0..p or `dv` is not in 0..q.
    """
    p, q = degree
    size = (len(knots_u) - p - 1) * (len(knots_v) - q - 1)
    cols, vals = surface_rows(knots_u, knots_v, u, v, degree=degree, du=du, dv=dv)
    rows = np.repeat(np.arange(len(cols)), cols.shape[1])
    return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(len(cols), size))


def evaluate_curve(knots: np.ndarray, control_points: np.ndarray, t: np.ndarray, *, degree: int = 3,
                   derivatives: int = 0) -> list[np.ndarray]:
    """Evaluate a B-spline curve and its derivatives: [C(t), C'(t), ...] up to `derivatives`.

    Parameters
    ----------
    knots : (count + degree + 1,) float64
        Clamped knot vector, in parameter units.
    control_points : (count, dim) float64
        Control points, in mm.
    t : (n,) float64
        Parameters, in parameter units; any shape is flattened.
    degree : int, optional
        Degree p of the curve (default 3).
    derivatives : int, optional
        Highest derivative order, 0..degree (default 0: points only).

    Returns
    -------
    values : list of (n, dim) float64
        ``derivatives + 1`` arrays; entry k is the k-th derivative C^(k)(t), in mm per parameter
        unit^k (the points themselves in mm).

    Raises
    ------
    ValueError
        If `derivatives` exceeds `degree`.
    """
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
    """Evaluate a B-spline control net: points and partial derivatives up to total `order`, in one pass.

    Parameters
    ----------
    knots_u : (nu + p + 1,) float64
        Clamped knot vector in u, in parameter units.
    knots_v : (nv + q + 1,) float64
        Clamped knot vector in v, in parameter units.
    control_points : (nu, nv, 3) float64
        Control net in mm, index [i, j] along u then v.
    u, v : (n,) float64
        Parameters, in parameter units; any shape is flattened.
    degree : tuple of (int, int), optional
        The degrees (p, q) in u and v (default (3, 3)).
    order : int, optional
        Highest total order du + dv (≤ 2, default 2).

    Returns
    -------
    terms : dict of (int, int) to (n, 3) float64
        {(du, dv): ∂^(du+dv)S/∂u^du∂v^dv} in mm per parameter unit^(du + dv) ((0, 0): the points, in
        mm); every du + dv ≤ `order`. Orders beyond the degrees are zero.
    """
    if order not in (0, 1, 2):
        raise ValueError(f"order must be 0, 1 or 2, got {order}")
    cp = np.asarray(control_points, dtype=np.float64)
    if cp.ndim != 3:
        raise ValueError(f"need a control net of shape (nu, nv, d), got {cp.shape}")
    return evaluate_net(knots_u, knots_v, cp, u, v, degree, order)


def span_params(knots: np.ndarray, per_span: int) -> np.ndarray:
    """Give `per_span` evenly spaced parameters in every non-empty knot span, and the end.

    Parameters
    ----------
    knots : (count + degree + 1,) float64
        Knot vector, in parameter units.
    per_span : int
        Parameters per non-empty span, starting at the span's left end.

    Returns
    -------
    t : (k,) float64
        Increasing parameters in parameter units, k = per_span * (number of non-empty spans) + 1;
        the last is the right end of the knot vector.
    """
    breaks = np.unique(np.asarray(knots, dtype=np.float64))
    inner = [np.linspace(a, b, per_span, endpoint=False) for a, b in zip(breaks[:-1], breaks[1:])]
    return np.concatenate(inner + [breaks[-1:]])


def gram_matrix(knots: np.ndarray, degree: int, derivative: int) -> np.ndarray:
    """Compute the Gram matrix G[r, s] = ∫ N_r^(d) N_s^(d) dt over the knot span.

    Exact by Gauss–Legendre (degree + 1 points per non-empty span).

    Parameters
    ----------
    knots : (count + degree + 1,) float64
        Clamped knot vector, in parameter units.
    degree : int
        Degree p of the basis.
    derivative : int
        Order d of the derivative, 0..degree.

    Returns
    -------
    G : (count, count) float64
        Symmetric Gram matrix, in parameter units^(1 - 2d).

    Raises
    ------
    ValueError
        If `derivative` is not in 0..degree.
    """
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
    """Build the thin-plate matrix H with c·Hc = ∫∫ |S_xx|² + 2|S_xy|² + |S_yy|² dx dy per coordinate.

    x = u * length_u and y = v * length_v (mm): scaling the parameters by the patch's side lengths
    makes the energy a bending energy of the part, independent of how long the patch is in
    parameter space, so one smoothing weight suits every patch.

    Parameters
    ----------
    knots_u : (nu + p + 1,) float64
        Clamped knot vector in u, in parameter units.
    knots_v : (nv + q + 1,) float64
        Clamped knot vector in v, in parameter units.
    degree : tuple of (int, int), optional
        The degrees (p, q) in u and v (default (3, 3)); both must be at least 2.
    length_u, length_v : float, optional
        The patch's side lengths in mm (per parameter unit), along u and v (default 1.0).

    Returns
    -------
    H : (nu * nv, nu * nv) scipy.sparse.csr_matrix of float64
        Symmetric positive semi-definite matrix in mm^-2, columns in the order i * nv + j of
        control_points.reshape(-1, 3); for one coordinate c (nu * nv,) in mm, c·Hc is the
        (dimensionless) bending energy.

    Raises
    ------
    ValueError
        If p or q is less than 2.
    """
    p, q = degree
    G0u, G1u, G2u = (sp.csr_matrix(gram_matrix(knots_u, p, d)) for d in range(3))
    G0v, G1v, G2v = (sp.csr_matrix(gram_matrix(knots_v, q, d)) for d in range(3))
    Lu, Lv = float(length_u), float(length_v)
    H = (sp.kron(G2u, G0v) / Lu**4 + 2.0 * sp.kron(G1u, G1v) / (Lu**2 * Lv**2) + sp.kron(G0u, G2v) / Lv**4)
    return (H * (Lu * Lv)).tocsr()
