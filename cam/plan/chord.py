"""Points along the passes: straight moves whose chord error stays within its share of the scallop budget.

The budget h is split: the grid plans the scallop with h_s = (1 − f)·h and the straight moves
between cutter positions may deviate from the ideal ball-centre curve by at most δ = f·h.
Where the path bends towards the tool (convex along the pass) a chord would cut under the centre
curve and gouge; there both ends of a move are lifted along the normal by the chord's dip, so the
move stays on or above the ideal offset and leaves at most δ of extra material. Where the path is
hollow along the pass the chord lies above the curve and leaves at most δ too. Either way the
material left is at most h_s + δ = h.

A chord can also leave the centre curve sideways, in the tangent plane, where an iso-line bends
within the surface (common on fitted patches whose domain square maps to a curved quadrilateral).
That moves the contact towards or away from the neighbouring pass; at a point between them the
ball's surface meets the normal line at an angle φ from its radius, so the material changes by at
most the sideways deviation times tan φ. The caller passes tan φ (`lateral_weight`) and that share
is added to each move's error.

Vertices of iso-parameter passes sit on one lattice per parameter direction, uniform over the patch
and fine enough for the patch's largest bending, so that neighbouring passes have their vertices side
by side (the extra material of two lifted passes then lines up instead of smearing out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.plan.errors import NotPlannable
from cam.spline.geometry import Patch, frame, normal_curvature

__all__ = ["PassPoints", "discretize", "lattices"]


@dataclass(frozen=True)
class PassPoints:
    """Cutter positions of one parameter path.

    Attributes
    ----------
    uv : (n, 2) float64
        Contact parameters (u, v) of each position.
    cc : (n, 3) float64
        Contact points, mm, in the patch's frame.
    normal : (n, 3) float64
        Outward unit normals at the contact points.
    centre : (n, 3) float64
        Ball centres after chord lifts, mm: contact + (r + lift)·normal.
    lift : (n,) float64
        Chord lift of each position, mm along the normal.
    kind : (n − 1,) int8
        Per move: 0 side, 1 link, 2 excursion.
    chord_error : (n − 1,) float64
        The extra material each move may leave, mm.
    """

    uv: np.ndarray
    cc: np.ndarray
    normal: np.ndarray
    centre: np.ndarray
    lift: np.ndarray
    kind: np.ndarray
    chord_error: np.ndarray


def lattices(patch: Patch, *, r: float, tol: float, samples: int = 25) -> tuple[np.ndarray, np.ndarray]:
    """Uniform vertex lattices (u values, v values) whose steps keep the centre-curve chord sag ≤ tol.

    The sag of a step Δ along u is Δ²·|S_u|²·|κ_u|·(1 + rκ_u)/8 (the centre curve is the contact curve
    scaled by 1 + rκ, with curvature κ/(1 + rκ)); the lattice takes the worst point of a grid.

    Parameters
    ----------
    patch : Patch
        The patch.
    r : float
        Ball radius, mm.
    tol : float
        Largest chord sag of the ball-centre curve, mm.
    samples : int
        Grid of samples × samples points over the domain on which the worst bending is taken.

    Returns
    -------
    lat_u : (k_u + 1,) float64
        Evenly spaced u values from u0 to u1 (just the two ends where the u lines do not bend).
    lat_v : (k_v + 1,) float64
        The same for v.
    """
    (u0, u1), (v0, v1) = patch.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, samples), np.linspace(v0, v1, samples), indexing="ij")
    fr = frame(patch, uu, vv)
    out = []
    for (lo, hi), du, dv, speed2 in (((u0, u1), 1.0, 0.0, fr.e), ((v0, v1), 0.0, 1.0, fr.g)):
        k = normal_curvature(fr, np.full_like(uu, du), np.full_like(uu, dv))
        bend = np.max(speed2 * np.abs(k) * np.maximum(1 + r * k, 0.0))
        n = 1 if bend <= 1e-12 else int(np.ceil((hi - lo) / np.sqrt(8 * tol / bend)))
        out.append(np.linspace(lo, hi, n + 1))
    return out[0], out[1]


def _vertices(uv: np.ndarray, kind: np.ndarray, lat_u: np.ndarray, lat_v: np.ndarray):
    step_u = np.min(np.diff(lat_u)) if len(lat_u) > 1 else np.inf
    step_v = np.min(np.diff(lat_v)) if len(lat_v) > 1 else np.inf
    pts, kinds = [uv[0]], []
    for q0, q1, kd in zip(uv[:-1], uv[1:], kind):
        if q0[1] == q1[1] and q0[0] != q1[0]:
            inner = lat_u[(lat_u > min(q0[0], q1[0])) & (lat_u < max(q0[0], q1[0]))]
            inner = inner if q1[0] > q0[0] else inner[::-1]
            seg = [np.array([x, q0[1]]) for x in inner]
        elif q0[0] == q1[0] and q0[1] != q1[1]:
            inner = lat_v[(lat_v > min(q0[1], q1[1])) & (lat_v < max(q0[1], q1[1]))]
            inner = inner if q1[1] > q0[1] else inner[::-1]
            seg = [np.array([q0[0], y]) for y in inner]
        else:
            n = int(np.ceil(max(abs(q1[0] - q0[0]) / step_u, abs(q1[1] - q0[1]) / step_v, 1.0)))
            t = np.linspace(0, 1, n + 1)[1:-1, None]
            seg = list(q0 * (1 - t) + q1 * t)
        for p in [*seg, q1]:
            if not np.array_equal(p, pts[-1]):
                pts.append(np.asarray(p, dtype=np.float64))
                kinds.append(int(kd))
    return np.array(pts), np.array(kinds, dtype=np.int8)


def _deviation(centre: np.ndarray, probe_c: np.ndarray, probe_n: np.ndarray,
               probes: int) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (m, probes) of probe centres above (+, towards the tool) the chord of their move,
    and their distance from it across the normal (sideways, ≥ 0)."""
    a, b = centre[:-1, None, :], centre[1:, None, :]
    ab = b - a
    t = np.clip(np.einsum("mpk,mpk->mp", probe_c - a, ab) / np.maximum(np.einsum("mpk,mpk->mp", ab, ab), 1e-300), 0, 1)
    d = probe_c - (a + t[..., None] * ab)
    up = np.einsum("mpk,mpk->mp", d, probe_n)
    return up, np.sqrt(np.maximum(np.einsum("mpk,mpk->mp", d, d) - up * up, 0.0))


def discretize(patch: Patch, uv: np.ndarray, kind: np.ndarray, *, r: float, tol: float,
               lat_u: np.ndarray, lat_v: np.ndarray, probes: int = 3, lateral_weight: float = 0.0) -> PassPoints:
    """Cutter positions along a parameter path (uv float (m, 2), kind int (m − 1,)) with chord error ≤ tol.

    Each move is probed at `probes` interior points; moves whose error would exceed tol are split.
    Segments along u (v constant) get a vertex at every lattice u between their ends, segments along v
    likewise; other segments are split evenly at the finest lattice step. Where a move's chord passes
    below its probes (towards the part) both its ends are lifted along the normal by the dip. A move's
    error is the largest of its ends' lifts and its probes' distances below or above the chord, plus
    `lateral_weight` times its largest sideways deviation; moves over `tol` are halved, up to 8 rounds.

    Parameters
    ----------
    patch : Patch
        The patch the path runs on.
    uv : (m, 2) float
        Corner points of the parameter path (straight parameter segments between them).
    kind : (m − 1,) int
        Per segment: 0 side, 1 link, 2 excursion; every move cut from a segment keeps its kind.
    r : float
        Ball radius, mm.
    tol : float
        Chord error allowed per move, mm (> 0).
    lat_u, lat_v : (k,) float64
        Vertex lattices in u and v (`lattices`).
    probes : int
        Interior points probed per move.
    lateral_weight : float
        mm of material per mm of sideways chord deviation (tan φ, see the module docstring); ≥ 0.

    Returns
    -------
    PassPoints
        The positions along the path, every move's ``chord_error`` ≤ tol. A path of one point gives one
        position and no moves.

    Raises
    ------
    ValueError
        When `tol` is not positive or `lateral_weight` is negative or NaN.
    NotPlannable
        When after 8 rounds of splitting some move still exceeds `tol` (a degenerate fitted surface).
    """
    if tol <= 0:
        raise ValueError(f"chord tolerance must be positive, got {tol} mm")
    if not lateral_weight >= 0:
        raise ValueError(f"lateral_weight must be a non-negative number, got {lateral_weight}")
    verts, kinds = _vertices(np.asarray(uv, float), np.asarray(kind), lat_u, lat_v)
    if len(verts) == 1:
        fr = frame(patch, verts[:, 0], verts[:, 1])
        return PassPoints(verts, fr.p, fr.n, fr.p + r * fr.n, np.zeros(1), np.zeros(0, np.int8), np.zeros(0))
    for _ in range(8):
        fr = frame(patch, verts[:, 0], verts[:, 1])
        centre0 = fr.p + r * fr.n
        t = (np.arange(1, probes + 1) / (probes + 1))[None, :, None]
        puv = verts[:-1, None, :] * (1 - t) + verts[1:, None, :] * t
        pf = frame(patch, puv[..., 0], puv[..., 1])
        pc = pf.p + r * pf.n
        lift = np.zeros(len(verts))
        for _ in range(4):  # lifting one end changes the chord: settle the lifts
            centre = centre0 + lift[:, None] * fr.n
            dev, _ = _deviation(centre, pc, pf.n, probes)
            dip = np.max(np.maximum(dev, 0.0), axis=1)
            if np.all(dip <= 1e-9):
                break
            need = np.zeros(len(verts))
            need[:-1] = np.maximum(need[:-1], dip)
            need[1:] = np.maximum(need[1:], dip)
            lift += need
        centre = centre0 + lift[:, None] * fr.n
        dev, side = _deviation(centre, pc, pf.n, probes)
        err = np.maximum(np.maximum(lift[:-1], lift[1:]), np.max(-np.minimum(dev, 0.0), axis=1))
        err = np.maximum(err, np.max(np.maximum(dev, 0.0), axis=1)) + lateral_weight * np.max(side, axis=1)
        split = err > tol * (1 + 1e-9)
        if not np.any(split):
            return PassPoints(verts, fr.p, fr.n, centre, lift, kinds, err)
        mids = 0.5 * (verts[:-1][split] + verts[1:][split])
        order = np.concatenate([np.arange(len(verts)), np.flatnonzero(split) + 0.5])
        verts = np.concatenate([verts, mids])[np.argsort(order, kind="stable")]
        kinds = np.concatenate([kinds, kinds[split]])[np.argsort(np.concatenate([np.arange(len(kinds)),
                                                                               np.flatnonzero(split) + 0.5]),
                                                                kind="stable")]
    raise NotPlannable(f"the chord error of its passes did not settle below {tol:.4g} mm: the fitted surface is "
                       "degenerate there; refit the patch")
