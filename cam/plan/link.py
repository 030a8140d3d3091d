"""Linking: patch order, staying down or retracting, and the move list of one setup (tool tips, machine frame).

Between passes of one patch the tool stays down when the straight move is short and clears the part;
otherwise, and always between patches, it retracts to the clearance height, moves across in rapid,
comes down in rapid to `retract_mm` above the next start and plunges at the plunge feed. Patches are
visited greedily, each next the one whose entry is nearest to the current exit, which cuts air time.
`link_on_part` links whole-part programs the same way, except that a link rises only as high as the part
under its straight line needs (the rapid margin kept), not to the clearance height, and that where a
straight move would cut, the tool may instead ride over the part at feed when that is shorter than the
lift and plunge it replaces.
"""

from __future__ import annotations

import numpy as np

from cam.gcode.moves import FEED, PLUNGE, RAPID, MoveList

__all__ = ["link_on_part", "link_passes", "order_passes", "order_patches"]


def order_patches(entries: np.ndarray, exits: np.ndarray, *, start: np.ndarray | None = None) -> list[int]:
    """Greedy nearest-neighbour order of k patches: entries, exits float (k, 3) → indices.

    Each next patch is the one whose entry is nearest, in x and y only, to the current exit.

    Parameters
    ----------
    entries : (k, 3) float
        First tool tip of each patch, mm.
    exits : (k, 3) float
        Last tool tip of each patch, mm.
    start : (3,) float or None
        Where the tool starts, mm; default the first patch's entry (so that patch comes first).

    Returns
    -------
    list of int
        The patch indices (0..k − 1) in cutting order; empty when k = 0.
    """
    k = len(entries)
    if k == 0:
        return []
    here = entries[0] if start is None else np.asarray(start, dtype=np.float64)
    left, order = list(range(k)), []
    while left:
        j = min(left, key=lambda i: float(np.linalg.norm(entries[i, :2] - here[:2])))
        order.append(j)
        left.remove(j)
        here = exits[j]
    return order


def link_passes(patch_passes: list[tuple[int, list[np.ndarray]]], *, clearance_z: float, retract_mm: float,
                stay_down=None) -> MoveList:
    """One setup's moves from its patches' passes (tool-tip arrays (n_i, 3)), in the given patch order.

    stay_down(a, b) -> bool decides whether the tool may feed straight from tip a to tip b inside a
    patch (the caller checks the move against the part); None always retracts.

    Parameters
    ----------
    patch_passes : list of (int, list of (n_i, 3) float)
        Per patch its id and its passes: tool tips, mm, machine frame, in cutting order; empty passes
        are skipped.
    clearance_z : float
        Height of the rapid moves between passes and patches, mm (machine z).
    retract_mm : float
        Height above a pass's first tip where the rapid descent ends and the plunge starts, mm.
    stay_down : callable or None
        ``stay_down(a, b) -> bool`` with a, b (3,) tool tips, asked only between passes of one patch.

    Returns
    -------
    MoveList
        The moves (rapid, plunge, feed), ending with a rapid to `clearance_z` above the last tip;
        feeds carry their patch id. Empty when there is no tip.
    """
    pts: list[np.ndarray] = []
    kinds: list[int] = []
    owners: list[int] = []

    def add(p, kind, owner=-1):
        pts.append(np.asarray(p, dtype=np.float64))
        kinds.append(kind)
        owners.append(owner)

    here = None
    for pid, passes in patch_passes:
        new_patch = True
        for tips in passes:
            if not len(tips):
                continue
            first = tips[0]
            if here is not None and not new_patch and stay_down is not None and stay_down(here, first):
                add(first, FEED, pid)
            else:
                if here is not None:
                    add([here[0], here[1], clearance_z], RAPID)
                add([first[0], first[1], clearance_z], RAPID)
                add([first[0], first[1], first[2] + retract_mm], RAPID)
                add(first, PLUNGE)
            for p in tips[1:]:
                add(p, FEED, pid)
            here = tips[-1]
            new_patch = False
    if here is not None:
        add([here[0], here[1], clearance_z], RAPID)
    if not pts:
        return MoveList(np.zeros((0, 3)), np.zeros(0, np.int8), np.zeros(0, np.int64), clearance_z)
    return MoveList(np.array(pts), np.array(kinds, dtype=np.int8), np.array(owners, dtype=np.int64), clearance_z)


def order_passes(passes: list[np.ndarray], *, start: np.ndarray | None = None) -> list[tuple[int, bool]]:
    """Greedy order of passes (tool tips (n_i, 3) each): next the pass whose start or end is nearest (in xy)
    to where the last one ended, turned round when its end is the nearer.

    Parameters
    ----------
    passes : list of (n_i, 3) float
        Non-empty passes, mm.
    start : (3,) float, optional
        Where the tool is before the first pass; default the first pass's start.

    Returns
    -------
    list of (int, bool)
        Each pass's index and whether it is cut reversed, in cutting order.
    """
    if not passes:
        return []
    heads = np.array([p[0, :2] for p in passes])
    tails = np.array([p[-1, :2] for p in passes])
    here = heads[0] if start is None else np.asarray(start, dtype=np.float64)[:2]
    free = np.ones(len(passes), dtype=bool)
    out = []
    for _ in range(len(passes)):
        dh = np.where(free, np.linalg.norm(heads - here, axis=1), np.inf)
        dt = np.where(free, np.linalg.norm(tails - here, axis=1), np.inf)
        i, j = int(np.argmin(dh)), int(np.argmin(dt))
        k, turned = (j, True) if dt[j] < dh[i] else (i, False)
        free[k] = False
        out.append((k, turned))
        here = heads[k] if turned else tails[k]
    return out


def _lift(out: np.ndarray | None, into: np.ndarray, first: np.ndarray, *, clearance_z: float,
          travel_z) -> list[tuple[list[float] | np.ndarray, int]]:
    """The moves (point, kind) of a lift: feed along `out` (k, 3) (None: the program's start), rapid up to the
    link's travel height and across, rapid down to the end of `into` (k, 3) and back along it to tip
    `first` at the plunge feed."""
    down = into[-1]
    if out is None:
        moves = [([down[0], down[1], clearance_z], RAPID)]
    else:
        up = out[-1]
        across = clearance_z if travel_z is None else min(max(travel_z(up[:2], down[:2]), up[2], down[2]),
                                                          clearance_z)
        moves = [(p, FEED) for p in out]
        if across > up[2]:
            moves.append(([up[0], up[1], across], RAPID))
        moves.append(([down[0], down[1], across], RAPID))
    return [*moves, (down, RAPID), *[(p, PLUNGE) for p in into[-2::-1]], (first, PLUNGE)]


def _feed_length(tip: np.ndarray, way: np.ndarray) -> float:
    """Length (mm) of the feed from tip (3,) along the points of `way` (k, 3)."""
    return float(np.linalg.norm(np.diff(np.vstack([tip, way]), axis=0), axis=1).sum())


def link_on_part(passes: list[np.ndarray], *, clearance_z: float, leave, stay_down, ride=None, travel_z=None,
                 owner: int = -1) -> MoveList:
    """One program's moves from passes given in cutting order (tool tips, machine frame).

    Between two passes the tool feeds straight across when `stay_down(a, b)` allows it, else along
    `ride(a, b, budget)` where that offers a link; otherwise it feeds off the part along `leave(a)` to where
    a rapid straight up keeps the rapid margin, rises in rapid to the travel height of that link
    (`travel_z`, at most the clearance height), moves across, comes down in rapid to the end of
    `leave(b)` and feeds back along it onto the next start: rapids never pass closer to the part than the
    margin.

    Parameters
    ----------
    passes : list of (n_i, 3) float
        Tool tips, mm, in cutting order.
    clearance_z : float
        Height of the first approach and the last retract, and the highest a link travels, mm.
    leave : callable
        leave(tip (3,)) -> (k, 3) tips (tip excluded, k >= 1): a feed off the part from tip whose last point
        is where a rapid straight up keeps the rapid margin (at most `clearance_z` high); the way onto the
        part at tip is the same, reversed.
    stay_down : callable
        stay_down(a (3,), b (3,)) -> bool: whether feeding straight from tip a to tip b is safe and short.
    ride : callable, optional
        ride(a (3,), b (3,), budget_mm) -> (k, 3) tips or None: a feed link from tip a that ends at tip b
        (a excluded, b last), cuts nothing and is no longer than `budget_mm` (the feed off and onto the part
        of the lift it would replace). None: lift.
    travel_z : callable, optional
        travel_z(a_xy (2,), b_xy (2,)) -> tip height (mm) at which a rapid straight from over a to over b
        keeps the margin; None: links travel at the clearance height.
    owner : int
        Id carried by the cutting moves.

    Returns
    -------
    MoveList
    """
    pts: list[np.ndarray] = []
    kinds: list[int] = []

    def add(p, kind):
        pts.append(np.asarray(p, dtype=np.float64))
        kinds.append(kind)

    here = None
    for tips in passes:
        if not len(tips):
            continue
        first = tips[0]
        if here is not None and stay_down(here, first):
            link = [first]
        else:
            into = leave(first)
            out = None if here is None else leave(here)
            link = None if out is None or ride is None else ride(
                here, first, _feed_length(here, out) + _feed_length(first, into))
        if link is not None:
            for p in link:
                add(p, FEED)
        else:
            for p, kind in _lift(out, into, first, clearance_z=clearance_z, travel_z=travel_z):
                add(p, kind)
        for p in tips[1:]:
            add(p, FEED)
        here = tips[-1]
    if here is not None:
        for p in leave(here):
            add(p, FEED)
        add([pts[-1][0], pts[-1][1], clearance_z], RAPID)
    if not pts:
        return MoveList(np.zeros((0, 3)), np.zeros(0, np.int8), np.zeros(0, np.int64), clearance_z)
    kinds_a = np.array(kinds, dtype=np.int8)
    return MoveList(np.array(pts), kinds_a, np.where(kinds_a == FEED, owner, -1).astype(np.int64), clearance_z)
