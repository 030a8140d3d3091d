"""Foot points: where points fall on a B-spline surface, and the surface's differential geometry there.

The squared-distance iteration needs, at every step, each sample's foot point on the current surface
(`project_points`, Newton on |S - p|² from the sample's current parameters) and the frame there
(`foot_frames`: normal, principal directions and curvatures). Measuring a finished surface needs the
same without a starting guess (`distance_to_surface`). Parameters are in the knots' units (grid-index
units in the fit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.spline._compiled import newton_feet
from cam.spline.basis import evaluate_surface, span_params
from cam.spline.pieces import c0_pieces, foot_in_pieces, make_piece_boxes, span_boxes

__all__ = ["FootFrame", "distance_to_surface", "foot_frames", "project_points", "unit_rows"]


def project_points(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, points: np.ndarray,
                   u: np.ndarray, v: np.ndarray, *, degree: tuple[int, int] = (3, 3), iterations: int = 8
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Foot points of `points` on the surface, by Newton's method from (u, v), kept in the domain.

    A step that does not shorten the distance is halved (twice), then dropped, so the distance
    never grows. Across C0 knot lines see `cam.spline.surface.foot_in_pieces`.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's clamped knot vectors, in parameter units.
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    points : ndarray, shape (n, 3), float64
        The points to project, mm.
    u, v : ndarray, shape (n,), float64
        Starting parameters; clipped into the domain.
    degree : tuple of int
        (p, q), the surface's degrees.
    iterations : int
        Newton steps at most.

    Returns
    -------
    u, v : ndarray, shape (n,), float64
        The foot points' parameters, inside the domain.
    distance : ndarray, shape (n,), float64
        Distance from each point to its foot point, mm.
    """
    p, q = degree
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64)
    start = np.stack([np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)], -1).reshape(-1, 2)

    def newton(rows, uv, lo, hi):
        fu, fv, d = _newton(ku, kv, control_points, P[rows], uv[:, 0], uv[:, 1], lo, hi, degree, iterations)
        return np.stack([fu, fv], -1), d

    pieces_u, pieces_v = c0_pieces(ku, p, ku[p], ku[-p - 1]), c0_pieces(kv, q, kv[q], kv[-q - 1])
    bound = None
    if pieces_u.size > 2 or pieces_v.size > 2:
        boxes = make_piece_boxes(ku, kv, control_points, pieces_u, pieces_v, degree=degree)

        def bound(rows, iu, iv):
            return boxes.distance_bound(P[rows], iu, iv)
    uv, d = foot_in_pieces(newton, pieces_u, pieces_v, np.clip(start, [ku[p], kv[q]], [ku[-p - 1], kv[-q - 1]]),
                           lower_bound=bound)
    return uv[:, 0], uv[:, 1], d


def _newton(ku, kv, control_points, P, u, v, lo, hi, degree, iterations):
    """Newton steps for the feet of P (n, 3) from (u, v) (n,), each kept inside its box lo..hi (n, 2);
    returns (u, v, distance), each (n,).

    Each step solves with the Hessian of |S - p|² (Gauss–Newton where it is not positive definite); a
    parameter on its bound whose descent leads out of the box is held there and the step taken in the
    other alone; a step that does not shorten the distance is halved (twice), then dropped; a point stops
    once its step moves it less than 1e-10. Compiled (`cam.spline._compiled`), point by point."""
    return newton_feet(ku, kv, control_points, P, u, v, lo, hi, degree, iterations)


@dataclass(frozen=True, eq=False)
class FootFrame:
    """Differential geometry of a surface at n parameter pairs.

    Attributes
    ----------
    point : ndarray, shape (n, 3), float64
        The surface point, mm.
    normal : ndarray, shape (n, 3), float64
        The unit normal N = S_u x S_v / |S_u x S_v|.
    t1, t2 : ndarray, shape (n, 3), float64
        Unit principal directions (tangent), t2 = N x t1.
    k1, k2 : ndarray, shape (n,), float64
        Their curvatures, 1/mm, positive where the surface bends towards +N; k1 >= k2.
    su, sv : ndarray, shape (n, 3), float64
        The first derivatives S_u and S_v, mm per parameter unit.
    """

    point: np.ndarray
    normal: np.ndarray
    t1: np.ndarray
    t2: np.ndarray
    k1: np.ndarray
    k2: np.ndarray
    su: np.ndarray
    sv: np.ndarray


def foot_frames(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, u: np.ndarray,
                v: np.ndarray, *, degree: tuple[int, int] = (3, 3)) -> FootFrame:
    """Normals, principal directions and curvatures at (u, v) from the fundamental forms.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's clamped knot vectors, in parameter units.
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    u, v : ndarray, shape (n,), float64
        Parameters inside the domain.
    degree : tuple of int
        (p, q), the surface's degrees.

    Returns
    -------
    FootFrame
        Point, normal, principal directions and curvatures, S_u and S_v at each (u, v). A
        degenerate point (S_u parallel to S_v) is treated as flat.
    """
    d = evaluate_surface(knots_u, knots_v, control_points, u, v, degree=degree, order=2)
    su, sv = d[(1, 0)], d[(0, 1)]
    n = unit_rows(np.cross(su, sv))
    E, F, G = (np.einsum("ij,ij->i", a, b) for a, b in ((su, su), (su, sv), (sv, sv)))
    L, M, N = (np.einsum("ij,ij->i", d[k], n) for k in ((2, 0), (1, 1), (0, 2)))
    det = E * G - F**2
    # A degenerate point (S_u parallel to S_v) has no curvature to speak of: treat it as flat.
    flat = ~(det > 1e-12 * E * G) | ~np.isfinite(det)
    det = np.where(flat, 1.0, det)
    L, M, N = (np.where(flat, 0.0, x) for x in (L, M, N))
    # Shape operator W = I^-1 II in the (S_u, S_v) basis.
    w00, w01 = (G * L - F * M) / det, (G * M - F * N) / det
    w10, w11 = (E * M - F * L) / det, (E * N - F * M) / det
    half_trace = 0.5 * (w00 + w11)
    disc = np.sqrt(np.maximum(half_trace**2 - (w00 * w11 - w01 * w10), 0.0))
    k1, k2 = half_trace + disc, half_trace - disc
    # Eigenvector of k1: pick the better conditioned of the two row-derived candidates.
    a1, b1 = w01, k1 - w00
    a2, b2 = k1 - w11, w10
    use2 = (a2**2 + b2**2) > (a1**2 + b1**2)
    a, b = np.where(use2, a2, a1), np.where(use2, b2, b1)
    t1 = a[:, None] * su + b[:, None] * sv
    degenerate = np.linalg.norm(t1, axis=1) < 1e-12 * (np.linalg.norm(su, axis=1) + 1e-300)
    t1 = np.where(degenerate[:, None], su, t1)  # umbilic: any tangent direction is principal
    t1 = unit_rows(t1 - np.einsum("ij,ij->i", t1, n)[:, None] * n)
    t2 = np.cross(n, t1)
    return FootFrame(point=d[(0, 0)], normal=n, t1=t1, t2=t2, k1=k1, k2=k2, su=su, sv=sv)


def distance_to_surface(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray,
                        points: np.ndarray, *, degree: tuple[int, int] = (3, 3), density: int = 4, starts: int = 4,
                        search_above: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance from points to a surface, without a starting guess.

    Starts Newton from the nearest of `density` x `density` samples per knot span, so a
    point far from where any guess would put it still finds its foot point. Where the foot found
    lies on the domain's border, or another of the `starts` nearest samples lies more than a
    sample away from it in the parameter grid, Newton runs from that sample too and the nearest
    foot is kept: the border can hold a local minimum that is not the foot, and the surface can
    come back near the point elsewhere (where a closed surface meets itself at a seam, the
    sample nearest a point can lie on the seam's far side, and Newton stops on that border or
    just inside it).

    search_above (mm): a point whose distance found is still above it is searched span by span:
    Newton runs from nine starts inside every knot span whose control points' box is nearer than
    the foot found (a span lies in that hull), so a distance that decides a verdict does not rest
    on one start.

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's clamped knot vectors, in parameter units.
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    points : ndarray, shape (n, 3), float64
        The points to measure, mm.
    degree : tuple of int
        (p, q), the surface's degrees.
    density : int
        Start samples per knot span, each way.
    starts : int
        How many of the nearest start samples may each run Newton.
    search_above : float or None
        Distance (mm) above which a point is searched span by span; None: never.

    Returns
    -------
    u, v : ndarray, shape (n,), float64
        Parameters of each point's nearest foot found.
    distance : ndarray, shape (n,), float64
        Distance to it, mm.
    """
    from scipy.spatial import cKDTree

    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    gu = span_params(ku, density)
    gv = span_params(kv, density)
    uu, vv = np.meshgrid(gu, gv, indexing="ij")
    uu, vv = uu.ravel(), vv.ravel()
    S = evaluate_surface(ku, kv, control_points, uu, vv, degree=degree, order=0)[(0, 0)]
    m = int(min(max(starts, 1), len(S)))
    nearest = cKDTree(S).query(P, k=m)[1].reshape(len(P), m)
    u, v, d = project_points(ku, kv, control_points, P, uu[nearest[:, 0]], vv[nearest[:, 0]], degree=degree)
    p, q = degree
    for j in range(1, m):
        # Grid cells of the foot and of the j-th start (row-major, as `nearest` indexes them).
        fi = np.searchsorted(gu, u) - 0.5
        fj = np.searchsorted(gv, v) - 0.5
        si, sj = np.divmod(nearest[:, j], gv.size)
        on_border = (u <= ku[p]) | (u >= ku[-p - 1]) | (v <= kv[q]) | (v >= kv[-q - 1])
        rows = np.flatnonzero(on_border | (np.abs(si - fi) > 1.5) | (np.abs(sj - fj) > 1.5))
        if not rows.size:
            continue
        s = nearest[rows, j]
        fu, fv, fd = project_points(ku, kv, control_points, P[rows], uu[s], vv[s], degree=degree)
        better = fd < d[rows]
        rows = rows[better]
        u[rows], v[rows], d[rows] = fu[better], fv[better], fd[better]
    if search_above is not None:
        rows = np.flatnonzero(d > search_above)
        if rows.size:
            u[rows], v[rows], d[rows] = _search_spans(ku, kv, control_points, P[rows], u[rows], v[rows], d[rows],
                                                      degree)
    return u, v, d


def _search_spans(ku, kv, control_points, P, u, v, d, degree, chunk: int = 1_000_000):
    """Improve feet (u, v, d, each (n,), updated in place and returned) of points P (n, 3) by Newton
    inside every knot span whose control-point box is nearer than d, from nine points of the span."""
    p, q = degree
    cp = np.asarray(control_points, dtype=np.float64)
    nu, nv = cp.shape[:2]
    su, sv, lo_all, hi_all = span_boxes(ku, kv, cp, degree=degree)
    i, j = (a.ravel() for a in np.meshgrid(su, sv, indexing="ij"))
    box_lo, box_hi = lo_all[i, j], hi_all[i, j]  # (spans, 3)
    # The span's own derivatives hold up to its end, not at a C0 knot there: approach it from below.
    lo = np.stack([ku[i + p], kv[j + q]], -1)
    hi = np.stack([np.where(i + p + 1 < nu, np.nextafter(ku[i + p + 1], -np.inf), ku[i + p + 1]),
                   np.where(j + q + 1 < nv, np.nextafter(kv[j + q + 1], -np.inf), kv[j + q + 1])], -1)
    rows, spans = [], []
    step = max(1, chunk // max(len(i), 1))
    for c in range(0, len(P), step):
        x = P[c:c + step, None, :]
        gap = np.maximum(np.maximum(box_lo - x, x - box_hi), 0.0)
        r, k = np.nonzero(np.sqrt(np.einsum("nki,nki->nk", gap, gap)) < d[c:c + step, None])
        rows.append(r + c)
        spans.append(k)
    rows, spans = np.concatenate(rows), np.concatenate(spans)
    if not rows.size:
        return u, v, d
    # Nine starts per span (a folded span holds more than one local minimum).
    f = np.array([1 / 6, 1 / 2, 5 / 6])
    fu_, fv_ = (a.ravel() for a in np.meshgrid(f, f, indexing="ij"))
    rows, spans = np.repeat(rows, fu_.size), np.repeat(spans, fu_.size)
    w = np.stack([np.tile(fu_, rows.size // fu_.size), np.tile(fv_, rows.size // fu_.size)], -1)
    start = lo[spans] + w * (hi[spans] - lo[spans])
    fu, fv, fd = _newton(ku, kv, cp, P[rows], start[:, 0], start[:, 1], lo[spans], hi[spans], degree, 12)
    order = np.argsort(fd, kind="stable")[::-1]  # nearest last, so it is the one written
    rows, fu, fv, fd = rows[order], fu[order], fv[order], fd[order]
    better = fd < d[rows]
    u[rows[better]], v[rows[better]], d[rows[better]] = fu[better], fv[better], fd[better]
    return u, v, d


def unit_rows(a: np.ndarray) -> np.ndarray:
    """Vectors scaled to unit length.

    Parameters
    ----------
    a : ndarray, shape (..., k), float64
        Vectors along the last axis.

    Returns
    -------
    ndarray, shape (..., k), float64
        Each vector over its length; a zero vector stays zero.
    """
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)
