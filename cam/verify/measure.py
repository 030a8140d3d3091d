"""Independent measurement of what a program leaves on the part: scallop, overcut, reach.

Nothing here comes from the planner: the cutter motion is re-derived from the parsed program (ball
centre = tool tip + r·Z), the surfaces are sampled on their own grid (spacing a fraction of the flat
pass interval), and a sample counts as reachable only when the tangent ball there contains no other
sample of the part and no sample stands inside the shank above it. For every sample the normal line
is met with every nearby swept capsule: the first entry above the surface is the material left there
(the scallop), and a sample inside a capsule is overcut by its depth in it (gouge), for cutting and rapid
moves separately. Around the highest samples the maximum is refined on finer local grids, since the
cusp between two passes is a ridge that a grid only brushes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from cam import CheckCancel
from cam.gcode.parser import ParsedProgram
from cam.gcode.sweep import Sweep
from cam.spline.folds import flipped_normals
from cam.spline.geometry import Patch
from cam.verify.solid import SampleSolid

__all__ = ["Measurement", "heat_colors", "measure_program"]


@dataclass(frozen=True)
class Measurement:
    """What `measure_program` finds: the report and the samples as a heat-map mesh.

    Attributes
    ----------
    report : dict
        The JSON-ready numbers.
    vertices : (n, 3) float64
        The samples of every machined patch, mm, machine frame.
    faces : (m, 3) int64
        Two triangles per cell of each patch's sample grid, indices into `vertices`.
    scallop : (n,) float64
        Material left at each sample, mm (NaN where unreachable, +inf where never reached).
    patch : (n,) int64
        The patch id of each sample.
    """

    report: dict
    vertices: np.ndarray
    faces: np.ndarray
    scallop: np.ndarray
    patch: np.ndarray


def _grid(patch: Patch, spacing: float, cap: int):
    (u0, u1), (v0, v1) = patch.domain
    g = np.linspace(0, 1, 9)
    uu, vv = np.meshgrid(u0 + g * (u1 - u0), v0 + g * (v1 - v0), indexing="ij")
    lu = np.max(np.linalg.norm(patch.surface.evaluate(uu, vv, du=1), axis=-1)) * (u1 - u0)
    lv = np.max(np.linalg.norm(patch.surface.evaluate(uu, vv, dv=1), axis=-1)) * (v1 - v0)
    nu = int(min(max(np.ceil(lu / spacing), 2), cap)) + 1
    nv = int(min(max(np.ceil(lv / spacing), 2), cap)) + 1
    return np.linspace(u0, u1, nu), np.linspace(v0, v1, nv)


def _eval(patch: Patch, u: np.ndarray, v: np.ndarray):
    p = patch.surface.evaluate(u, v)
    su, sv = patch.surface.evaluate(u, v, du=1), patch.surface.evaluate(u, v, dv=1)
    cross = np.cross(su, sv) * patch.sign
    area = np.linalg.norm(cross, axis=-1)
    return p, cross / np.maximum(area, 1e-300)[..., None], area


def heat_colors(scallop: np.ndarray, target: float) -> np.ndarray:
    """uint8 (n, 3): blue → green → yellow → red up to the target, magenta above it, grey unreachable,
    black never reached.

    Parameters
    ----------
    scallop : (n,) float
        Material left per sample, mm (NaN unreachable, +inf never reached), as `Measurement.scallop`.
    target : float
        The target scallop height, mm (> 0).

    Returns
    -------
    (n, 3) uint8
        RGB colour of each sample.
    """
    x = np.clip(np.nan_to_num(scallop, nan=0.0, posinf=0.0) / target, 0, 1)
    stops = np.array([[40, 60, 220], [40, 200, 80], [240, 220, 40], [220, 40, 30]], float)
    pos = x * (len(stops) - 1)
    k = np.minimum(pos.astype(int), len(stops) - 2)
    f = (pos - k)[:, None]
    rgb = stops[k] * (1 - f) + stops[k + 1] * f
    rgb[np.nan_to_num(scallop, nan=0.0) > target * (1 + 1e-9)] = [230, 0, 230]
    rgb[np.isnan(scallop)] = [150, 150, 150]
    rgb[np.isposinf(scallop)] = [0, 0, 0]
    return rgb.astype(np.uint8)


def _golden(fn, lo: np.ndarray, hi: np.ndarray, iterations: int = 22) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised golden-section maximisation of fn over [lo, hi] (arrays of one shape): (argmax, max)."""
    g = (np.sqrt(5) - 1) / 2
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = fn(x1), fn(x2)
    for _ in range(iterations):
        left = f1 >= f2
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        x2n = np.where(left, x1, lo + g * (hi - lo))
        x1n = np.where(left, hi - g * (hi - lo), x2)
        fn_new = fn(np.where(left, x1n, x2n))
        f1, f2 = np.where(left, fn_new, f2), np.where(left, f1, fn_new)
        x1, x2 = x1n, x2n
    take = f1 >= f2
    return np.where(take, x1, x2), np.where(take, f1, f2)


def _refine(patch: Patch, sweep: Sweep, solid: SampleSolid, h: np.ndarray, ok: np.ndarray, gu: np.ndarray,
            gv: np.ndarray, reach: float) -> tuple[float, np.ndarray]:
    """Refine the grid maximum: the cusp between two passes is a ridge the grid only brushes.

    Every sample that is a local maximum along u (or along v) starts a golden-section search along that
    direction over its two neighbouring cells, which climbs onto the ridge wherever it crosses the row;
    the best of those is polished on shrinking 2D grids. Returns (max, (u, v) where it is).
    """
    grid = np.where(ok & np.isfinite(h), h, -1.0).reshape(len(gu), len(gv))
    if grid.max() < 0:
        return -1.0, np.zeros(2)
    floor = 0.5 * grid.max()

    def value(u, v):
        p, n, _ = _eval(patch, u, v)
        out, _ = sweep.probe(p, n, reach)
        return np.where(solid.reachable(p, n) & np.isfinite(out), out, -1.0)

    best, where = float(grid.max()), np.array([gu[np.argmax(grid.max(axis=1))], gv[np.argmax(grid.max(axis=0))]])
    cands = []
    for axis, coords in ((0, gu), (1, gv)):
        g = np.moveaxis(grid, axis, 0)
        peak = np.zeros_like(g, dtype=bool)
        peak[1:-1] = (g[1:-1] >= g[:-2]) & (g[1:-1] >= g[2:]) & (g[1:-1] >= floor)
        i, j = np.nonzero(peak)
        if not len(i):
            continue
        other = gv if axis == 0 else gu
        fixed = other[j]
        lo, hi = coords[i - 1], coords[i + 1]
        fn = (lambda x, f=fixed: value(x, f)) if axis == 0 else (lambda x, f=fixed: value(f, x))
        x, f = _golden(fn, lo, hi)
        uv = np.stack([x, fixed] if axis == 0 else [fixed, x], -1)
        cands.append((f, uv))
    if cands:
        f = np.concatenate([c[0] for c in cands])
        uv = np.concatenate([c[1] for c in cands])
        top = np.argsort(-f)[:32]
        f, uv = f[top], uv[top]
        (u0, u1), (v0, v1) = patch.domain
        half = np.array([gu[1] - gu[0], gv[1] - gv[0]]) / 8
        for _ in range(3):
            o = np.linspace(-1, 1, 5)
            ou, ov = np.meshgrid(o, o, indexing="ij")
            qu = np.clip(uv[:, :1] + ou.ravel()[None] * half[0], u0, u1)
            qv = np.clip(uv[:, 1:] + ov.ravel()[None] * half[1], v0, v1)
            q = value(qu.ravel(), qv.ravel()).reshape(len(f), -1)
            k = np.argmax(q, axis=1)
            rows = np.arange(len(f))
            better = q[rows, k] > f
            f = np.where(better, q[rows, k], f)
            uv = np.where(better[:, None], np.stack([qu[rows, k], qv[rows, k]], -1), uv)
            half /= 3
        i = int(np.argmax(f))
        if f[i] > best:
            best, where = float(f[i]), uv[i]
    return best, where


def pass_width_mm(tool_radius_mm: float, target_mm: float) -> float:
    """Width of the pass a ball of radius r leaves `target_mm` beside on a plane, 2·√(h(2r − h)) mm: verify's
    unit of sample spacing (its own, so that it samples the same way whatever the planner does).

    Parameters
    ----------
    tool_radius_mm : float
        Ball radius r, mm.
    target_mm : float
        Scallop height h, mm.

    Returns
    -------
    float
        The pass width, mm.
    """
    return float(2.0 * np.sqrt(target_mm * (2.0 * tool_radius_mm - target_mm)))


@dataclass
class _PatchSamples:
    """What one machined patch's samples show: their points, scallop left (NaN where not reached), the
    heat-map value (NaN unreachable, +inf never reached), area weights, reachability, folds, its
    triangles, the refined maximum and its entry of the report."""

    points: np.ndarray
    scallop: np.ndarray
    heat: np.ndarray
    weight: np.ndarray
    reachable: np.ndarray
    folded: np.ndarray
    faces: np.ndarray
    h_max: float
    at: np.ndarray
    gouge_cut: float
    gouge_air: float
    entry: dict


def _grid_faces(nu: int, nv: int) -> np.ndarray:
    """Two triangles per cell of an nu x nv sample grid: int (2 (nu-1)(nv-1), 3)."""
    ii, jj = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    q = (ii * nv + jj).ravel()
    return np.concatenate([np.stack([q, q + nv, q + nv + 1], -1), np.stack([q, q + nv + 1, q + 1], -1)])


def _measure_patch(patch: Patch, cut: Sweep, air: Sweep, solid: SampleSolid, *, spacing: float, max_side: int,
                   reach: float, refine: bool) -> _PatchSamples:
    gu, gv = _grid(patch, spacing, max_side)
    uu, vv = np.meshgrid(gu, gv, indexing="ij")
    p, n, area = _eval(patch, uu.ravel(), vv.ravel())
    weight = area * (gu[-1] - gu[0]) * (gv[-1] - gv[0]) / (len(gu) * len(gv))
    # Where the surface folds over itself its normal flips: neither material left nor overcut can
    # be measured along it. Such samples are counted apart and as not reachable.
    folded = flipped_normals(n.reshape(len(gu), len(gv), 3)).ravel()
    ok = solid.reachable(p, n) & ~folded
    h, g_cut = cut.probe(p, n, reach)
    _, g_air = air.probe(p, n, reach)
    g_cut, g_air = np.where(folded, 0.0, g_cut), np.where(folded, 0.0, g_air)
    finite = ok & np.isfinite(h)
    h_max, at = _refine(patch, cut, solid, h, ok, gu, gv, reach) if refine else (
        float(np.max(np.where(finite, h, -1.0), initial=-1.0)), np.zeros(2))
    entry = {
        "patch": patch.id, "samples": len(p), "max_scallop_mm": h_max if np.any(finite) else None,
        "p99_scallop_mm": float(np.percentile(h[finite], 99)) if np.any(finite) else None,
        "fraction_reachable": float(weight[ok].sum() / weight.sum()),
        "fraction_folded": float(weight[folded].sum() / weight.sum()),
        "fraction_reached": float(weight[finite].sum() / max(weight[ok].sum(), 1e-300)),
        "max_gouge_mm": float(g_cut.max(initial=0)), "max_rapid_gouge_mm": float(g_air.max(initial=0)),
    }
    return _PatchSamples(points=p, scallop=np.where(finite, h, np.nan), heat=np.where(ok, h, np.nan), weight=weight, reachable=ok, folded=folded,
                         faces=_grid_faces(len(gu), len(gv)), h_max=h_max, at=at,
                         gouge_cut=float(g_cut.max(initial=0)), gouge_air=float(g_air.max(initial=0)), entry=entry)


def _report(done: list[_PatchSamples], machined: list[Patch], *, r: float, target_mm: float, spacing: float,
            moves: dict) -> dict:
    """The JSON-ready report over every machined patch's samples."""
    h_all = np.concatenate([d.scallop for d in done]) if done else np.zeros(0)
    w_all = np.concatenate([d.weight for d in done]) if done else np.zeros(0)
    ok_all = np.concatenate([d.reachable for d in done]) if done else np.zeros(0, bool)
    fin = np.isfinite(h_all)
    w_ok = w_all[ok_all].sum()
    best = (-1.0, None, None)
    for d, patch in zip(done, machined):
        if d.h_max > best[0] and np.any(np.isfinite(d.scallop)):
            best = (d.h_max, patch.id, patch.surface.evaluate(d.at[:1], d.at[1:])[0])
    return {
        "tool_radius_mm": r, "target_scallop_mm": target_mm, "sample_spacing_mm": spacing,
        "samples": len(h_all),
        "max_scallop_mm": best[0] if best[1] is not None else None,
        "max_at": {"patch": best[1], "xyz": [float(x) for x in best[2]]} if best[1] is not None else None,
        "p99_scallop_mm": float(np.percentile(h_all[fin], 99)) if np.any(fin) else None,
        "mean_scallop_mm": float(np.average(h_all[fin], weights=w_all[fin])) if np.any(fin) else None,
        "fraction_over_target": float(w_all[fin & (np.nan_to_num(h_all) > target_mm * (1 + 1e-9))].sum()
                                      / max(w_ok, 1e-300)),
        "fraction_unreachable": float(w_all[~ok_all].sum() / max(w_all.sum(), 1e-300)),
        "fraction_folded": float(w_all[np.concatenate([d.folded for d in done])].sum() / max(w_all.sum(), 1e-300))
        if done else 0.0,
        "fraction_never_reached": float(w_all[ok_all & ~fin].sum() / max(w_ok, 1e-300)),
        "uncut_area_mm2": float(w_all[ok_all & ~fin].sum()),
        "max_gouge_mm": max((d.gouge_cut for d in done), default=0.0),
        "max_rapid_gouge_mm": max((d.gouge_air for d in done), default=0.0),
        "moves": moves, "patches": [d.entry for d in done],
    }


def measure_program(program: ParsedProgram, machined: list[Patch], part: list[Patch], *, tool_radius_mm: float,
                    target_mm: float, samples_per_interval: int = 12, refine: bool = True,
                    reach_tol_mm: float = 1e-3, max_side: int = 1500,
                    check_cancel: CheckCancel | None = None) -> Measurement:
    """Measure the program on the `machined` patches; `part` is every patch (for reachability).

    All patches in the machine frame of the program's setup, signs outward. The sample spacing is
    `pass_width_mm` / samples_per_interval. Returns the report and the samples as a heat-map mesh.

    Parameters
    ----------
    program : ParsedProgram
        The parsed program: straight moves of the tool tip, mm, machine frame; rapids apart.
    machined : list of Patch
        The patches the program claims to finish (`claimed_patches`).
    part : list of Patch
        Every patch of the part, for the reachability tests.
    tool_radius_mm : float
        Ball radius, mm.
    target_mm : float
        The target scallop height, mm.
    samples_per_interval : int
        Samples per pass width (≥ 2).
    refine : bool
        Refine each patch's maximum past the grid (golden-section searches across the ridges, then
        finer local grids); False takes the grid maximum.
    reach_tol_mm : float
        Tolerance of the reachability tests (tangent ball and shank), mm.
    max_side : int
        Most grid intervals per parameter direction of a patch.
    check_cancel : callable or None
        Called before each patch; it stops the work by raising.

    Returns
    -------
    Measurement
        The report (scallop maximum, 99th percentile and mean, fractions over target, unreachable,
        folded and never reached, gouges of cutting and rapid moves, per patch entries) and the mesh.

    Raises
    ------
    ValueError
        When `samples_per_interval` is below 2.
    """
    t0 = time.perf_counter()
    r = float(tool_radius_mm)
    if samples_per_interval < 2:
        raise ValueError(f"samples_per_interval must be at least 2, got {samples_per_interval}")
    check_cancel = check_cancel or (lambda: None)
    spacing = pass_width_mm(r, target_mm) / samples_per_interval
    z = np.array([0.0, 0.0, r])
    a, b = program.start + z, program.end + z
    reach = max(4 * target_mm, 0.25 * r)
    cut = Sweep(a[~program.rapid], b[~program.rapid], r, step=r / 2)
    air = Sweep(a[program.rapid], b[program.rapid], r, step=r / 2)
    part_pts = np.concatenate([_eval(p, *[x.ravel() for x in np.meshgrid(*_grid(p, spacing, max_side), indexing="ij")])[0]
                               for p in part])
    solid = SampleSolid(part_pts, cell=spacing, r=r, tol=reach_tol_mm)
    done = []
    for patch in machined:
        check_cancel()
        done.append(_measure_patch(patch, cut, air, solid, spacing=spacing, max_side=max_side, reach=reach,
                                   refine=refine))
    report = _report(done, machined, r=r, target_mm=target_mm, spacing=spacing,
                     moves={"cutting": len(cut.a), "rapid": len(air.a)})
    report["time_s"] = time.perf_counter() - t0
    offsets = np.cumsum([0] + [len(d.points) for d in done])
    return Measurement(report=report,
                       vertices=np.concatenate([d.points for d in done]) if done else np.zeros((0, 3)),
                       faces=(np.concatenate([d.faces + o for d, o in zip(done, offsets)]).astype(np.int64)
                              if done else np.zeros((0, 3), np.int64)),
                       scallop=np.concatenate([d.heat for d in done]) if done else np.zeros(0),
                       patch=np.concatenate([np.full(len(d.points), m.id) for d, m in zip(done, machined)])
                       if done else np.zeros(0, np.int64))
