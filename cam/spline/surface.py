"""Tensor-product B-spline surfaces: the record every later stage shares, and its evaluation.

`make_bspline_surface` validates once; `BSplineSurface.evaluate` gives points
and partial derivatives (for curvature and normals) through SciPy's `NdBSpline`.
Coordinates are millimetres in the part frame; parameters run over the
clamped knot span, normally [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.interpolate import NdBSpline


@dataclass(frozen=True, eq=False)
class BSplineSurface:
    """A non-rational B-spline surface.

    degree: (p, q); knots_u: float64 (nu + p + 1,), knots_v: float64 (nv + q + 1,), both clamped;
    control_points: float64 (nu, nv, 3) in mm, index [i, j] along u then v.
    """

    degree: tuple[int, int]
    knots_u: np.ndarray
    knots_v: np.ndarray
    control_points: np.ndarray
    _spline: NdBSpline = field(repr=False, compare=False)

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        p, q = self.degree
        return ((float(self.knots_u[p]), float(self.knots_u[-p - 1])),
                (float(self.knots_v[q]), float(self.knots_v[-q - 1])))

    def evaluate(self, u: np.ndarray, v: np.ndarray, *, du: int = 0, dv: int = 0) -> np.ndarray:
        """Points (du = dv = 0) or partial derivatives ∂^(du+dv)S/∂u^du∂v^dv at parameters.

        u, v: float arrays of one shape (...); returns float64 (..., 3), mm per parameter unit^(du+dv).
        """
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        if u.shape != v.shape:
            raise ValueError(f"u and v must have one shape, got {u.shape} and {v.shape}")
        (u0, u1), (v0, v1) = self.domain
        # Clip by a hair: round-off just outside the clamped span would extrapolate.
        uv = np.stack([np.clip(u, u0, u1), np.clip(v, v0, v1)], axis=-1).reshape(-1, 2)
        out = self._spline(uv, nu=(du, dv))
        return np.asarray(out, dtype=np.float64).reshape(u.shape + (3,))

    def normals(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit normals S_u × S_v, float64 (..., 3); NaN where the surface is degenerate."""
        n = np.cross(self.evaluate(u, v, du=1), self.evaluate(u, v, dv=1))
        length = np.linalg.norm(n, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(length > 0, n / length, np.nan)

    def to_json(self) -> dict[str, Any]:
        """DESIGN's `surfaces.json` fields for one surface (without `patch` and errors)."""
        return {"degree": list(self.degree), "knots_u": self.knots_u.tolist(), "knots_v": self.knots_v.tolist(),
                "control_points": self.control_points.tolist()}


def _check_knots(name: str, knots: np.ndarray, degree: int, count: int) -> None:
    if knots.ndim != 1 or knots.size != count + degree + 1:
        raise ValueError(f"{name} needs {count + degree + 1} values for {count} control points of degree "
                         f"{degree}, got {knots.size}")
    if not np.all(np.isfinite(knots)) or np.any(np.diff(knots) < 0):
        raise ValueError(f"{name} must be finite and non-decreasing")
    if np.any(knots[: degree + 1] != knots[0]) or np.any(knots[-degree - 1:] != knots[-1]):
        raise ValueError(f"{name} must be clamped: its first and last {degree + 1} values repeated")
    if knots[-1] <= knots[0]:
        raise ValueError(f"{name} spans no interval: [{knots[0]}, {knots[-1]}]")
    inner = knots[degree + 1: -degree - 1]
    if inner.size and np.max(np.unique(inner, return_counts=True)[1]) > degree:
        raise ValueError(f"{name} has an interior knot repeated more than {degree} times (a break in the surface)")


def make_bspline_surface(control_points: Any, knots_u: Any, knots_v: Any, *,
                         degree: tuple[int, int] = (3, 3)) -> BSplineSurface:
    """Build a validated surface; raises ValueError naming what is wrong."""
    cp = np.asarray(control_points, dtype=np.float64)
    if cp.ndim != 3 or cp.shape[2] != 3:
        raise ValueError(f"control_points must have shape (nu, nv, 3), got {cp.shape}")
    if not np.all(np.isfinite(cp)):
        raise ValueError("control_points contain NaN or Inf")
    p, q = (int(d) for d in degree)
    if p < 1 or q < 1:
        raise ValueError(f"degrees must be at least 1, got {degree}")
    if cp.shape[0] <= p or cp.shape[1] <= q:
        raise ValueError(f"degree {degree} needs more than {p} x {q} control points, got {cp.shape[:2]}")
    ku = np.asarray(knots_u, dtype=np.float64)
    kv = np.asarray(knots_v, dtype=np.float64)
    _check_knots("knots_u", ku, p, cp.shape[0])
    _check_knots("knots_v", kv, q, cp.shape[1])
    spline = NdBSpline((ku, kv), cp, (p, q), extrapolate=False)
    return BSplineSurface(degree=(p, q), knots_u=ku, knots_v=kv, control_points=cp, _spline=spline)


def clamped_uniform_knots(count: int, degree: int = 3) -> np.ndarray:
    """Clamped uniform knots on [0, 1] for `count` control points: float64 (count + degree + 1,)."""
    if count <= degree:
        raise ValueError(f"{count} control points are too few for degree {degree}")
    inner = np.linspace(0.0, 1.0, count - degree + 1)
    return np.concatenate([np.zeros(degree), inner, np.ones(degree)])


def c0_knots(knots: np.ndarray, degree: int) -> np.ndarray:
    """Interior knot values of multiplicity >= degree, sorted: where the curve or surface is only C0
    (a border that turns a corner; its derivatives jump there)."""
    values, counts = np.unique(np.asarray(knots, dtype=np.float64)[degree + 1:-degree - 1], return_counts=True)
    return values[counts >= degree]


def c0_pieces(knots: np.ndarray, degree: int, lo: float, hi: float) -> np.ndarray:
    """lo, the C0 lines strictly inside (lo, hi), hi: the ends of the pieces of [lo, hi], sorted."""
    inner = c0_knots(knots, degree)
    return np.concatenate([[lo], inner[(inner > lo) & (inner < hi)], [hi]])


@dataclass(frozen=True, eq=False)
class PieceBoxes:
    """Boxes around the control points of every knot span, grouped by the piece between C0 lines
    that the span lies in (see `make_piece_boxes`): lo[k], hi[k] float64 (m, 3) mm for piece
    k = iu * pieces_v + iv."""

    lo: tuple[np.ndarray, ...]
    hi: tuple[np.ndarray, ...]
    pieces_v: int

    def distance_bound(self, points: np.ndarray, iu: np.ndarray, iv: np.ndarray) -> np.ndarray:
        """A lower bound on the distance from each of points (k, 3) to the piece (iu, iv): float64 (k,) mm."""
        out = np.full(len(points), np.inf)
        key = np.asarray(iu) * self.pieces_v + np.asarray(iv)
        for k in np.unique(key):
            lo, hi = self.lo[k], self.hi[k]
            if not len(lo):
                continue
            at = np.flatnonzero(key == k)
            step = max(1, 2_000_000 // len(lo))  # points per chunk: about 50 MB of gaps
            for c in range(0, at.size, step):
                sel = at[c:c + step]
                x = points[sel][:, None, :]
                gap = np.maximum(np.maximum(lo - x, x - hi), 0.0)
                out[sel] = np.sqrt(np.min(np.einsum("kmi,kmi->km", gap, gap), axis=1))
        return out


def span_boxes(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, *,
               degree: tuple[int, int] = (3, 3)) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes around the control points acting on each knot span (a span lies in their convex hull).

    Returns su, sv int (the spans of positive length: span (i, j) runs over knots_u[i + p] ..
    knots_u[i + p + 1] and likewise in v) and lo, hi float64 (nu - p, nv - q, 3) mm, indexed by
    (i, j) for every window of control points, including those of empty spans.
    """
    p, q = degree
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    cp = np.asarray(control_points, dtype=np.float64)
    nu, nv = cp.shape[:2]
    nets = np.lib.stride_tricks.sliding_window_view(cp, (p + 1, q + 1), axis=(0, 1))  # (nu-p, nv-q, 3, p+1, q+1)
    su = np.flatnonzero(ku[p:nu] < ku[p + 1:nu + 1])
    sv = np.flatnonzero(kv[q:nv] < kv[q + 1:nv + 1])
    return su, sv, nets.min(axis=(3, 4)), nets.max(axis=(3, 4))


def make_piece_boxes(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray,
                     pieces_u: np.ndarray, pieces_v: np.ndarray, *, degree: tuple[int, int] = (3, 3)) -> PieceBoxes:
    """The boxes that bound each piece between C0 lines from below, for `foot_in_pieces`.

    A knot span of a B-spline surface lies in the convex hull of the (p+1) x (q+1) control points
    that act on it, so the distance to the box around them bounds the distance to the span from
    below, and the nearest box of a piece's spans bounds the piece. It lets `foot_in_pieces` skip
    the Newton runs in neighbouring pieces that cannot hold a nearer foot, which is nearly all of them.
    knots, control_points (nu, nv, 3) and degree as in `BSplineSurface`; pieces_u/v from `c0_pieces`.
    """
    p, q = degree
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    su, sv, lo_all, hi_all = span_boxes(ku, kv, control_points, degree=degree)
    bu, bv = np.asarray(pieces_u, dtype=np.float64), np.asarray(pieces_v, dtype=np.float64)
    # The piece a span belongs to: the one its midpoint falls in (spans never straddle a C0 line).
    piece_u = np.clip(np.searchsorted(bu, 0.5 * (ku[su + p] + ku[su + p + 1]), side="right") - 1, 0, bu.size - 2)
    piece_v = np.clip(np.searchsorted(bv, 0.5 * (kv[sv + q] + kv[sv + q + 1]), side="right") - 1, 0, bv.size - 2)
    lo, hi = [], []
    for a in range(bu.size - 1):
        for b in range(bv.size - 1):
            i, j = np.ix_(su[piece_u == a], sv[piece_v == b])
            lo.append(lo_all[i, j].reshape(-1, 3))
            hi.append(hi_all[i, j].reshape(-1, 3))
    return PieceBoxes(tuple(lo), tuple(hi), bv.size - 1)


def foot_in_pieces(newton, pieces_u: np.ndarray, pieces_v: np.ndarray, uv: np.ndarray, *, rounds: int = 2,
                   lower_bound=None) -> tuple[np.ndarray, np.ndarray]:
    """Foot points by a Newton method run piece by piece between C0 lines.

    At a C0 line the derivatives jump and Newton can settle on the line (or on a border of the
    wrong piece) short of the foot. So each run stays inside one piece, whose derivatives hold up
    to its edge; the method also runs from the start in each piece next to the start's, and a foot
    that ends on an edge of its piece is tried again from the pieces next to it (up to `rounds`
    times), the nearest foot kept.
    newton(rows int (k,), uv (k, 2), lo (k, 2), hi (k, 2)) -> (uv (k, 2), distance (k,)) runs the
    method for those rows inside the boxes lo..hi; pieces_u/v from `c0_pieces`; uv (n, 2) the starts.
    lower_bound(rows, iu, iv) -> (k,): a bound on the distance from those rows' points to the
    pieces (iu, iv), such as `PieceBoxes.distance_bound`; a piece whose bound is not below the
    distance found so far is not tried (the answer is the same, found with fewer runs).
    Returns uv (n, 2) and distance (n,).
    """
    bu, bv = np.asarray(pieces_u, dtype=np.float64), np.asarray(pieces_v, dtype=np.float64)

    def box(iu, iv):
        # A piece that ends at a C0 line is approached from below, so the span evaluated there (and
        # its derivatives) are the piece's own; the position is the same up to round-off.
        hi_u = np.where(iu + 2 < bu.size, np.nextafter(bu[iu + 1], -np.inf), bu[iu + 1])
        hi_v = np.where(iv + 2 < bv.size, np.nextafter(bv[iv + 1], -np.inf), bv[iv + 1])
        return np.stack([bu[iu], bv[iv]], -1), np.stack([hi_u, hi_v], -1)

    start = np.asarray(uv, dtype=np.float64)
    iu = np.clip(np.searchsorted(bu, start[:, 0], side="right") - 1, 0, bu.size - 2)
    iv = np.clip(np.searchsorted(bv, start[:, 1], side="right") - 1, 0, bv.size - 2)
    uv, d = newton(np.arange(len(start)), start, *box(iu, iv))
    if bu.size == 2 and bv.size == 2:
        return uv, d
    # First from the start in every piece next to the start's (the start's piece may hold only a local
    # minimum inside it), then from feet left on an edge of their piece into the piece across.
    todo, origin = np.arange(len(start)), start
    for _ in range(1 + rounds):
        found = False
        for su, sv in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            ju, jv = iu[todo] + su, iv[todo] + sv
            ok = (ju >= 0) & (ju <= bu.size - 2) & (jv >= 0) & (jv <= bv.size - 2)
            rows, ju, jv = todo[ok], ju[ok], jv[ok]
            if lower_bound is not None and rows.size:
                near = lower_bound(rows, ju, jv) < d[rows]
                rows, ju, jv = rows[near], ju[near], jv[near]
            if not rows.size:
                continue
            q, dq = newton(rows, origin[rows], *box(ju, jv))
            better = dq < d[rows]
            rows = rows[better]
            uv[rows], d[rows], iu[rows], iv[rows] = q[better], dq[better], ju[better], jv[better]
            found |= bool(better.any())
        if not found:
            break
        lo, hi = box(iu, iv)
        todo, origin = np.flatnonzero(np.any((uv <= lo) | (uv >= hi), axis=1)), uv.copy()
    return uv, d


def surface_from_json(data: dict[str, Any]) -> BSplineSurface:
    """Inverse of `BSplineSurface.to_json` (reads one entry of `surfaces.json`)."""
    return make_bspline_surface(data["control_points"], data["knots_u"], data["knots_v"],
                                degree=tuple(data.get("degree", (3, 3))))


# The grid the planner checks a surface for folds (and hollows) on before it plans it. The fit reports
# folds on the same grid, so that surfaces.json names every fold the planner then leaves out; its own
# iterations compare folds on the default 33 x 33 grid, a quarter of the cost.
FOLD_CHECK_SAMPLES = 65


def fold_mask(surface: BSplineSurface, *, samples: int = 33) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where a surface folds over itself on a samples x samples parameter grid.

    A regular patch keeps the direction of S_u x S_v; a fold reverses it, and there normals,
    curvature and every offset built on them are meaningless. A sample is marked when its normal
    points against a grid neighbour's; samples where S_u x S_v vanishes (a degenerate corner) are
    not. Returns (bool mask, u, v), each (samples, samples).
    """
    (u0, u1), (v0, v1) = surface.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, samples), np.linspace(v0, v1, samples), indexing="ij")
    n = np.cross(surface.evaluate(uu, vv, du=1), surface.evaluate(uu, vv, dv=1))
    folded = flipped_normals(n)
    return folded, uu, vv


def flipped_normals(normals: np.ndarray) -> np.ndarray:
    """bool (a, b): samples of a grid of normals float (a, b, 3) that point against a grid neighbour's.

    The normals need not be unit; those of vanishing length (a degenerate corner) are not marked.
    """
    n = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(n, axis=-1)
    ok = length > 1e-9 * max(float(np.median(length)), 1e-300)
    n = n / np.where(ok, length, 1.0)[..., None]
    folded = np.zeros(ok.shape, dtype=bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        flip = (np.einsum("ijk,ijk->ij", n[tuple(a)], n[tuple(b)]) < 0) & ok[tuple(a)] & ok[tuple(b)]
        folded[tuple(a)] |= flip
        folded[tuple(b)] |= flip
    return folded


def find_folds(surface: BSplineSurface, *, samples: int = 33) -> tuple[float, np.ndarray | None]:
    """The share of a samples x samples parameter grid where the surface folds (`fold_mask`), and
    one such point: (fraction in [0, 1], float64 (3,) mm or None)."""
    folded, uu, vv = fold_mask(surface, samples=samples)
    if not folded.any():
        return 0.0, None
    i = np.unravel_index(np.argmax(folded), folded.shape)
    return float(folded.mean()), surface.evaluate(uu[i], vv[i])
