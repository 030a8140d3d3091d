"""Pieces of a B-spline surface between its C0 knot lines, and bounding boxes for searching foot points.

A border that turns a corner is a knot line of full multiplicity: the surface is only C0 there, and a
Newton search for the closest point must not step across it. `c0_pieces` cuts the domain there,
`make_piece_boxes` bounds each piece (its control points' hull), and `foot_in_pieces` runs a foot-point
search inside every piece whose box can still hold a closer point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.spline._compiled import box_bounds, window_boxes

__all__ = ["PieceBoxes", "c0_knots", "c0_pieces", "foot_in_pieces", "make_piece_boxes", "span_boxes"]


def c0_knots(knots: np.ndarray, degree: int) -> np.ndarray:
    """Interior knot values of multiplicity >= degree: where the curve or surface is only C0.

    Such a knot is a border that turns a corner; derivatives jump there.

    Parameters
    ----------
    knots : (count + degree + 1,) array_like of float
        A clamped knot vector (parameter units).
    degree : int
        Its degree.

    Returns
    -------
    values : (k,) float64
        The distinct interior knot values repeated at least `degree` times, sorted.
    """
    values, counts = np.unique(np.asarray(knots, dtype=np.float64)[degree + 1:-degree - 1], return_counts=True)
    return values[counts >= degree]


def c0_pieces(knots: np.ndarray, degree: int, lo: float, hi: float) -> np.ndarray:
    """The ends of the pieces of [lo, hi] between C0 lines, sorted.

    Parameters
    ----------
    knots : (count + degree + 1,) array_like of float
        A clamped knot vector (parameter units).
    degree : int
        Its degree.
    lo, hi : float
        The parameter interval to cut, lo < hi.

    Returns
    -------
    ends : (k + 2,) float64
        The start lo, the C0 knots (`c0_knots`) strictly inside (lo, hi), then the end hi.
    """
    inner = c0_knots(knots, degree)
    return np.concatenate([[lo], inner[(inner > lo) & (inner < hi)], [hi]])


@dataclass(frozen=True, eq=False)
class PieceBoxes:
    """Boxes around the control points of every knot span, grouped by the piece between C0 lines that the
    span lies in (see `make_piece_boxes`).

    Attributes
    ----------
    lo, hi : (m, 3) float64
        Lower and upper corners in mm of the boxes, one row per non-empty knot span, piece by piece:
        piece k = iu * pieces_v + iv holds rows starts[k] .. starts[k + 1] (none, for some pieces).
    starts : (pieces + 1,) int64
        Where each piece's rows begin.
    pieces_v : int
        Number of pieces along v.
    """

    lo: np.ndarray
    hi: np.ndarray
    starts: np.ndarray
    pieces_v: int

    def distance_bound(self, points: np.ndarray, iu: np.ndarray, iv: np.ndarray) -> np.ndarray:
        """A lower bound on the distance from each point to the piece (iu, iv).

        Parameters
        ----------
        points : (k, 3) float64
            Points in mm, in the frame of the control points.
        iu, iv : (k,) int
            The piece of each point, indices into the pieces along u and v.

        Returns
        -------
        bound : (k,) float64
            Distance in mm to the nearest box of the piece; inf for a piece without spans.
        """
        key = np.asarray(iu) * self.pieces_v + np.asarray(iv)
        return box_bounds(points, key, self.lo, self.hi, self.starts)


def span_boxes(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, *,
               degree: tuple[int, int] = (3, 3)) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes around the control points acting on each knot span (a span lies in their convex hull).

    Parameters
    ----------
    knots_u : (nu + p + 1,) array_like of float
        Clamped knot vector in u.
    knots_v : (nv + q + 1,) array_like of float
        Clamped knot vector in v.
    control_points : (nu, nv, 3) array_like of float
        Control net in mm.
    degree : tuple of (int, int), optional
        The degrees (p, q) (default (3, 3)).

    Returns
    -------
    su : (a,) int64
        The u spans of positive length: span i runs over knots_u[i + p] .. knots_u[i + p + 1].
    sv : (b,) int64
        Likewise in v: span j runs over knots_v[j + q] .. knots_v[j + q + 1].
    lo, hi : (nu - p, nv - q, 3) float64
        Box corners in mm, indexed by (i, j) for every window of (p + 1) x (q + 1) control points,
        including those of empty spans.
    """
    p, q = degree
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    cp = np.asarray(control_points, dtype=np.float64)
    nu, nv = cp.shape[:2]
    su = np.flatnonzero(ku[p:nu] < ku[p + 1:nu + 1])
    sv = np.flatnonzero(kv[q:nv] < kv[q + 1:nv + 1])
    return su, sv, *window_boxes(cp, degree)


def make_piece_boxes(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray,
                     pieces_u: np.ndarray, pieces_v: np.ndarray, *, degree: tuple[int, int] = (3, 3)) -> PieceBoxes:
    """The boxes that bound each piece between C0 lines from below, for `foot_in_pieces`.

    A knot span of a B-spline surface lies in the convex hull of the (p+1) x (q+1) control points that
    act on it, so the distance to the box around them bounds the distance to the span from below, and
    the nearest box of a piece's spans bounds the piece. It lets `foot_in_pieces` skip the Newton runs
    in neighbouring pieces that cannot hold a nearer foot, which is nearly all of them.

    Parameters
    ----------
    knots_u : (nu + p + 1,) array_like of float
        Clamped knot vector in u, as in `BSplineSurface`.
    knots_v : (nv + q + 1,) array_like of float
        Clamped knot vector in v.
    control_points : (nu, nv, 3) array_like of float
        Control net in mm.
    pieces_u, pieces_v : (a,), (b,) array_like of float
        Piece ends along u and v, from `c0_pieces`.
    degree : tuple of (int, int), optional
        The degrees (p, q) (default (3, 3)).

    Returns
    -------
    boxes : PieceBoxes
        (a - 1) * (b - 1) pieces; use `PieceBoxes.distance_bound` as the `lower_bound` of
        `foot_in_pieces`.
    """
    p, q = degree
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    su, sv, lo_all, hi_all = span_boxes(ku, kv, control_points, degree=degree)
    bu, bv = np.asarray(pieces_u, dtype=np.float64), np.asarray(pieces_v, dtype=np.float64)
    # The piece a span belongs to: the one its midpoint falls in (spans never straddle a C0 line).
    piece_u = np.clip(np.searchsorted(bu, 0.5 * (ku[su + p] + ku[su + p + 1]), side="right") - 1, 0, bu.size - 2)
    piece_v = np.clip(np.searchsorted(bv, 0.5 * (kv[sv + q] + kv[sv + q + 1]), side="right") - 1, 0, bv.size - 2)
    lo, hi, counts = [], [], []
    for a in range(bu.size - 1):
        for b in range(bv.size - 1):
            i, j = np.ix_(su[piece_u == a], sv[piece_v == b])
            lo.append(lo_all[i, j].reshape(-1, 3))
            hi.append(hi_all[i, j].reshape(-1, 3))
            counts.append(len(lo[-1]))
    return PieceBoxes(np.concatenate(lo), np.concatenate(hi), np.r_[0, np.cumsum(counts)].astype(np.int64), bv.size - 1)


def foot_in_pieces(newton, pieces_u: np.ndarray, pieces_v: np.ndarray, uv: np.ndarray, *, rounds: int = 2,
                   lower_bound=None) -> tuple[np.ndarray, np.ndarray]:
    """Foot points by a Newton method run piece by piece between C0 lines.

    At a C0 line the derivatives jump and Newton can settle on the line (or on a border of the wrong
    piece) short of the foot. So each run stays inside one piece, whose derivatives hold up to its edge;
    the method also runs from the start in each piece next to the start's, and a foot that ends on an
    edge of its piece is tried again from the pieces next to it (up to `rounds` times), the nearest foot
    kept.

    Parameters
    ----------
    newton : callable
        ``newton(rows, uv, lo, hi) -> (uv, distance)`` runs the method for those rows inside the
        parameter boxes lo..hi: rows (k,) int, uv (k, 2) float starts, lo and hi (k, 2) float; it returns
        the feet uv (k, 2) and their distances (k,) (mm).
    pieces_u, pieces_v : (a,), (b,) array_like of float
        Piece ends along u and v, from `c0_pieces`.
    uv : (n, 2) array_like of float
        The starting parameters.
    rounds : int, optional
        How many times feet left on an edge of their piece are tried again from the pieces next to it
        (default 2).
    lower_bound : callable or None, optional
        ``lower_bound(rows, iu, iv) -> (k,)``: a bound on the distance from those rows' points to the
        pieces (iu, iv), such as `PieceBoxes.distance_bound`; a piece whose bound is not below the
        distance found so far is not tried (the answer is the same, found with fewer runs).

    Returns
    -------
    uv : (n, 2) float
        The nearest feet found, in parameters.
    distance : (n,) float
        Their distances, as `newton` measures them (mm).
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
