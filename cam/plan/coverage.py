"""What planned passes leave on the part: the planner's own measurement, sample by sample.

The ball swept along a pass's straight moves is a chain of capsules; the material left at a sample of
the part is how far its normal line runs before it enters one (`cam.gcode.sweep`). The planner uses
this to know what is finished after each strategy and to aim the next one at the rest; verify measures
the programs again, independently, from their G-code.
"""

from __future__ import annotations

import numpy as np

from cam.gcode.sweep import Sweep

__all__ = ["left_on_samples", "pass_moves"]


def pass_moves(passes: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The straight moves of ball-centre polylines: starts and ends, float64 (m, 3) each (a pass of one
    point is a move of length zero)."""
    a = [p[:-1] if len(p) > 1 else p for p in passes if len(p)]
    b = [p[1:] if len(p) > 1 else p for p in passes if len(p)]
    if not a:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(a), np.concatenate(b)


def left_on_samples(passes: list[np.ndarray], points: np.ndarray, normals: np.ndarray, *, tool_radius_mm: float,
                    reach_mm: float) -> np.ndarray:
    """Material the balls swept along `passes` leave at each sample, along its normal.

    Parameters
    ----------
    passes : list of (n_i, 3) float
        Ball centres, mm, in the samples' frame.
    points, normals : (k, 3) float
        Samples of the part and their outward unit normals.
    tool_radius_mm : float
    reach_mm : float
        Material beyond this is not measured.

    Returns
    -------
    (k,) float64
        Material left, mm (0 where the sample is cut into); +inf where more than `reach_mm` or none of the
        passes comes near.
    """
    a, b = pass_moves(passes)
    if not len(a) or not len(points):
        return np.full(len(points), np.inf)
    sweep = Sweep(a, b, tool_radius_mm, step=tool_radius_mm / 2)
    left, _ = sweep.probe(points, normals, reach_mm)
    return left
