"""Baseline for bench/toolpath.py: an OpenCAMLib drop-cutter raster on the same surfaces, verified by our
`verify` measurement, with the stepover that makes its verified maximum scallop meet the target.

OpenCAMLib (LGPL, bench-only) drops a ball end mill onto a triangulation of every surface of the setup
(so the raster cannot cut a neighbour), along lines of constant y. A contact point counts for a patch when
it lies over that patch's claimed parameter rectangle (its footprint seen along the tool axis). The first and
last lines are inset by half a step along the surface, like our first ring, from the lines whose ball touches
the border (on a wall, not at all). Each run of such points (sampled finely, so the last one stands within a
sample of the border) is one pass. Straight moves between drop positions are thinned only where the tool-tip
polyline stays within THIN_MM of the dropped positions: on a convex pass a longer chord would dip into the
part. The stepover search starts at the flat-plane stepover for the target, widens by 10 % while the verified
maximum over the claimed rectangles stays under the target and narrows by sqrt(target / maximum) (at least
10 %) while it is over; it keeps the widest stepover that met the target. Verify measures material up to a
quarter of r: a maximum of r / 4 means at least that much is left.
"""

from __future__ import annotations

import time

import numpy as np
from matplotlib.path import Path as Polygon
from opencamlib import ocl

from cam.gcode import parse_program, write_program
from cam.plan.link import link_passes
from cam.plan.scallop import flat_spacing
from cam.spline.geometry import Patch, frame
from cam.verify import measure_program
from cam.verify.measure import (
    _grid as sample_grid,  # the same spacing rule verify samples with
)

THIN_MM = 5e-4  # on a convex pass a thinned chord dips into the part: keep it under the 0.001 mm gouge limit
FACET_MM = 0.2  # triangle size: the facets' sag below the surface stays under 0.002 mm where its radius is ≥ 3 mm


def triangulate(patches: list[Patch], spacing_mm: float) -> np.ndarray:
    """All patches sampled about spacing_mm apart as one triangle soup, float64 (n, 3, 3)."""
    tris = []
    for p in patches:
        uu, vv = np.meshgrid(*sample_grid(p, spacing_mm, 2000), indexing="ij")
        x = p.surface.evaluate(uu, vv)
        a, b, c, d = x[:-1, :-1], x[1:, :-1], x[1:, 1:], x[:-1, 1:]
        tris += [np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)]
    return np.concatenate(tris)


def _stl(tris: np.ndarray) -> ocl.STLSurf:
    surf = ocl.STLSurf()
    for t in tris.tolist():
        surf.addTriangle(ocl.Triangle(ocl.Point(*t[0]), ocl.Point(*t[1]), ocl.Point(*t[2])))
    return surf


def _border_uv(patch: Patch, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Parameters round the claimed rectangle's border, a hair inside: a ball hanging over the border
    touches it exactly there, and such a drop is not on the patch."""
    (u0, u1), (v0, v1) = patch.domain
    du, dv = 1e-5 * (u1 - u0), 1e-5 * (v1 - v0)
    u0, u1, v0, v1 = u0 + du, u1 - du, v0 + dv, v1 - dv
    t = np.linspace(0, 1, samples, endpoint=False)
    u = np.concatenate([u0 + t * (u1 - u0), np.full(samples, u1), u1 - t * (u1 - u0), np.full(samples, u0)])
    v = np.concatenate([np.full(samples, v0), v0 + t * (v1 - v0), np.full(samples, v1), v1 - t * (v1 - v0)])
    return u, v


def footprint(patch: Patch, samples: int = 64) -> Polygon:
    """The claimed rectangle's border seen along the tool axis, as a closed xy polygon."""
    return Polygon(patch.surface.evaluate(*_border_uv(patch, samples))[:, :2], closed=False)


def border_lines(patch: Patch, r: float, stepover_mm: float, samples: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Where the raster's lines touch the footprint's lowest and highest border, and how steep it is there.

    A dropped ball touches a point p with outward normal n from the line y = p_y + r n_y: on a slope that is
    downhill of p, by up to r. Returns ((y_lo, y_hi), (c_lo, c_hi)): the median of that line over the border
    points within a stepover of the footprint's lowest (highest) y, and the cos of the steepest slope across
    the lines there (half a step in y is half a step times that along the surface; 0 on a wall facing y).
    """
    u, v = _border_uv(patch, samples)
    f = frame(patch, u, v)
    across = np.hypot(f.n[:, 1], f.n[:, 2])
    # A border point whose normal has no y or z part (a wall facing x) does not slope across the lines.
    cos = np.where(across > 1e-12, np.abs(f.n[:, 2]) / np.maximum(across, 1e-300), 1.0)
    line = f.p[:, 1] + r * f.n[:, 1]
    y0, y1 = f.p[:, 1].min(), f.p[:, 1].max()
    lo, hi = f.p[:, 1] <= y0 + stepover_mm, f.p[:, 1] >= y1 - stepover_mm
    # A collapsed corner has no normal (NaN): it touches from no particular line.
    t0, t1 = (float(np.nanmedian(line[m])) if np.isfinite(line[m]).any() else y for m, y in ((lo, y0), (hi, y1)))
    return np.array([t0, t1]), np.array([cos[lo].min(), cos[hi].min()])


def _thin(tips: np.ndarray, tol: float) -> np.ndarray:
    """Douglas–Peucker on a tool-tip polyline (n, 3): keep what a straight move cannot replace within tol."""
    keep = np.zeros(len(tips), bool)
    keep[[0, -1]] = True
    stack = [(0, len(tips) - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        seg = tips[b] - tips[a]
        w = tips[a + 1:b] - tips[a]
        t = np.clip(w @ seg / max(seg @ seg, 1e-300), 0, 1)
        d = np.linalg.norm(w - t[:, None] * seg, axis=1)
        k = int(np.argmax(d))
        if d[k] > tol:
            keep[a + 1 + k] = True
            stack += [(a, a + 1 + k), (a + 1 + k, b)]
    return tips[keep]


def raster(tris: np.ndarray, machined: list[Patch], *, r: float, stepover_mm: float, sample_mm: float,
           tol_mm: float) -> list[tuple[int, list[np.ndarray]]]:
    """Drop-cutter raster passes (tool tips) over each machined patch's footprint, lines along x.

    tris: the whole part's triangles (n, 3, 3). This OpenCAMLib build tests every triangle against every
    drop position, so each line gets only the triangles the ball can reach from it (within r in y).
    """
    cutter = ocl.BallCutter(2 * r, 10 * r)
    lo, hi = tris.min(axis=1), tris.max(axis=1)
    out = []
    for p in machined:
        poly = footprint(p)
        (x0, y0), (x1, y1) = poly.vertices.min(axis=0), poly.vertices.max(axis=0)
        # Lines evenly spaced, the first and last half a step inside the border as our first ring is. That
        # is measured from the lines that touch the border (on a slope the ball touches uphill of its line)
        # and along the surface across the lines (c: cos of the border's slope in y; on a wall the line
        # touches the border). n lines span (n - 1 + (c0 + c1) / 2) steps; the fewest with a step within
        # the stepover. Lines go on beyond at the stepover, where the border is not straight in x; a wall's
        # footprint is a sliver, so those are spaced by the stepover, not by the inner step.
        (t0, t1), (c0, c1) = border_lines(p, r, stepover_mm)
        span, ends = t1 - t0, (c0 + c1) / 2
        n = max(int(np.ceil(span / stepover_mm - ends + 1 - 1e-9)), 1)
        if span > 0 and n - 1 + ends > 0:
            step = span / (n - 1 + ends)
            inner = t0 + c0 * step / 2 + np.arange(n) * step
        else:
            inner = np.array([(t0 + t1) / 2])
        out_k = np.arange(1, int(np.ceil(r / stepover_mm)) + 1) * stepover_mm
        ys = np.concatenate([inner[0] - out_k[::-1], inner, inner[-1] + out_k])
        xs = np.arange(x0 - r, x1 + r + sample_mm, sample_mm)
        passes = []
        for k, y in enumerate(ys):
            near = (lo[:, 1] <= y + r) & (hi[:, 1] >= y - r) & (hi[:, 0] >= xs[0] - r) & (lo[:, 0] <= xs[-1] + r)
            if not near.any():
                continue
            stl = _stl(tris[near])
            drop = ocl.BatchDropCutter()
            drop.setSTL(stl)
            drop.setCutter(cutter)
            for x in xs:
                drop.appendPoint(ocl.CLPoint(float(x), float(y), -1e4))
            drop.run()
            cl = drop.getCLPoints()
            tips = np.array([[q.x, q.y, q.z] for q in cl])
            cc = np.array([[q.getCC().x, q.getCC().y] for q in cl])
            hit = np.array([str(q.getCC().type) != "NONE" for q in cl])
            mask = poly.contains_points(cc) & hit
            edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
            for a, b in zip(edges[::2], edges[1::2]):
                if b - a >= 2:
                    line = _thin(tips[a:b], tol_mm)
                    passes.append(line if k % 2 == 0 else line[::-1])
        if passes:
            out.append((p.id, passes))
    return out


def measure_raster(tris, machined: list[Patch], part: list[Patch], *, r: float, h: float, stepover_mm: float,
                   clearance_z: float) -> dict:
    """One raster at `stepover_mm`, written as G-code, parsed and measured like any program."""
    t0 = time.perf_counter()
    passes = raster(tris, machined, r=r, stepover_mm=stepover_mm, sample_mm=min(0.1, stepover_mm / 4),
                    tol_mm=THIN_MM)
    t_plan = time.perf_counter() - t0
    moves = link_passes(passes, clearance_z=clearance_z, retract_mm=1.0)
    prog = parse_program(write_program(moves, header={}))
    m = measure_program(prog, machined, part, tool_radius_mm=r, target_mm=h)
    st, rep = moves.stats(), m.report
    return {"stepover": stepover_mm, "max": rep["max_scallop_mm"] or 0.0, "length": st["cut_length_mm"],
            "air": st["air_length_mm"], "retracts": st["retracts"], "reached": 1 - rep["fraction_never_reached"],
            "over": rep["fraction_over_target"], "uncut": rep["uncut_area_mm2"],
            "gouge": max(rep["max_gouge_mm"], rep["max_rapid_gouge_mm"]),
            "t_plan": t_plan}


def matched_raster(machined: list[Patch], part: list[Patch], *, r: float, h: float, clearance_z: float,
                   tries: int = 3) -> dict:
    """The raster whose verified maximum meets the target with the widest stepover found in `tries`."""
    tris = triangulate(part, spacing_mm=FACET_MM)
    s = float(flat_spacing(h, r))
    best, tried = None, []
    for _ in range(tries):
        res = measure_raster(tris, machined, part, r=r, h=h, stepover_mm=s, clearance_z=clearance_z)
        tried.append(res)
        print(f"    raster stepover {s:.4f} mm: verified max {res['max']:.4f} mm", flush=True)
        if res["max"] <= h and (best is None or res["stepover"] > best["stepover"]):
            best = res
        if best is not None and best["max"] >= 0.8 * h:
            break
        # Wider while it stays under the target, narrower (at least 10 %) while it is over.
        s = s * (1.1 if res["max"] <= h else min(np.sqrt(h / res["max"]), 0.9))
    chosen = best if best is not None else min(tried, key=lambda x: x["max"])
    return {**chosen, "met": best is not None, "tries": len(tried)}
