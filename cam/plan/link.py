"""Linking: patch order, staying down or retracting, and the move list of one setup (tool tips, machine frame).

Between passes of one patch the tool stays down when the straight move is short and clears the part;
otherwise, and always between patches, it retracts to the clearance height, moves across in rapid,
comes down in rapid to `retract_mm` above the next start and plunges at the plunge feed. Patches are
visited greedily, each next the one whose entry is nearest to the current exit, which cuts air time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FEED", "PLUNGE", "RAPID", "MoveList", "link_passes", "order_patches"]

RAPID, PLUNGE, FEED = 0, 1, 2


@dataclass(frozen=True)
class MoveList:
    """Targets of the moves after the start at (x0, y0, clearance_z): points float64 (n, 3) tool tips mm;
    kind int8 (n,) RAPID | PLUNGE | FEED; patch int64 (n,) patch id of cutting moves, −1 otherwise."""

    points: np.ndarray
    kind: np.ndarray
    patch: np.ndarray
    clearance_z: float

    def stats(self) -> dict[str, float]:
        """Cutting and air lengths (mm) and the number of retracts."""
        if not len(self.points):
            return {"cut_length_mm": 0.0, "air_length_mm": 0.0, "retracts": 0}
        start = np.array([[self.points[0, 0], self.points[0, 1], self.clearance_z]])
        seg = np.linalg.norm(np.diff(np.concatenate([start, self.points]), axis=0), axis=1)
        up = (self.kind == RAPID) & np.isclose(self.points[:, 2], self.clearance_z)
        retracts = int(np.sum(up[1:] & ~up[:-1]))
        return {"cut_length_mm": float(seg[self.kind == FEED].sum()),
                "air_length_mm": float(seg[self.kind != FEED].sum()), "retracts": retracts}


def order_patches(entries: np.ndarray, exits: np.ndarray, *, start: np.ndarray | None = None) -> list[int]:
    """Greedy nearest-neighbour order of k patches: entries, exits float (k, 3) → indices."""
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
