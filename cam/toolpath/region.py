"""Where on a patch the ball can finish it: the parameter rectangle free of folds and of tight hollows.

A fitted patch may fold over itself in a thin strip along a border (its boundary curve sits on a
crease that the reconstructed mesh rounded), or hold a hollow whose radius of curvature is not
larger than the tool radius. On neither is a scallop bound meaningful: the first has no outward
normal, the second no tangent ball. The planner machines the largest rectangle it can keep by
moving the sides of the parameter square inward past such samples, cheapest cut first, and
reports what it left out (verify then counts it as never reached). When the trouble is inside,
the rectangle empties and the whole patch is reported, with the reason, never cut.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.bspline import BSplineSurface, fold_mask
from cam.fit.knots import sub_curve
from cam.toolpath.geometry import Patch, frame, principal_curvatures
from cam.toolpath.grid import concave_message
from cam.toolpath.scallop import fits_concave

__all__ = ["Region", "area_share", "finishable_region", "sub_surface", "surface_area"]


@dataclass(frozen=True)
class Region:
    """box: (u0, u1, v0, v1) kept, or None when nothing is; kept: its share of the patch's area;
    reason: why samples were left out ("" when the whole patch is kept)."""

    box: tuple[float, float, float, float] | None
    kept: float
    reason: str


def finishable_region(patch: Patch, tool_radius_mm: float, *, samples: int = 65) -> Region:
    """The parameter rectangle of `patch` without folds or hollows of radius ≤ `tool_radius_mm`.

    Checked on a samples x samples grid; each side moves inward one grid line past the bad samples
    nearest to it, until none is left inside.
    """
    r = float(tool_radius_mm)
    folded, uu, vv = fold_mask(patch.surface, samples=samples)
    fr = frame(patch, uu, vv)
    kmin, _ = principal_curvatures(fr)
    hollow = ~fits_concave(kmin, r) & ~folded  # a fold's curvature is no hollow
    bad = folded | hollow
    area = np.sqrt(np.maximum(fr.e * fr.g - fr.f ** 2, 0.0))
    total = float(area.sum()) or 1.0
    if not bad.any():
        (u0, u1), (v0, v1) = patch.domain
        return Region((u0, u1, v0, v1), 1.0, "")
    i0, i1, j0, j1 = 0, samples - 1, 0, samples - 1
    while True:
        bi, bj = np.nonzero(bad[i0:i1 + 1, j0:j1 + 1])
        if not bi.size:
            break
        bi, bj = bi + i0, bj + j0
        # Each bad sample is cut off by the side nearest to it; that side moves one grid line past
        # the deepest of its samples. A strip along a border costs only its own width.
        depth = np.stack([bi - i0, i1 - bi, bj - j0, j1 - bj])
        nearest = np.argmin(depth, axis=0)
        for side in range(4):
            mine = nearest == side
            if not mine.any():
                continue
            d = int(depth[side, mine].max()) + 1
            if side == 0:
                i0 += d
            elif side == 1:
                i1 -= d
            elif side == 2:
                j0 += d
            else:
                j1 -= d
        if i1 - i0 < 2 or j1 - j0 < 2:
            return Region(None, 0.0, _reason(patch, folded, hollow, kmin, fr, r))
    kept = float(area[i0:i1 + 1, j0:j1 + 1].sum()) / total
    box = (float(uu[i0, 0]), float(uu[i1, 0]), float(vv[0, j0]), float(vv[0, j1]))
    return Region(box, kept, _reason(patch, folded, hollow, kmin, fr, r))


def _reason(patch: Patch, folded, hollow, kmin, fr, r: float) -> str:
    parts = []
    if folded.any():
        i = np.unravel_index(np.argmax(folded), folded.shape)
        parts.append(f"its fitted surface folds over itself ({folded.mean():.1%} of it, near "
                     f"{np.round(fr.p[i], 3).tolist()}): no scallop bound can be certified there; refit "
                     "the patch (fit lists it under 'folded') or change remesh.target_faces")
    if hollow.any():
        i = np.unravel_index(np.argmin(np.where(hollow, kmin, np.inf)), kmin.shape)
        parts.append(concave_message(-1.0 / kmin[i], r, fr.p[i]))
    return "; ".join(parts)


def surface_area(surface: BSplineSurface, box: tuple[float, float, float, float] | None = None, *,
                 samples: int = 64) -> float:
    """Area (mm²) of the surface over its domain or the parameter rectangle `box` (midpoint rule)."""
    (u0, u1), (v0, v1) = surface.domain
    a, b, c, d = box if box is not None else (u0, u1, v0, v1)
    t = (np.arange(samples) + 0.5) / samples
    uu, vv = np.meshgrid(a + t * (b - a), c + t * (d - c), indexing="ij")
    n = np.cross(surface.evaluate(uu, vv, du=1), surface.evaluate(uu, vv, dv=1))
    return float(np.linalg.norm(n, axis=-1).mean()) * (b - a) * (d - c)


def area_share(surface: BSplineSurface, box: tuple[float, float, float, float], *, samples: int = 64) -> float:
    """The share of the surface's area inside the parameter rectangle `box`."""
    total = surface_area(surface, samples=samples)
    return surface_area(surface, box, samples=samples) / total if total > 0 else 0.0


def sub_surface(surface: BSplineSurface, box: tuple[float, float, float, float]) -> BSplineSurface:
    """The same surface on the parameter rectangle `box` = (u0, u1, v0, v1), as its own B-spline
    (exact: knot insertion), with the same parameters."""
    from cam.bspline import make_bspline_surface

    u0, u1, v0, v1 = box
    cp = surface.control_points
    nu, nv = cp.shape[:2]
    ku, P = sub_curve(surface.knots_u, cp.reshape(nu, -1), u0, u1, degree=surface.degree[0])
    P = P.reshape(len(P), nv, 3).transpose(1, 0, 2)
    kv, Q = sub_curve(surface.knots_v, P.reshape(nv, -1), v0, v1, degree=surface.degree[1])
    Q = Q.reshape(len(Q), -1, 3).transpose(1, 0, 2)
    return make_bspline_surface(Q, ku, kv, degree=surface.degree)
