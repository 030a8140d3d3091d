"""The paper's Algorithm 1: the grid of iso-parameter lines whose concentric rings machine a patch.

Starting from the first ring, each side of the current ring
takes the largest step into the patch whose scallop stays within the budget: sample k points on
the side, turn the admissible arc gap at each (exact relation, signed normal curvature across the
side) into a parameter step with the first fundamental form — the distance between the iso-lines
v and v + Δv is Δv·√(EG − F²)/√E (eqs. 5–6; with F = 0 this is the paper's Δv·√G) — and take the
smallest. The step is then checked against the real next line: each sample's ball centre is paired
with the nearest ball centre on that line and the exact circle-intersection scallop is evaluated with
the smaller of the two curvatures; the step shrinks until every sample holds. Rings are added until
the parameter square is filled; when two opposite sides would cross, the last line sits between them
where both gaps hold.

`strategy="paper"` is the published variant used as the baseline: one global minimum interval per
parameter direction for the whole patch, and at each ring corner Δs shrinks until the corner pocket
holds; its first ring runs on the patch's edges. `strategy="adaptive"` (ours) starts its first ring as far
inside the edges as one pass may leave the budget there (`edge.py`), takes the admissible step of each side
of each ring and leaves the corner pockets to short corner excursions (see `rings.py`), which keeps the
certificate with shorter paths.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.plan.edge import inset_rectangle
from cam.plan.errors import NotPlannable, TooConcave, concave_message
from cam.plan.scallop import arc_gap, fits_concave, scallop_from_half_chord
from cam.spline.geometry import (
    Patch,
    across_iso_line,
    frame,
    iso_line_frame,
    principal_curvatures,
)

__all__ = ["RingGrid", "check_concavity", "global_steps", "ring_grid"]

SIDES = ("v0", "u1", "v1", "u0")  # bottom, right, top, left of the parameter square


@dataclass(frozen=True)
class RingGrid:
    """Rings of one patch, outermost first.

    Attributes
    ----------
    rects : (K, 4) float64
        (u0, u1, v0, v1) of each ring, parameters; a ring with u0 == u1 or v0 == v1 is a line (the
        innermost).
    side_scallop : (K − 1, 4) float64
        Predicted scallop (mm) of the gap between ring k and k + 1 on the sides SIDES.
    side_steps : (K − 1, 4) float64
        The parameter steps taken, per side in SIDES order.
    strategy : str
        'adaptive' or 'paper' (see the module docstring).
    claim : tuple of 4 float
        The rectangle (u0, u1, v0, v1) the rings finish (the patch's domain).
    edge_scallop : (4,) float64
        The material (mm) the first ring leaves on the claim's edges, in SIDES order (zero where the
        first ring runs on the edge).
    """

    rects: np.ndarray
    side_scallop: np.ndarray
    side_steps: np.ndarray
    strategy: str
    claim: tuple[float, float, float, float]
    edge_scallop: np.ndarray


def check_concavity(patch: Patch, tool_radius_mm: float, *, samples: int = 33) -> None:
    """Raise `TooConcave` when a concave radius of curvature ≤ r occurs on a samples × samples grid.

    Parameters
    ----------
    patch : Patch
        The patch.
    tool_radius_mm : float
        Ball radius r, mm.
    samples : int
        Grid size per parameter direction, over the whole domain.

    Raises
    ------
    TooConcave
        Naming the tightest sample (radius, point) and listing the parameters of every sample found
        too concave (smallest principal curvature κ_min ≤ −1/r).
    """
    (u0, u1), (v0, v1) = patch.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, samples), np.linspace(v0, v1, samples), indexing="ij")
    fr = frame(patch, uu, vv)
    kmin, _ = principal_curvatures(fr)
    bad = ~fits_concave(kmin, tool_radius_mm)
    if np.any(bad):
        raise _too_concave(fr, kmin, bad, uu, vv, tool_radius_mm)


def _too_concave(fr, kmin: np.ndarray, bad: np.ndarray, u: np.ndarray, v: np.ndarray, r: float) -> TooConcave:
    """`TooConcave` for the samples flagged `bad` (bool, the shape of u, v and kmin), named by the tightest."""
    i = np.unravel_index(np.argmin(np.where(bad, kmin, np.inf)), kmin.shape)
    radius = -1.0 / kmin[i]
    return TooConcave(concave_message(radius, r, fr.p[i]), radius_mm=float(radius), point=fr.p[i],
                      uv=np.stack([u[bad], v[bad]], -1))


def _point_to_polyline(x: np.ndarray, poly: np.ndarray):
    """Nearest point of polyline poly (m, 3) to each x (n, 3): distance (n,), segment (n,), fraction (n,)."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.einsum("nmk,mk->nm", x[:, None, :] - a[None], ab) / np.maximum(np.einsum("mk,mk->m", ab, ab), 1e-300)
    t = np.clip(t, 0.0, 1.0)
    d = np.linalg.norm(a[None] + t[..., None] * ab[None] - x[:, None, :], axis=-1)
    j = np.argmin(d, axis=1)
    rows = np.arange(len(x))
    return d[rows, j], j, t[rows, j]


def gap_scallop(patch: Patch, *, along: str, fixed0: float, fixed1: float, lo: float, hi: float,
                r: float, samples: int) -> np.ndarray:
    """Predicted scallop (mm, float64 (samples,)) between iso-lines fixed0 and fixed1 over [lo, hi].

    Ball centres on line 0 are paired with the nearest point of the ball-centre polyline of line 1;
    pairs whose nearest point is an end of that polyline (not a perpendicular foot) are left to the
    corner checks. The exact relation takes the smaller curvature of the two ends of the gap.
    """
    q0 = np.linspace(lo, hi, samples)
    q1 = np.linspace(lo, hi, 4 * samples)
    f0, f1 = iso_line_frame(patch, along, fixed0, q0), iso_line_frame(patch, along, fixed1, q1)
    c0, c1 = f0.p + r * f0.n, f1.p + r * f1.n
    k0, _ = across_iso_line(f0, along)
    k1, _ = across_iso_line(f1, along)
    dist, seg, frac = _point_to_polyline(c0, c1)
    k_foot = k1[seg] * (1 - frac) + k1[seg + 1] * frac
    h = scallop_from_half_chord(dist / 2, r, np.minimum(k0, k_foot))
    interior = ~(((seg == 0) & (frac <= 0)) | ((seg == len(q1) - 2) & (frac >= 1)))
    return np.where(interior | (hi - lo <= 0), h, 0.0)


def _hollow_on_line(patch: Patch, along: str, fixed: float, q: np.ndarray, r: float) -> TooConcave | None:
    """`TooConcave` naming every parameter q (float (n,)) of the iso-line where the ball does not fit, or None.

    `check_concavity` looks at a grid; a hollow narrower than its spacing shows first on a ring's line,
    where the scallop relations have no answer. Points whose curvature is undefined are not hollows.
    """
    line = np.full_like(q, fixed)
    u, v = (q, line) if along == "u" else (line, q)
    fr = frame(patch, u, v)
    kmin, _ = principal_curvatures(fr)
    bad = np.isfinite(kmin) & ~fits_concave(kmin, r)
    return _too_concave(fr, kmin, bad, u, v, r) if np.any(bad) else None


def side_step(patch: Patch, *, along: str, fixed: float, lo: float, hi: float, direction: float, limit: float,
              r: float, h: float, samples: int, start: float | None = None) -> tuple[float, float]:
    """Largest checked step (parameter units, ≥ 0) from iso-line `fixed` towards `limit`, and its scallop.

    Raises `TooConcave` (with the parameters of the points) when the ball does not fit a hollow on
    the line or on the next one.
    """
    room = abs(limit - fixed)
    if room <= 0:
        return 0.0, 0.0
    q0 = np.linspace(lo, hi, samples)
    if start is None:
        fr = iso_line_frame(patch, along, fixed, q0)
        kappa, speed = across_iso_line(fr, along)
        step = float(np.min(arc_gap(h, r, kappa) / speed))
    else:
        step = start
    step = min(step, room) if np.isfinite(step) else room
    worst = 0.0
    for _ in range(30):
        worst = float(np.max(gap_scallop(patch, along=along, fixed0=fixed, fixed1=fixed + direction * step,
                                         lo=lo, hi=hi, r=r, samples=samples)))
        if worst <= h * (1 + 1e-9):
            return step, worst
        if not np.isfinite(worst):
            # No scallop relation holds: the ball does not fit a hollow on one of the two lines, or the
            # step is wider than a hollow's centre circle (then a shorter one has an answer).
            for line, q in ((fixed, q0), (fixed + direction * step, np.linspace(lo, hi, 4 * samples))):
                hollow = _hollow_on_line(patch, along, line, q, r)
                if hollow is not None:
                    raise hollow
            step *= 0.5
            continue
        step *= 0.995 * np.sqrt(h / worst)  # the scallop grows about quadratically with the step
    what = "curvature undefined there" if not np.isfinite(worst) else f"worst scallop {worst:.4g} mm"
    raise NotPlannable(f"no pass interval keeps the scallop within {h:.4g} mm ({what}): the fitted surface is "
                       "degenerate there; refit the patch")


def global_steps(patch: Patch, *, r: float, h: float, samples: int) -> tuple[float, float]:
    """The paper's one global minimum interval per direction: (Δu, Δv) over a samples × samples grid.

    At each sample the admissible arc gap (`arc_gap`, exact relation, normal curvature across the
    iso-line) is turned into a parameter step with the first fundamental form; the smallest is taken.

    Parameters
    ----------
    patch : Patch
        The patch.
    r : float
        Ball radius, mm.
    h : float
        Scallop height, mm, in (0, r).
    samples : int
        Grid size per parameter direction.

    Returns
    -------
    du : float
        Step between the lines u = const, u units.
    dv : float
        Step between the lines v = const, v units.

    Raises
    ------
    ValueError
        When r or h are out of range (`arc_gap`).
    """
    (u0, u1), (v0, v1) = patch.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, samples), np.linspace(v0, v1, samples), indexing="ij")
    fr = frame(patch, uu, vv)
    ku, su = across_iso_line(fr, "v")  # lines u = const: step in u
    kv, sv = across_iso_line(fr, "u")
    return float(np.min(arc_gap(h, r, ku) / su)), float(np.min(arc_gap(h, r, kv) / sv))


def ring_grid(patch: Patch, *, tool_radius_mm: float, scallop_mm: float, samples_per_line: int = 32,
              strategy: str = "adaptive", corner_mm: float | None = None, max_rings: int = 5000) -> RingGrid:
    """Algorithm 1 on one patch; raises `TooConcave` when the ball does not fit a hollow.

    scallop_mm is the scallop share of the budget (the chord share is taken off by the caller);
    corner_mm (paper strategy) the bound the corner pockets must hold, default scallop_mm.

    Parameters
    ----------
    patch : Patch
        The patch, sign outward.
    tool_radius_mm : float
        Ball radius, mm.
    scallop_mm : float
        The scallop share of the budget, mm: every side gap (and, adaptive, the first ring's edge
        material) holds it.
    samples_per_line : int
        Samples per side of a ring (≥ 4).
    strategy : {'adaptive', 'paper'}
        'paper': global start steps (`global_steps`), first ring on the edges, side steps shrunk for
        the corner pockets (`rings.shrink_for_corners`); 'adaptive': first ring inset
        (`edge.inset_rectangle`), each side's own step.
    corner_mm : float or None
        Paper strategy: the bound the corner pockets must hold, mm; default scallop_mm.
    max_rings : int
        Most rings built.

    Returns
    -------
    RingGrid
        The rings, outermost first, with their predicted side scallops and the first ring's edge
        material.

    Raises
    ------
    ValueError
        When `strategy` or `samples_per_line` is not allowed.
    TooConcave
        When the ball does not fit a hollow, on the grid or on a ring's line.
    NotPlannable
        When no step or first-ring inset keeps the scallop within scallop_mm (degenerate fitted
        surface).
    """
    if strategy not in ("adaptive", "paper"):
        raise ValueError(f"strategy must be 'adaptive' or 'paper', got {strategy!r}")
    if samples_per_line < 4:
        raise ValueError(f"samples_per_line must be at least 4, got {samples_per_line}")
    r, h, k = float(tool_radius_mm), float(scallop_mm), int(samples_per_line)
    check_concavity(patch, r)
    (u0, u1), (v0, v1) = patch.domain
    claim, first, edge = (u0, u1, v0, v1), (u0, u1, v0, v1), np.zeros(4)
    start_u = start_v = None
    if strategy == "paper":
        start_u, start_v = global_steps(patch, r=r, h=h, samples=k)
    else:
        first, edge = inset_rectangle(patch, r=r, h=h, samples=k)
    rects, scallops, steps = [first], [], []
    while len(rects) < max_rings:
        a, b, c, d = rects[-1]
        if a >= b or c >= d:
            break
        sc, wc = side_step(patch, along="u", fixed=c, lo=a, hi=b, direction=1, limit=d, r=r, h=h, samples=k, start=start_v)
        sd, wd = side_step(patch, along="u", fixed=d, lo=a, hi=b, direction=-1, limit=c, r=r, h=h, samples=k, start=start_v)
        sa, wa = side_step(patch, along="v", fixed=a, lo=c, hi=d, direction=1, limit=b, r=r, h=h, samples=k, start=start_u)
        sb, wb = side_step(patch, along="v", fixed=b, lo=c, hi=d, direction=-1, limit=a, r=r, h=h, samples=k, start=start_u)
        na, nb, nc, nd = a + sa, b - sb, c + sc, d - sd
        if na >= nb:  # the sides would cross: one line where both gaps hold
            na = nb = float(np.clip(0.5 * (a + b), b - sb, a + sa))
        if nc >= nd:
            nc = nd = float(np.clip(0.5 * (c + d), d - sd, c + sc))
        if strategy == "paper":
            from cam.plan.rings import shrink_for_corners

            na, nb = shrink_for_corners(patch, (a, b, c, d), (na, nb, nc, nd), r=r,
                                        h=h if corner_mm is None else corner_mm, samples=k)
        rects.append((na, nb, nc, nd))
        scallops.append((wc, wb, wd, wa))
        steps.append((nc - c, b - nb, d - nd, na - a))
    return RingGrid(rects=np.array(rects, dtype=np.float64), side_scallop=np.array(scallops).reshape(-1, 4),
                    side_steps=np.array(steps).reshape(-1, 4), strategy=strategy, claim=claim, edge_scallop=edge)
