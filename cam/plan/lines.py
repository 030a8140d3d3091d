"""Ball-centre polylines that follow the part within a chord tolerance and never cut it.

A pass is planned as points whose ball centres come from the drop-cutter; between two of them the
ball moves straight. Where the true drop-cutter height at the middle of a move is above the straight
line, the move would cut the part; where it is more than the chord tolerance below, the move would
leave that much more material than the points show. Either way the middle point is inserted, and the
halves are checked again.
"""

from __future__ import annotations

import numpy as np

from cam.plan.part import SetupPart

__all__ = ["GOUGE_TOL_MM", "follow_part", "merge_straight", "ride_over", "split_runs"]

#: A straight move may reach this far into the part between its ends (float round-off, not a budget).
GOUGE_TOL_MM = 1e-4


def split_runs(keep: np.ndarray, *, min_length: int = 2) -> list[slice]:
    """Maximal runs of True in a bool (n,) array, as slices, those of at least `min_length` elements."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    return [slice(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= min_length]


def follow_part(part: SetupPart, centres: np.ndarray, *, chord_mm: float, lift_mm: float = 0.0, max_depth: int = 12
                ) -> tuple[np.ndarray, float]:
    """Insert drop-cutter points into a centre polyline until every move follows the part.

    Parameters
    ----------
    part : SetupPart
        The part in the polyline's (machine) frame, for the ball.
    centres : (n, 3) float
        Ball centres of the pass, mm, each on the drop-cutter height of its xy.
    chord_mm : float
        Largest height a straight move may leave above the drop-cutter height under its middle.
    lift_mm : float
        Height the points are put above the drop-cutter height (the given ones raised by it). A move
        over a convex stretch sags below its ends; on points lifted this much it may sag that far before
        it cuts, so it can be much longer than on points on the height itself. The lift is material left
        and counts in the chord share: keep it at most half of `chord_mm`.
    max_depth : int
        Halvings at most; moves still off after them are left as they are and reported.

    Returns
    -------
    centres : (m, 3) float64
        The refined polyline.
    chord : float
        The largest deviation of a move's middle from the drop-cutter height still left, mm (below the
        line: material the move leaves; above it only within `GOUGE_TOL_MM`).
    """
    pts = np.asarray(centres, dtype=np.float64) + np.array([0.0, 0.0, lift_mm])
    for _ in range(max_depth + 1):
        if len(pts) < 2:
            return pts, 0.0
        mid = 0.5 * (pts[:-1] + pts[1:])
        z = part.drop(mid[:, :2])
        gap = mid[:, 2] - z  # > 0: the move passes above the part's height there, leaving material
        bad = (gap > chord_mm) | (gap < -GOUGE_TOL_MM)
        if not bad.any() or _ == max_depth:
            return pts, float(np.max(np.abs(gap), initial=0.0))
        pts = np.insert(pts, np.flatnonzero(bad) + 1, np.column_stack([mid[bad, :2], z[bad] + lift_mm]), axis=0)
    return pts, 0.0


def merge_straight(points: np.ndarray, *, tol_mm: float = 0.5 * GOUGE_TOL_MM) -> np.ndarray:
    """Drop the points of a polyline that lie within `tol_mm` of the straight move that replaces them
    (Douglas–Peucker: a flat stretch of a raster becomes one move).

    Parameters
    ----------
    points : (n, 3) float
        The polyline, mm.
    tol_mm : float

    Returns
    -------
    (m, 3) float64
        The kept points, the ends among them; every dropped point lies within `tol_mm` of the move between
        the kept points on either side of it.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 3:
        return pts
    keep = np.zeros(len(pts), dtype=bool)
    keep[[0, -1]] = True
    stack = [(0, len(pts) - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        a, ab, p = pts[i], pts[j] - pts[i], pts[i + 1:j]
        t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
        d = np.linalg.norm(p - (a + t[:, None] * ab), axis=1)
        k = int(np.argmax(d))
        if d[k] > tol_mm:
            keep[i + 1 + k] = True
            stack += [(i, i + 1 + k), (i + 1 + k, j)]
    return pts[keep]


def ride_over(part: SetupPart, a: np.ndarray, b: np.ndarray, *, budget_mm: float) -> np.ndarray | None:
    """Ball centres of a link from centre a (3,) to centre b (3,) that rides over the part where the straight
    move would cut it: the straight line raised to the drop-cutter height wherever that is higher.

    Between two passes on a convex stretch (a waterline's end on a rounded wall, the next level's start) the
    straight move cuts, and a lift and plunge would cost more feed than the link itself. Beside a steep wall
    a slanted move between two heights cuts the wall's edge however finely it is split; such a move is made
    as a climb then a move across, or a move across then a descent.

    Returns
    -------
    (k, 3) float64 or None
        The link after a, b last, mm; None where it is longer than `budget_mm` or a move of it does not
        clear the part within `GOUGE_TOL_MM`.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    straight = float(np.linalg.norm(b - a))
    if straight > budget_mm:
        return None
    # Raised at points a sixth of the ball apart; `follow_part` splits the moves that still cut.
    n = max(int(np.ceil(straight / (part.radius_mm / 6.0))), 1)
    line = a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)
    line[1:-1, 2] = np.maximum(line[1:-1, 2], part.drop(line[1:-1, :2]))
    path = _square_where_cut(part, follow_part(part, line, chord_mm=np.inf)[0])
    # Merged, a move beside a steep wall may sink further than the check allows: then merged more finely,
    # or the points as found.
    for candidate in (merge_straight(path), merge_straight(path, tol_mm=0.05 * GOUGE_TOL_MM), path):
        if float(np.linalg.norm(np.diff(candidate, axis=0), axis=1).sum()) > budget_mm:
            return None
        if _clear(part, candidate).all():
            return candidate[1:]
    return None


def _clear(part: SetupPart, path: np.ndarray) -> np.ndarray:
    """bool (n - 1,): whether each move of the centre polyline (n, 3) clears the part within `GOUGE_TOL_MM`."""
    return part.clear_moves(path[:-1], path[1:], tol_mm=GOUGE_TOL_MM)


def _square_where_cut(part: SetupPart, path: np.ndarray) -> np.ndarray:
    """The centre polyline (n, 3) with each move that cuts made as two: the vertical one first where it
    climbs, last where it descends, so that it is made where the ball stands at or above the part."""
    ok = _clear(part, path)
    out = [path[0]]
    for p, q, fine in zip(path[:-1], path[1:], ok, strict=True):
        if not fine:
            out.append(np.array([p[0], p[1], q[2]]) if q[2] > p[2] else np.array([q[0], q[1], p[2]]))
        out.append(q)
    return np.array(out)
