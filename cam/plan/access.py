"""Setups and accessibility: which setup machines which patch, and what no setup reaches.

A 3-axis ball end reaches a surface point from +Z (machine frame) when the normal does not face
away from the tool, the ball tangent there does not cut any patch, and the shank above the ball
meets nothing. Each patch goes to the given setup that reaches most of it; when that is less than
`min_reach` of the patch, the setup with the opposite tool axis (the part turned over about machine
X) is tried as a second setup. A patch no setup reaches at all is listed as unmachined with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam.gcode.setup import Setup
from cam.plan.gouge import SurfaceIndex, build_index, clearance, shank_clear
from cam.spline.geometry import Patch, frame, machine_patches
from cam.spline.surface import BSplineSurface

__all__ = ["Assignment", "assign_setups", "opposite_setup", "reach"]


@dataclass
class Assignment:
    """Which setup machines which patch, and the patches no setup reaches.

    Attributes
    ----------
    setups : list of Setup
        The setups in use, the given ones first (the opposite setup after them, when a patch went to it).
    patches : dict of int to list of int
        ``patches[setup id]``: the ids of the patches that setup machines.
    unmachined : list of dict
        ``{"patch": id, "reason": str}`` for every patch no setup reaches.
    reach : dict of int to float
        ``reach[patch id]``: the fraction (0..1] of the patch its setup reaches.
    """

    setups: list[Setup]
    patches: dict[int, list[int]] = field(default_factory=dict)
    unmachined: list[dict] = field(default_factory=list)
    reach: dict[int, float] = field(default_factory=dict)


def opposite_setup(setup: Setup, surfaces: list[BSplineSurface], *, new_id: int) -> Setup:
    """The part turned over about machine X, placed so its lowest point and xy centre stay where they were.

    Parameters
    ----------
    setup : Setup
        The setup to turn over.
    surfaces : list of BSplineSurface
        The part's surfaces, part frame, mm; their control points give the lowest point (smallest
        machine z) and the xy centre (mean machine x, y) that are kept.
    new_id : int
        Id of the new setup.

    Returns
    -------
    Setup
        Rotation diag(1, −1, −1) · ``setup.rotation`` (the opposite tool axis), translation (mm) such
        that the control points' lowest z and mean x, y are those in `setup`.
    """
    flip = np.diag([1.0, -1.0, -1.0])
    rot = flip @ setup.rotation
    pts = np.concatenate([s.control_points.reshape(-1, 3) for s in surfaces])
    m1 = setup.to_machine(pts)
    m2 = pts @ rot.T
    shift = np.array([*(m1[:, :2].mean(0) - m2[:, :2].mean(0)), m1[:, 2].min() - m2[:, 2].min()])
    return Setup(id=new_id, rotation=rot, translation=shift)


def reach(index: SurfaceIndex, patch: Patch, r: float, *, samples: int = 10) -> tuple[float, str]:
    """Fraction of a samples × samples grid of the patch the ball reaches, and the main reason for the rest.

    A sample is reached when its outward normal has a positive z part (faces the tool), the tangent ball
    there clears every patch of `index` (to 1e-4 mm) and its shank meets none (`shank_clear`).

    Parameters
    ----------
    index : SurfaceIndex
        The whole part, machine frame (`build_index`).
    patch : Patch
        The patch, in the same machine frame, sign outward.
    r : float
        Ball radius, mm.
    samples : int
        Grid size per parameter direction; the grid spans 2 % to 98 % of the domain.

    Returns
    -------
    fraction : float
        Share of the samples reached, in [0, 1].
    reason : str
        The most frequent of "the surface faces away from the tool", "the ball would cut a neighbouring
        surface" and "the tool shank would hit the part" among the rest; "" when every sample is reached.
    """
    (u0, u1), (v0, v1) = patch.domain
    g = np.linspace(0.02, 0.98, samples)
    uu, vv = np.meshgrid(u0 + g * (u1 - u0), v0 + g * (v1 - v0), indexing="ij")
    fr = frame(patch, uu.ravel(), vv.ravel())
    centre = fr.p + r * fr.n
    facing = fr.n[:, 2] > 1e-6
    ball = clearance(index, centre, r) >= -1e-4
    shank = shank_clear(index, centre, r)
    ok = facing & ball & shank
    if ok.all():
        return 1.0, ""
    counts = {"the surface faces away from the tool": int((~facing).sum()),
              "the ball would cut a neighbouring surface": int((facing & ~ball).sum()),
              "the tool shank would hit the part": int((facing & ball & ~shank).sum())}
    return float(ok.mean()), max(counts, key=counts.get)


def assign_setups(ids: list[int], surfaces: list[BSplineSurface], signs: np.ndarray, setups: list[Setup], *,
                  r: float, min_reach: float = 0.5, spacing_mm: float | None = None,
                  skip: set[int] = frozenset(), obstacles: list[BSplineSurface] | None = None,
                  add_opposite: bool = True) -> Assignment:
    """Give every patch the setup that reaches most of it; add the opposite setup when that helps.

    Patches in `skip` (already reported by the caller) still count as part of the part but get no setup.
    When some patch's best fraction is below `min_reach`, the setup opposite to ``setups[0]``
    (`opposite_setup`) is tried for those patches; it is kept only when a patch goes to it. A patch
    that no setup reaches at all is listed under ``unmachined`` with the reason of the first setup.

    Parameters
    ----------
    ids : list of int
        Patch ids, one per surface.
    surfaces : list of BSplineSurface
        The surfaces to finish, part frame, mm.
    signs : (len(surfaces),) float64
        +1/−1 per surface making S_u × S_v outward.
    setups : list of Setup
        The given setups; at least one.
    r : float
        Ball radius, mm.
    min_reach : float
        Reachable fraction (0..1) below which the opposite setup is tried.
    add_opposite : bool
        Whether the opposite setup may be added (False: the setups given are all there are).
    spacing_mm : float or None
        Sample spacing of the part's `SurfaceIndex`, mm; default max(r / 4, 0.25).
    skip : set of int
        Patch ids the caller has already reported: no setup for them.
    obstacles : list of BSplineSurface or None
        The whole surfaces the tool must not cut, when `surfaces` are only the parts to finish (one per id,
        part frame, mm); default `surfaces`.

    Returns
    -------
    Assignment
        The setups in use, the patches of each, the unmachined patches and each patch's reach.

    Raises
    ------
    ValueError
        When `setups` is empty.
    """
    if not setups:
        raise ValueError("at least one setup is needed")
    spacing = spacing_mm or max(r / 4, 0.25)
    out = Assignment(setups=list(setups))
    scores: dict[int, list[tuple[float, str]]] = {i: [] for i in ids}
    solid = surfaces if obstacles is None else obstacles

    def reaches(setup: Setup, which) -> None:
        index = build_index(machine_patches(ids, solid, signs, setup), spacing_mm=spacing)
        for p in machine_patches(ids, surfaces, signs, setup):
            scores[p.id].append(reach(index, p, r) if which(p.id) else (-1.0, ""))

    for setup in setups:
        reaches(setup, lambda i: True)
    weak = [i for i in ids if i not in skip and max(f for f, _ in scores[i]) < min_reach]
    extra = None
    if weak and add_opposite:
        extra = opposite_setup(setups[0], solid, new_id=max(s.id for s in setups) + 1)
        reaches(extra, lambda i: i in weak)
    all_setups = list(setups) + ([extra] if extra is not None else [])
    used = set()
    for i in ids:
        if i in skip:
            continue
        fractions = [f for f, _ in scores[i]]
        k = int(np.argmax(fractions))
        if fractions[k] <= 0:
            reason = scores[i][0][1] or "no setup reaches it"
            out.unmachined.append({"patch": int(i), "reason": f"no setup reaches it: {reason}"})
            continue
        out.patches.setdefault(all_setups[k].id, []).append(int(i))
        out.reach[int(i)] = fractions[k]
        used.add(k)
    if extra is not None and len(all_setups) - 1 in used:
        out.setups.append(extra)
    return out
