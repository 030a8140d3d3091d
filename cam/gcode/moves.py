"""The move list of one setup's program: tool-tip targets and what kind of move reaches each.

The planner builds it (`cam.plan.link`), the G-code writer turns it into text.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FEED", "PLUNGE", "RAPID", "MoveList"]

RAPID, PLUNGE, FEED = 0, 1, 2


@dataclass(frozen=True)
class MoveList:
    """The moves of one setup's program: targets after the start at (x0, y0, clearance_z), where x0, y0 are
    the first target's.

    Attributes
    ----------
    points : (n, 3) float64
        Tool-tip targets in mm, machine frame.
    kind : (n,) int8
        RAPID, PLUNGE or FEED: how each target is reached.
    patch : (n,) int64
        Patch id of cutting moves, −1 otherwise.
    clearance_z : float
        Safe height in mm, machine frame.
    """

    points: np.ndarray
    kind: np.ndarray
    patch: np.ndarray
    clearance_z: float

    def stats(self) -> dict[str, float]:
        """Cutting and air lengths and the number of retracts.

        Returns
        -------
        stats : dict
            ``cut_length_mm`` (FEED moves) and ``air_length_mm`` (the rest), from the start, in mm, and
            ``retracts``: rapid moves to clearance height that follow a move that is not one.
        """
        if not len(self.points):
            return {"cut_length_mm": 0.0, "air_length_mm": 0.0, "retracts": 0}
        start = np.array([[self.points[0, 0], self.points[0, 1], self.clearance_z]])
        seg = np.linalg.norm(np.diff(np.concatenate([start, self.points]), axis=0), axis=1)
        up = (self.kind == RAPID) & np.isclose(self.points[:, 2], self.clearance_z)
        retracts = int(np.sum(up[1:] & ~up[:-1]))
        return {"cut_length_mm": float(seg[self.kind == FEED].sum()),
                "air_length_mm": float(seg[self.kind != FEED].sum()), "retracts": retracts}
