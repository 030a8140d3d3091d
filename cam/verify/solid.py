"""The part as a cloud of its own samples in one setup's frame: can a ball touching a sample get there?

A ball touching a sample (its centre r along the sample's normal) is clear of the part when no sample
lies within r of its centre, and it can come down the tool axis when nothing of the part stands in the
cylinder of radius r above that centre. The cylinder test uses a grid of the highest sample per cell,
taken over the cells wholly inside the circle, so a thin wall between two cells is never missed by more
than a cell.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter
from scipy.spatial import cKDTree

__all__ = ["SampleSolid"]


class SampleSolid:
    """The samples (k, 3) of a part in a setup's machine frame, for the reach tests of a ball of radius r.

    Parameters
    ----------
    points : (k, 3) float
        The part's samples, mm, machine frame.
    r : float
        Ball radius, mm.
    cell : float
        Grid cell of the shank test, mm (the sample spacing).
    tol : float
        Distance within which a sample counts as touching, mm.
    floor_z : float, optional
        The table: a ball centre below floor_z + r is not reachable. None: no table.
    """

    def __init__(self, points: np.ndarray, *, r: float, cell: float, tol: float, floor_z: float | None = None):
        self.tree = cKDTree(points)
        self.r, self.tol, self.cell, self.floor_z = r, tol, cell, floor_z
        self.lo = points[:, :2].min(axis=0) - r
        shape = np.ceil((points[:, :2].max(axis=0) + r - self.lo) / cell).astype(int) + 1
        top = np.full(shape, -np.inf)
        ij = ((points[:, :2] - self.lo) / cell).astype(int)
        np.maximum.at(top, (ij[:, 0], ij[:, 1]), points[:, 2])
        rad = max((r - tol) / cell - 0.75, 0.0)  # cells wholly inside the shank circle
        k = int(np.floor(rad))
        y, x = np.mgrid[-k:k + 1, -k:k + 1]
        self.shank_top = maximum_filter(top, footprint=(x * x + y * y) <= rad * rad, mode="constant", cval=-np.inf)

    def reachable(self, p: np.ndarray, n: np.ndarray, *, lift_mm: float = 0.0, min_normal_z: float = 1e-6
                  ) -> np.ndarray:
        """bool (m,): the ball touching each point p (m, 3) with unit normal n (m, 3), its centre lifted by
        `lift_mm` more along n, is clear of the samples, under no sample, above the table, and n's z is
        over `min_normal_z` (a normal turned down puts the point itself in the cylinder above the centre,
        within the grid's tolerance ring the shank test could miss)."""
        centre = p + (self.r + lift_mm) * n
        nearest, _ = self.tree.query(centre, distance_upper_bound=self.r)
        ij = np.clip(((centre[:, :2] - self.lo) / self.cell).astype(int), 0, np.array(self.shank_top.shape) - 1)
        shank = self.shank_top[ij[:, 0], ij[:, 1]] <= centre[:, 2] + self.tol
        ok = (n[:, 2] > min_normal_z) & (nearest >= self.r - self.tol) & shank
        if self.floor_z is not None:
            ok &= centre[:, 2] >= self.floor_z + self.r - self.tol
        return ok
