"""The links of one whole-part program against the part (`link_setup`).

`cam.plan.link.link_on_part` strings passes together from four questions asked of the part, answered
here: may the tool feed straight from one pass to the next (`stay_down`), can it ride over the part at
feed instead of lifting (`ride`), where does a lift leave the part so that a rapid may start there
(`leave`), and how high must a rapid across travel (`travel_z`). A rapid keeps the rapid margin to the
part; a lift leaves the part by `retract_mm` or more before its rapid starts, straight up, or beside a
wall off the wall along its normal, whichever is the shorter feed (straight up beside a wall climbs to
the wall's top).
"""

from __future__ import annotations

import numpy as np

from cam.gcode.moves import MoveList
from cam.mesh.dropcutter import drop_ball, drop_index
from cam.params import ToolpathParams
from cam.plan.lines import GOUGE_TOL_MM, ride_over
from cam.plan.link import link_on_part
from cam.plan.part import SetupPart

__all__ = ["LINK_STEP_MM", "link_setup"]

#: Spacing of the points a link's rapid is checked at, mm.
LINK_STEP_MM = 0.5

#: Links feed straight across or ride over the part only between tips at most this many ball radii apart.
NEAR_RADII = 2.5


def link_setup(part: SetupPart, passes: list[np.ndarray], toolpath: ToolpathParams, *, top_z: float) -> MoveList:
    """One program's moves from a setup's passes in cutting order.

    Parameters
    ----------
    part : SetupPart
        The part in the setup's machine frame, for the program's ball.
    passes : list of (n_i, 3) float
        Tool tips, mm, machine frame, in cutting order (each in its cutting direction).
    toolpath : ToolpathParams
        clearance_mm, retract_mm and rapid_margin_mm are used.
    top_z : float
        The part's highest point, mm, machine frame: the clearance height is clearance_mm above it.

    Returns
    -------
    MoveList
    """
    r = part.radius_mm
    clearance_z = top_z + toolpath.clearance_mm
    safe_z, travel_z = _rapid_heights(part, toolpath.rapid_margin_mm)
    lift = np.array([0.0, 0.0, r])

    def stay_down(a: np.ndarray, b: np.ndarray) -> bool:
        if float(np.linalg.norm(b[:2] - a[:2])) > NEAR_RADII * r or abs(b[2] - a[2]) > r:
            return False
        return part.clear_between(a + lift, b + lift, tol_mm=GOUGE_TOL_MM)

    def ride(a: np.ndarray, b: np.ndarray, budget_mm: float) -> np.ndarray | None:
        if float(np.linalg.norm(b[:2] - a[:2])) > NEAR_RADII * r:
            return None
        over = ride_over(part, a + lift, b + lift, budget_mm=budget_mm)
        return None if over is None else over - lift

    def leave(tip: np.ndarray) -> np.ndarray:
        return _leave(part, tip, safe_z, retract_mm=toolpath.retract_mm, clearance_z=clearance_z)

    return link_on_part(passes, clearance_z=clearance_z, leave=leave, stay_down=stay_down, ride=ride,
                        travel_z=travel_z)


def _rapid_heights(part: SetupPart, margin_mm: float):
    """safe_z(xy (2,)) -> the tip height (mm) from which a ball lowered at xy keeps the margin to the part
    (and to the table); travel_z(a_xy, b_xy) -> the tip height at which a rapid straight from over a to
    over b keeps it."""
    r = part.radius_mm
    least = part.floor_z + r + margin_mm
    # The ball grown by the margin, lowered where a rapid ends: its tip height keeps that margin. Both
    # indexes answer a few heights per link: buckets as wide as their ball build fast (the same heights),
    # and no second bucketing for clear queries.
    grown_mm = r + margin_mm
    grown = drop_index(part.mesh.vertices, part.mesh.faces, radius_mm=grown_mm, cell_mm=grown_mm, clears=False)
    # A rapid across is checked at points LINK_STEP_MM apart, by a ball grown by half that more: between
    # two of them the real ball keeps the whole margin.
    link_mm = grown_mm + 0.5 * LINK_STEP_MM
    link = drop_index(part.mesh.vertices, part.mesh.faces, radius_mm=link_mm, cell_mm=link_mm, clears=False)

    def safe_z(xy: np.ndarray) -> float:
        return float(max(drop_ball(grown, np.asarray(xy, dtype=np.float64)[None])[0], least) - r)

    def travel_z(a: np.ndarray, b: np.ndarray) -> float:
        n = max(int(np.ceil(float(np.linalg.norm(b - a)) / LINK_STEP_MM)), 1)
        xy = a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)
        return float(max(drop_ball(link, xy).max(), least) - r)

    return safe_z, travel_z


def _leave(part: SetupPart, tip: np.ndarray, safe_z, *, retract_mm: float, clearance_z: float) -> np.ndarray:
    """Feed points (k, 3) off the part from tip (3,) (excluded) to where a rapid straight up keeps the margin:
    straight up by retract_mm or more, or, where that climbs further (beside a wall), retract_mm along the
    part's normal first when that makes the feed shorter; at most `clearance_z` high."""
    up = min(max(safe_z(tip[:2]), tip[2] + retract_mm), clearance_z)
    straight = np.array([[tip[0], tip[1], up]])
    if up - tip[2] <= retract_mm:
        return straight
    centre = tip + np.array([0.0, 0.0, part.radius_mm])
    normal = part.nearest(centre[None])[1][0]
    off = tip + retract_mm * normal
    off_up = min(max(safe_z(off[:2]), off[2]), clearance_z)
    if retract_mm + off_up - off[2] >= up - tip[2]:
        return straight
    # Checked at centres spaced as `SetupPart.clear_moves` spaces them, all but the first: beside a vertical
    # wall the pass's own centre is tangent to it, which the drop-cutter's test (clear all the way up)
    # refuses; the pass keeps it off the part. A ball that clears the part at `off` clears it all the way up.
    n = max(int(np.ceil(retract_mm / np.sqrt(8.0 * part.radius_mm * GOUGE_TOL_MM))), 1)
    along = centre + np.linspace(0.0, retract_mm, n + 1)[1:, None] * normal
    if not part.clears(along[:, :2], along[:, 2] + GOUGE_TOL_MM).all():
        return straight
    return np.array([off, [off[0], off[1], off_up]]) if off_up > off[2] else off[None]
