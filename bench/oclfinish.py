"""The OpenCAMLib baseline of bench/part_coverage.py: what a user would script with the field's library.

Per setup, on the same mesh our planner gets (`mesh.ply`, in the setup's machine frame): a drop-cutter
raster along x on the shallow area (contact normal within 60° of the tool axis) and waterline passes on
the steep area (contact normal at least 45° from it), the same slope bands as ours. The raster's
stepover and the waterlines' z step are the flat-surface interval for the scallop height,
2·sqrt(h·(2r − h)). OpenCAMLib's adaptive path drop-cutter re-samples wherever the height changes
faster than its sampling (so a step off a cliff is followed down, not cut through); its cutters carry a
long shank, so no position is under an overhang. Passes are linked the plain way: up to a clearance
height, across, and down at feed. Collinear points (within THIN_MM) are merged. The slope of a waterline
contact comes from the mesh point nearest the ball centre (cam.mesh.closest: the baseline only uses it to
choose where to keep its passes; the check that measures both programs shares no code with cam).
"""

from __future__ import annotations

import numpy as np
from opencamlib import ocl

from cam.mesh.closest import MeshIndex, closest_points, mesh_index

RASTER_MAX_DEG, WATERLINE_MIN_DEG = 60.0, 45.0
SAMPLING_MM, MIN_SAMPLING_MM = 0.2, 0.01
THIN_MM = 1e-4
CLEARANCE_MM, FEED_MM_MIN = 5.0, 1000.0


def _surface(vertices: np.ndarray, faces: np.ndarray) -> ocl.STLSurf:
    surf = ocl.STLSurf()
    for t in vertices[faces].tolist():
        surf.addTriangle(ocl.Triangle(ocl.Point(*t[0]), ocl.Point(*t[1]), ocl.Point(*t[2])))
    return surf


def _runs(points: np.ndarray, keep: np.ndarray, closed: bool = False) -> list[np.ndarray]:
    """Maximal runs of kept points (k, 3) as polylines of at least two points; a closed loop kept whole
    is closed again."""
    if closed and keep.all():
        return [np.vstack([points, points[:1]])]
    if closed and keep.any():
        shift = int(np.flatnonzero(~keep)[0])  # start the loop at a dropped point: no run is cut in two
        points, keep = np.roll(points, -shift, axis=0), np.roll(keep, -shift)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    return [points[a:b] for a, b in zip(edges[::2], edges[1::2]) if b - a >= 2]


def _thin(points: np.ndarray) -> np.ndarray:
    """Drop the points that lie within THIN_MM of the line through their kept neighbours."""
    keep = [0]
    for k in range(1, len(points) - 1):
        a, b, p = points[keep[-1]], points[k + 1], points[k]
        ab = b - a
        t = np.clip(np.dot(p - a, ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
        # Every point skipped since the last kept one must stay close to the longer chord too.
        skipped = points[keep[-1] + 1:k + 1]
        ts = np.clip((skipped - a) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
        if np.linalg.norm(skipped - (a + ts[:, None] * ab), axis=1).max() > THIN_MM or t in (0.0, 1.0):
            keep.append(k)
    keep.append(len(points) - 1)
    return points[keep]


def raster(surf: ocl.STLSurf, cutter: ocl.BallCutter, bounds, floor_z: float, r: float, step: float) -> list[np.ndarray]:
    """Drop-cutter lines along x, alternating, kept where the contact is shallow (tool tips, mm)."""
    x0, x1, y0, y1 = bounds
    cos_max = np.cos(np.radians(RASTER_MAX_DEG))
    passes = []
    for k, y in enumerate(np.arange(y0 + 0.5 * step, y1, step)):
        dropper = ocl.AdaptivePathDropCutter()
        dropper.setSTL(surf)
        dropper.setCutter(cutter)
        dropper.setSampling(SAMPLING_MM)
        dropper.setMinSampling(MIN_SAMPLING_MM)
        dropper.setZ(floor_z)
        path = ocl.Path()
        path.append(ocl.Line(ocl.Point(x0, float(y), floor_z), ocl.Point(x1, float(y), floor_z)))
        dropper.setPath(path)
        dropper.run()
        cl = dropper.getCLPoints()
        tip = np.array([[p.x, p.y, p.z] for p in cl])
        cc = [p.cc() for p in cl]
        on_part = np.array([str(c.type) != "NONE" for c in cc])
        contact = np.array([[c.x, c.y, c.z] for c in cc])
        normal_z = (tip[:, 2] + r - contact[:, 2]) / r
        runs = _runs(tip, on_part & (normal_z >= cos_max - 1e-9))
        passes += [run[::-1] if k % 2 else run for run in runs]
    return passes


def waterline(surf: ocl.STLSurf, cutter: ocl.BallCutter, mesh: MeshIndex, top_z: float, floor_z: float,
              r: float, step: float) -> list[np.ndarray]:
    """Waterline loops from the top down, kept where the contact is steep (tool tips, mm)."""
    cos_min = np.cos(np.radians(WATERLINE_MIN_DEG))
    levels = list(np.arange(top_z - 0.5 * step, floor_z, -step)) + [floor_z + 1e-3]
    passes = []
    for z in levels:
        wl = ocl.AdaptiveWaterline()
        wl.setSTL(surf)
        wl.setCutter(cutter)
        wl.setZ(float(z))
        wl.setSampling(SAMPLING_MM)
        wl.setMinSampling(MIN_SAMPLING_MM)
        wl.run()
        for loop in wl.getLoops():
            tip = np.array([[p.x, p.y, p.z] for p in loop])
            if len(tip) < 2:
                continue
            centre = tip + [0.0, 0.0, r]
            foot = closest_points(mesh, centre)[0]
            d = centre - foot
            normal_z = d[:, 2] / np.maximum(np.linalg.norm(d, axis=1), 1e-300)
            passes += _runs(tip, normal_z < cos_min, closed=True)
    return passes


def ocl_program(vertices: np.ndarray, faces: np.ndarray, *, r: float, h: float,
                step_fraction: float = 1.0) -> tuple[str, dict]:
    """A finishing program for one setup (vertices already in its machine frame) and its pass counts.

    `step_fraction` scales the stepover and the z step below the flat-surface interval for h: a user
    who finds scallops over h on slopes and in corners tightens them this way (the sweep of
    bench/part_coverage.py, which compares path lengths at equal largest left)."""
    surf = _surface(vertices, faces)
    cutter = ocl.BallCutter(2.0 * r, 1000.0)
    mesh = mesh_index(vertices, faces)
    step = step_fraction * 2.0 * np.sqrt(h * (2.0 * r - h))
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    bounds = (lo[0] - r, hi[0] + r, lo[1] - r, hi[1] + r)
    shallow = raster(surf, cutter, bounds, float(lo[2]), r, step)
    steep = waterline(surf, cutter, mesh, float(hi[2]), float(lo[2]), r, step)
    clear = float(hi[2]) + CLEARANCE_MM
    lines = ["G21 G90 G17", f"G0 Z{clear:.4f}"]
    for run in shallow + steep:
        run = _thin(run)
        lines += [f"G0 X{run[0, 0]:.4f} Y{run[0, 1]:.4f}", f"G1 Z{run[0, 2]:.4f} F{FEED_MM_MIN:.0f}"]
        lines += [f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f}" for x, y, z in run[1:]]
        lines.append(f"G0 Z{clear:.4f}")
    lines.append("M2")
    return "\n".join(lines) + "\n", {"raster_passes": len(shallow), "waterline_passes": len(steep)}
