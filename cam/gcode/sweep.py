"""The volume a ball sweeps along straight moves, met by lines: exact ray–capsule intervals.

A straight move of the ball centre from A to B sweeps a capsule (a cylinder of radius r around AB
capped by the two balls). A line p + t·n meets a capsule, which is convex, in one interval
[t_in, t_out]: the hull of its intervals with the two balls and with the cylinder clipped to the
slab between A and B. The capsules near a line are found through points spread along the moves (a
grid of them, in compiled code: `_sweepkernel`), so only capsules that can reach a line within the asked
range are evaluated.
"""

from __future__ import annotations

import numpy as np

from cam.gcode._sweepkernel import probe_sweep

__all__ = ["Sweep", "capsule_intervals"]


def _sphere(p, n, c, r):
    w = p - c
    b = np.einsum("ij,ij->i", n, w)
    q = b * b - (np.einsum("ij,ij->i", w, w) - r * r)
    root = np.sqrt(np.maximum(q, 0.0))
    hit = q >= 0
    return np.where(hit, -b - root, np.inf), np.where(hit, -b + root, -np.inf)


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point p to the segment a → b, row by row (float (m, 3) each)."""
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def capsule_intervals(p: np.ndarray, n: np.ndarray, a: np.ndarray, b: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """[t_in, t_out] of lines p + t·n (unit n) with capsules a → b of radius r, row by row.

    p, n, a, b: float64 (m, 3); returns two float64 (m,) arrays; t_in = +inf, t_out = −inf where they miss.

    Parameters
    ----------
    p : (m, 3) float64
        Points on the lines, mm.
    n : (m, 3) float64
        Line directions, unit.
    a, b : (m, 3) float64
        Segment ends (the axis of each capsule), mm.
    r : float
        Capsule radius, mm.

    Returns
    -------
    t_in, t_out : (m,) float64
        The interval along each line, mm from p (either may be negative); t_in = +inf, t_out = −inf
        where the line misses its capsule.
    """
    t_in, t_out = _sphere(p, n, a, r)
    s_in, s_out = _sphere(p, n, b, r)
    t_in, t_out = np.minimum(t_in, s_in), np.maximum(t_out, s_out)
    ab = b - a
    length = np.linalg.norm(ab, axis=1)
    ok = length > 1e-12
    d = np.where(ok[:, None], ab / np.where(ok, length, 1.0)[:, None], 0.0)
    w = p - a
    nd, wd = np.einsum("ij,ij->i", n, d), np.einsum("ij,ij->i", w, d)
    nperp, wperp = n - nd[:, None] * d, w - wd[:, None] * d
    qa = np.einsum("ij,ij->i", nperp, nperp)
    qb = np.einsum("ij,ij->i", nperp, wperp)
    qc = np.einsum("ij,ij->i", wperp, wperp) - r * r
    disc = qb * qb - qa * qc
    good = ok & (qa > 1e-14) & (disc >= 0)
    root = np.sqrt(np.maximum(disc, 0.0))
    qa_safe = np.where(good, qa, 1.0)
    c_in, c_out = (-qb - root) / qa_safe, (-qb + root) / qa_safe
    # Clip the cylinder to the slab 0 ≤ (w + t n)·d ≤ |AB|.
    with np.errstate(divide="ignore", invalid="ignore"):
        s0, s1 = (0.0 - wd) / nd, (length - wd) / nd
    flat = np.abs(nd) < 1e-14
    lo = np.where(flat, np.where((wd >= 0) & (wd <= length), -np.inf, np.inf), np.minimum(s0, s1))
    hi = np.where(flat, np.where((wd >= 0) & (wd <= length), np.inf, -np.inf), np.maximum(s0, s1))
    c_in, c_out = np.maximum(c_in, lo), np.minimum(c_out, hi)
    cyl = good & (c_in <= c_out)
    t_in = np.where(cyl, np.minimum(t_in, c_in), t_in)
    t_out = np.where(cyl, np.maximum(t_out, c_out), t_out)
    return t_in, t_out


class Sweep:
    """The capsules of a list of straight moves (ball centres a → b, float (m, 3)), ready to be probed.

    Parameters
    ----------
    a, b : (m, 3) float
        Start and end ball centres of each move, mm.
    r : float
        Ball radius, mm.
    step : float
        Spacing of the points spread along each move to find the moves near a point, mm.

    Attributes
    ----------
    a, b : (m, 3) float64
        The moves' ball centres, mm.
    r : float
        Ball radius, mm.
    step : float
        Spacing of the spread points, mm.
    spread : (K, 3) float64
        Points along the moves, at most `step` apart, ends included, mm.
    owner : (K,) int64
        The move of each spread point.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, r: float, *, step: float):
        self.a, self.b, self.r, self.step = np.asarray(a, float).reshape(-1, 3), np.asarray(b, float).reshape(-1, 3), r, step
        k = np.maximum(np.ceil(np.linalg.norm(self.b - self.a, axis=1) / step).astype(np.int64), 1)
        self.owner = np.repeat(np.arange(len(self.a)), k + 1)
        offsets = np.concatenate([[0], np.cumsum(k + 1)[:-1]]) if len(k) else np.zeros(0, np.int64)
        t = (np.arange(len(self.owner)) - np.repeat(offsets, k + 1)) / np.repeat(k, k + 1)
        self.spread = self.a[self.owner] + t[:, None] * (self.b - self.a)[self.owner]

    def probe(self, p: np.ndarray, n: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
        """Per point p with outward unit normal n (float (k, 3)): the material left along n (first entry into
        the swept volume, +inf when none within `reach`) and the overcut (≥ 0: how deep p lies inside the
        swept volume), both mm.

        Every capsule whose axis passes within r + reach of the point is measured: its axis then passes
        within step / 2 of a spread point, so one lies within r + reach + step / 2 of the point.

        Parameters
        ----------
        p : (k, 3) float
            Surface points, mm.
        n : (k, 3) float
            Their outward unit normals.
        reach : float
            Largest material measured, mm; farther entries count as none.

        Returns
        -------
        scallop : (k,) float64
            Material left along n, mm (0 where p lies inside a capsule), +inf when none within `reach`.
        gouge : (k,) float64
            Overcut, mm: r minus p's distance to the nearest capsule axis, ≥ 0. (The normal line's own
            depth overstates it wherever the line meets the capsule obliquely, e.g. a ball cutting the far
            face of a sharp edge next to the point.)
        """
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        n = np.asarray(n, dtype=np.float64).reshape(-1, 3)
        return probe_sweep(p, n, self.a, self.b, self.r, reach, self.spread, self.owner,
                           radius=self.r + reach + 0.5 * self.step)
