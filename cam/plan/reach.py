"""Where on a patch the ball reaches: the parameter rectangle whose boundary lines the tangent ball reaches.

At a hollow sharp edge the ball touching one patch cuts the next one, and part of a patch may face
away from the tool. `reachable_domain` starts from the largest block of a grid of contact points
the ball reaches, pushes each side outwards to where its iso-line stops being reachable, and moves
sides inwards where a line is blocked between grid points. What lies outside is reported by verify
as unreachable; trouble left inside is found when the passes are planned (`cam.plan.patch`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.plan.gouge import GOUGE_TOL_MM, SurfaceIndex, clearance, shank_clear
from cam.plan.region import largest_clear_rectangle
from cam.spline.geometry import Patch, frame

__all__ = ["reachable_domain"]

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class _Reach:
    """The tangent ball of radius r on `patch`, checked against the part in `index`."""

    patch: Patch
    index: SurfaceIndex
    r: float
    samples: int

    def reached(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """bool (n,): whether the tangent ball at each contact (u, v) faces up, clears every surface and
        its shank."""
        fr = frame(self.patch, u, v)
        c = fr.p + self.r * fr.n
        ok = np.all(np.isfinite(c), axis=1) & (fr.n[:, 2] > 1e-6)
        ok[ok] = clearance(self.index, c[ok], self.r) >= -GOUGE_TOL_MM
        ok[ok] = shank_clear(self.index, c[ok], self.r)
        return ok

    def line_ok(self, along: str, fixed: float, lo: float, hi: float) -> bool:
        """Whether the ball reaches every sample of an iso-line (along 'u': v = fixed, u from lo to hi)."""
        q = np.linspace(lo, hi, self.samples)
        fixed_q = np.full_like(q, fixed)
        return bool(np.all(self.reached(q, fixed_q) if along == "u" else self.reached(fixed_q, q)))


def _line(box: list[float], side: int) -> tuple[str, float, float]:
    """The iso-line a side of `box` lies on: sides 0, 1 are u = const lines (running along v)."""
    along = "u" if side >= 2 else "v"
    lo, hi = (box[2], box[3]) if along == "v" else (box[0], box[1])
    return along, lo, hi


def _grow(reach: _Reach, box: list[float], limits: list[float], beyond: list[float]) -> None:
    """Push each side of `box` outwards up to the grid line beyond it, where its line stops being
    reachable (bisection); in place."""
    for side in range(4):
        along, lo, hi = _line(box, side)
        inner = box[side]
        if inner == limits[side] or not reach.line_ok(along, inner, lo, hi):
            continue
        outer = beyond[side]
        if reach.line_ok(along, outer, lo, hi):
            box[side] = outer
            continue
        for _ in range(12):
            mid = 0.5 * (inner + outer)
            inner, outer = (mid, outer) if reach.line_ok(along, mid, lo, hi) else (inner, mid)
        box[side] = inner


def _inset(reach: _Reach, box: list[float], side: int, steps: int) -> float | None:
    """Smallest reachable inset of `side` as a fraction of the way to the opposite side; 0 when it holds,
    None when no line up to half way is reachable."""
    along, lo, hi = _line(box, side)
    start, other = box[side], box[side ^ 1]
    if reach.line_ok(along, start, lo, hi):
        return 0.0
    ts = np.linspace(0, 1, steps + 1)[1:] * 0.5
    good = next((t for t in ts if reach.line_ok(along, start + t * (other - start), lo, hi)), None)
    if good is None:
        return None
    a, b = good - 0.5 / steps, good
    for _ in range(12):
        mid = 0.5 * (a + b)
        a, b = (a, mid) if reach.line_ok(along, start + mid * (other - start), lo, hi) else (mid, b)
    return b


def _shrink_blocked(reach: _Reach, box: list[float], *, steps: int, rounds: int) -> Box:
    """Move in, one side per round (the one that gives up the least area), sides whose line is blocked
    between grid points; an empty box when that does not end within `rounds`."""
    for _ in range(rounds):
        if box[0] >= box[1] or box[2] >= box[3]:
            break
        moves = {side: _inset(reach, box, side, steps) for side in range(4)}
        if all(t == 0.0 for t in moves.values()):
            return tuple(box)
        width = {0: box[3] - box[2], 1: box[3] - box[2], 2: box[1] - box[0], 3: box[1] - box[0]}
        loss = {side: t * abs(box[side ^ 1] - box[side]) * width[side] for side, t in moves.items() if t}
        if not loss:
            break
        side = min(loss, key=loss.get)
        box[side] = box[side] + moves[side] * (box[side ^ 1] - box[side])
    return (box[0], box[0], box[2], box[2])


def reachable_domain(patch: Patch, index: SurfaceIndex, *, tool_radius_mm: float, samples: int = 32,
                     steps: int = 24, rounds: int = 8) -> Box:
    """A parameter rectangle (u0, u1, v0, v1) of `patch` whose four boundary lines the tangent ball reaches
    everywhere; empty (u0 == u1) when there is none.

    Parameters
    ----------
    patch : Patch
        The patch in its setup's machine frame (tool axis +Z), sign outward.
    index : SurfaceIndex
        The whole part in the same frame (`cam.plan.gouge.build_index`).
    tool_radius_mm : float
        Ball radius, mm.
    samples : int
        Grid of samples × samples contact points for the first block; also the samples per line checked.
    steps, rounds : int
        Insets tried per side (up to half way) and sides moved in at most.

    Returns
    -------
    tuple of 4 float
        (u0, u1, v0, v1), parameters; u0 == u1 and v0 == v1 when no grid point is reached or the
        blocked sides cannot be moved in to reachable lines within `rounds`.
    """
    (u0, u1), (v0, v1) = patch.domain
    reach = _Reach(patch, index, float(tool_radius_mm), samples)
    gu, gv = np.linspace(u0, u1, samples), np.linspace(v0, v1, samples)
    uu, vv = np.meshgrid(gu, gv, indexing="ij")
    ok = reach.reached(uu.ravel(), vv.ravel()).reshape(samples, samples)
    block = largest_clear_rectangle(~ok, np.ones(ok.shape), min_span=0)
    if block is None:
        return (u0, u0, v0, v0)
    i0, i1, j0, j1 = block
    box = [gu[i0], gu[i1], gv[j0], gv[j1]]
    beyond = [gu[max(i0 - 1, 0)], gu[min(i1 + 1, samples - 1)], gv[max(j0 - 1, 0)], gv[min(j1 + 1, samples - 1)]]
    _grow(reach, box, [u0, u1, v0, v1], beyond)
    return _shrink_blocked(reach, box, steps=steps, rounds=rounds)
