"""The outermost ring's inset from the edges of the claimed rectangle.

A pass leaves, at a surface point beside it, the material between the point and the first entry of
the point's normal ray into the swept ball. Half-way between two passes that height is the scallop;
at the edge of the claimed rectangle there is a pass on one side only, so one pass alone must leave
no more than the budget there. That allows the first ring about half an admissible interval inside
the edge. The paper runs its first ring on the edge (kept for `strategy="paper"`): there half of the
first ring's band lies outside the patch and its length buys nothing.

The material at the edge is computed exactly for the ideal ring line: the ball centres of the line,
sampled densely, form a polyline, the swept ball along each of its segments is a capsule, and the
entry of each edge point's normal ray into the nearest capsule is solved in closed form. Edge points
whose nearest centres lie beyond the ring's corners are the corner pockets' business (`rings.py`).
"""

from __future__ import annotations

import numpy as np

from cam.plan.errors import NotPlannable
from cam.plan.scallop import arc_gap
from cam.spline.geometry import Patch, across_iso_line, iso_line_frame

__all__ = ["edge_scallop", "edge_step", "inset_rectangle", "ray_capsule_entry"]

CENTRES_PER_SAMPLE = 16  # centre polyline density: its chord sag stays far below any budget


def ray_capsule_entry(origin: np.ndarray, direction: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray,
                      r: float) -> np.ndarray:
    """First entry t ≥ 0 (mm) of each ray origin + t·direction into the union of the capsules.

    Each capsule is the cylinder of radius r around a segment and the two balls at its ends; the
    entry is solved in closed form for every ray and capsule (O(n·m) memory).

    Parameters
    ----------
    origin : (n, 3) float
        Ray origins, mm.
    direction : (n, 3) float
        Ray directions, of unit length.
    seg_a, seg_b : (m, 3) float
        Segment ends (the axis of each capsule), mm.
    r : float
        Capsule radius, mm.

    Returns
    -------
    t : (n,) float64
        First entry along each ray, mm: 0 where the origin lies inside a capsule, +inf where the ray
        misses them all.
    """
    o, n = np.asarray(origin, dtype=np.float64), np.asarray(direction, dtype=np.float64)
    a, b = np.asarray(seg_a, dtype=np.float64), np.asarray(seg_b, dtype=np.float64)
    w = o[:, None, :] - a[None]  # (n, m, 3)
    d = b - a
    length = np.linalg.norm(d, axis=1)
    axis = d / np.maximum(length, 1e-300)[:, None]
    # The cylinder around each segment: the ray's components across its axis.
    wd, nd = np.einsum("nmk,mk->nm", w, axis), n @ axis.T
    w_perp = w - wd[..., None] * axis[None]
    n_perp = n[:, None, :] - nd[..., None] * axis[None]
    qa = np.einsum("nmk,nmk->nm", n_perp, n_perp)
    qb = np.einsum("nmk,nmk->nm", w_perp, n_perp)
    qc = np.einsum("nmk,nmk->nm", w_perp, w_perp) - r * r
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-qb - np.sqrt(qb * qb - qa * qc)) / qa
        s = wd + t * nd
        inside = (qc <= 0) & (wd >= 0) & (wd <= length[None])
        hit = (t >= 0) & (s >= 0) & (s <= length[None]) & (length[None] > 0)
        best = np.where(inside, 0.0, np.where(hit, t, np.inf)).min(axis=1)
    # The balls at the segment ends (the polyline's vertices).
    for ends in (a, b):
        v = o[:, None, :] - ends[None]
        bb = np.einsum("nmk,nk->nm", v, n)
        cc = np.einsum("nmk,nmk->nm", v, v) - r * r
        with np.errstate(invalid="ignore"):
            t = -bb - np.sqrt(bb * bb - cc)
        best = np.minimum(best, np.where(cc <= 0, 0.0, np.where(t >= 0, t, np.inf)).min(axis=1))
    return best


def edge_scallop(patch: Patch, *, along: str, edge: float, line: float, lo: float, hi: float, r: float,
                 samples: int) -> np.ndarray:
    """Material (mm, float64 (≥ samples,)) the ring line `line` alone leaves on the edge iso-line `edge`, at
    `samples` even parameters and at the surface's knots between them.

    along 'u': both are lines v = const over u in [lo, hi]; along 'v': lines u = const over v.
    The ball centres of the ring line, sampled `CENTRES_PER_SAMPLE` times as densely (and at the knots),
    form the capsules the normal ray of each edge point enters (`ray_capsule_entry`).

    Parameters
    ----------
    patch : Patch
        The patch.
    along : {'u', 'v'}
        The parameter that runs along both lines.
    edge : float
        Fixed parameter of the edge iso-line.
    line : float
        Fixed parameter of the ring line.
    lo, hi : float
        Range of the running parameter.
    r : float
        Ball radius, mm.
    samples : int
        Even samples on the edge line.

    Returns
    -------
    material : (k,) float64
        Material left at each edge sample, mm, in parameter order; k ≥ samples (the knots strictly
        between lo and hi are added); +inf where the normal ray misses the swept balls.
    """
    # A C0 knot line (a border that turns a corner) puts a corner in both lines and a sharp peak of the
    # material on the edge: its knots are sampled on both, wherever the uniform samples fall.
    knots = np.unique(patch.surface.knots_u if along == "u" else patch.surface.knots_v)
    knots = knots[(knots > lo) & (knots < hi)]
    fe = iso_line_frame(patch, along, edge, np.union1d(np.linspace(lo, hi, samples), knots))
    fl = iso_line_frame(patch, along, line, np.union1d(np.linspace(lo, hi, CENTRES_PER_SAMPLE * samples), knots))
    centres = fl.p + r * fl.n
    return ray_capsule_entry(fe.p, fe.n, centres[:-1], centres[1:], r)


def edge_step(patch: Patch, *, along: str, edge: float, direction: float, limit: float, lo: float, hi: float,
              r: float, h: float, samples: int) -> tuple[float, float]:
    """Largest checked inset (parameter units, ≥ 0) of a ring line from `edge` towards `limit`, and the
    material it leaves on the edge (mm).

    Starts from half the admissible interval at the edge's smallest normal curvature across it and
    shrinks until the exact material holds h at every sample. The start is the smallest over `samples`
    points of the edge of half the admissible arc gap (`arc_gap`) turned into parameter units, capped
    at the room to `limit`; each shrink multiplies it by 0.995·√(h / material) (by 0.5 where the
    material is not finite), at most 30 times.

    Parameters
    ----------
    patch : Patch
        The patch.
    along : {'u', 'v'}
        The parameter that runs along the edge (along 'u': the edge is a line v = const).
    edge : float
        Fixed parameter of the edge line.
    direction : float
        +1 or −1: the sign of the inset, towards `limit`.
    limit : float
        The opposite edge's parameter: the inset never passes it.
    lo, hi : float
        Range of the running parameter.
    r : float
        Ball radius, mm.
    h : float
        Material one pass alone may leave on the edge, mm.
    samples : int
        Samples along the edge.

    Returns
    -------
    step : float
        The inset, parameter units, in [0, |limit − edge|].
    material : float
        The largest material the ring line at that inset leaves on the edge, mm (≤ h); (0.0, 0.0) when
        `limit` equals `edge`.

    Raises
    ------
    NotPlannable
        When no inset keeps the material within h (a degenerate fitted surface).
    """
    room = abs(limit - edge)
    if room <= 0:
        return 0.0, 0.0
    kappa, speed = across_iso_line(iso_line_frame(patch, along, edge, np.linspace(lo, hi, samples)), along)
    step = min(float(np.min(0.5 * arc_gap(h, r, kappa) / speed)), room)
    worst = np.inf
    for _ in range(30):
        worst = float(np.max(edge_scallop(patch, along=along, edge=edge, line=edge + direction * step, lo=lo, hi=hi,
                                          r=r, samples=samples)))
        if worst <= h * (1 + 1e-9):
            return step, worst
        step *= 0.995 * np.sqrt(h / worst) if np.isfinite(worst) else 0.5
    raise NotPlannable(f"no inset of the first ring keeps the material on the patch edge within {h:.4g} mm "
                       f"(it leaves {worst:.4g} mm): the fitted surface is degenerate there; refit the patch")


def inset_rectangle(patch: Patch, *, r: float, h: float, samples: int) -> tuple[tuple[float, float, float, float],
                                                                                 np.ndarray]:
    """The first ring (u0, u1, v0, v1) inside the patch's domain, and the material it leaves on the four
    edges.

    Where opposite insets would cross, the ring is the one line between them that both edges allow.

    Parameters
    ----------
    patch : Patch
        The patch.
    r : float
        Ball radius, mm.
    h : float
        Material the first ring alone may leave on each edge, mm.
    samples : int
        Samples per edge (`edge_step`).

    Returns
    -------
    ring : tuple of 4 float
        (u0, u1, v0, v1) of the first ring, parameters.
    material : (4,) float64
        The material it leaves on the four edges, mm, in the grid's side order v0, u1, v1, u0.

    Raises
    ------
    NotPlannable
        When no inset of some edge keeps the material within h (`edge_step`).
    """
    (a, b), (c, d) = patch.domain
    sc, wc = edge_step(patch, along="u", edge=c, direction=1, limit=d, lo=a, hi=b, r=r, h=h, samples=samples)
    sd, wd = edge_step(patch, along="u", edge=d, direction=-1, limit=c, lo=a, hi=b, r=r, h=h, samples=samples)
    sa, wa = edge_step(patch, along="v", edge=a, direction=1, limit=b, lo=c, hi=d, r=r, h=h, samples=samples)
    sb, wb = edge_step(patch, along="v", edge=b, direction=-1, limit=a, lo=c, hi=d, r=r, h=h, samples=samples)
    na, nb, nc, nd = a + sa, b - sb, c + sc, d - sd
    if na >= nb:
        na = nb = float(np.clip(0.5 * (a + b), b - sb, a + sa))
    if nc >= nd:
        nc = nd = float(np.clip(0.5 * (c + d), d - sd, c + sc))
    return (na, nb, nc, nd), np.array([wc, wb, wd, wa], dtype=np.float64)
