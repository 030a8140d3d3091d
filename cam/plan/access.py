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
    """setups: the setups in use (given ones first); patches[setup id] = patch ids it machines;
    unmachined: [{"patch", "reason"}]; reach[patch id] = reachable fraction in its setup."""

    setups: list[Setup]
    patches: dict[int, list[int]] = field(default_factory=dict)
    unmachined: list[dict] = field(default_factory=list)
    reach: dict[int, float] = field(default_factory=dict)


def opposite_setup(setup: Setup, surfaces: list[BSplineSurface], *, new_id: int) -> Setup:
    """The part turned over about machine X, placed so its lowest point and xy centre stay where they were."""
    flip = np.diag([1.0, -1.0, -1.0])
    rot = flip @ setup.rotation
    pts = np.concatenate([s.control_points.reshape(-1, 3) for s in surfaces])
    m1 = pts @ setup.rotation.T + setup.translation
    m2 = pts @ rot.T
    shift = np.array([*(m1[:, :2].mean(0) - m2[:, :2].mean(0)), m1[:, 2].min() - m2[:, 2].min()])
    return Setup(id=new_id, rotation=rot, translation=shift)


def reach(index: SurfaceIndex, patch: Patch, r: float, *, samples: int = 10) -> tuple[float, str]:
    """Fraction of a samples × samples grid of the patch the ball reaches, and the main reason for the rest."""
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
                  skip: set[int] = frozenset(), obstacles: list[BSplineSurface] | None = None) -> Assignment:
    """Give every patch the setup that reaches most of it; add the opposite setup when that helps.

    Patches in `skip` (already reported by the caller) still count as part of the part but get no setup.
    obstacles: the whole surfaces the tool must not cut, when `surfaces` are only the parts to finish.
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
    if weak:
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
