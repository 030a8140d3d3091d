"""The planner: setups, Algorithm 1 rings, chord-checked cutter positions, gouge checks and linking.

`plan_job` is the whole `plan` stage without its files: part-frame surfaces and setups in, per setup
the passes (tool tips, machine frame), the certified scallop bound of every patch and the linked move
list out. The certificate of a patch is the largest predicted scallop of any gap between its rings
(exact relation, checked on the real next line), of the material the first ring leaves on the edges
of the claimed rectangle, or of any corner pocket, plus the largest chord error of its moves; by
construction it does not exceed the target.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from cam.gcode.moves import MoveList
from cam.gcode.setup import Setup
from cam.plan.access import Assignment, assign_setups
from cam.plan.chord import discretize, lattices
from cam.plan.errors import NotPlannable, TooConcave, Unreachable, concave_message
from cam.plan.gouge import (
    SurfaceIndex,
    build_index,
    clearance,
    lift_to_clear,
    move_clearance,
    shank_clear,
)
from cam.plan.grid import ring_grid
from cam.plan.link import link_passes, order_patches
from cam.plan.region import Region, finishable_region
from cam.plan.rings import ring_path
from cam.spline.geometry import Patch, area_share, frame, machine_patches
from cam.spline.knots import sub_surface
from cam.spline.surface import BSplineSurface

__all__ = ["GOUGE_TOL_MM", "PatchPlan", "Plan", "SetupPlan", "plan_job", "plan_patch"]

GOUGE_TOL_MM = 1e-5
ROUNDING_MM = 0.5e-4 * 3 ** 0.5  # 4 decimals per axis move a ball centre by at most this
CORNER_SHARE = 0.97  # corner pockets are held a little under the side gaps, which then set the maximum
MAX_REPLANS = 6
BESIDE_SHARE = 0.1  # a strip beside a patch's planned rectangle is planned too when it holds this share of it


@dataclass
class PatchPlan:
    """One machined patch. passes: tool tips float64 (n_i, 3) per pass in cutting order (machine frame);
    centres: the matching ball centres; certified_scallop_mm: the bound the planner certifies on `region`;
    replans: how often the rectangle was shrunk because the ball had to be lifted off the patch or left
    out (excluded_points such positions in all) or a hollow tighter than the ball turned up (hollows: what
    was found, as `TooConcave` words it); touched: whether the reach check or lifted and left-out
    positions took part of the patch; lift_mm: the largest lift kept (its effect is in the bound)."""

    patch: int
    region: tuple[float, float, float, float]
    passes: list[np.ndarray]
    centres: list[np.ndarray]
    certified_scallop_mm: float
    side_scallop_mm: float
    corner_scallop_mm: float
    chord_error_mm: float
    lift_mm: float
    spacing_mm: tuple[float, float]
    rings: int
    excursions: int
    path_length_mm: float
    reach_fraction: float
    replans: int
    excluded_points: int
    strategy: str
    time_s: float
    hollows: tuple[str, ...] = ()
    touched: bool = True


@dataclass
class SetupPlan:
    setup: Setup
    patches: list[PatchPlan]
    moves: MoveList
    program: str


@dataclass
class Plan:
    setups: list[SetupPlan]
    unmachined: list[dict]
    tool_radius_mm: float
    scallop_height_mm: float
    scallop_share_mm: float
    chord_tolerance_mm: float
    strategy: str
    stats: dict = field(default_factory=dict)
    partial: list[dict] = field(default_factory=list)

    @property
    def certified_scallop_mm(self) -> float:
        vals = [p.certified_scallop_mm for s in self.setups for p in s.patches]
        return max(vals) if vals else 0.0


def _spacing(patch: Patch, rects: np.ndarray, steps: np.ndarray) -> tuple[float, float]:
    """Smallest and largest pass interval in mm, from the side steps at the side midpoints."""
    if not len(steps):
        return 0.0, 0.0
    a, b, c, d = rects[:-1].T
    mu, mv = 0.5 * (a + b), 0.5 * (c + d)
    uv = [(mu, c), (b, mv), (mu, d), (a, mv)]
    out = []
    for side, (u, v) in enumerate(uv):
        fr = frame(patch, u, v)
        root = np.sqrt(np.maximum(fr.e * fr.g - fr.f ** 2, 0))
        speed = root / np.sqrt(fr.e) if side % 2 == 0 else root / np.sqrt(fr.g)
        out.append(steps[:, side] * speed)
    vals = np.concatenate(out)
    vals = vals[vals > 1e-9]
    return (float(vals.min()), float(vals.max())) if len(vals) else (0.0, 0.0)


def _pieces(keep: np.ndarray) -> list[slice]:
    """The maximal runs of True in a bool (n,) array, as slices."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    return [slice(a, b) for a, b in zip(edges[::2], edges[1::2])]


def _clear_path(index: SurfaceIndex, centres: np.ndarray, uv: np.ndarray, r: float, step: float):
    """Lift gouging positions, split moves that gouge, drop what the tool cannot reach.

    centres: ball centres float (n, 3); uv: their contact parameters (n, 2). Returns the centre runs
    (each float (n_i, 3)), the lift of every lifted position (k,) mm with its parameters (k, 2), and the
    parameters of every dropped position (j, 2): there the ball does not touch the patch as planned.
    """
    cl = clearance(index, centres, r)
    bad = cl < -GOUGE_TOL_MM
    centres = centres.copy()
    lifts, lift_uv, drop_uv = [np.zeros(0)], [np.zeros((0, 2))], []
    if bad.any():
        fixed, lift = lift_to_clear(index, centres[bad], r, tol=GOUGE_TOL_MM / 10)
        centres[bad] = fixed
        centres[np.flatnonzero(bad)[np.isnan(lift)]] = np.nan
        lifts.append(lift[np.isfinite(lift)])
        lift_uv.append(uv[bad][np.isfinite(lift)])
    ok = np.all(np.isfinite(centres), axis=1)
    ok[ok] = shank_clear(index, centres[ok], r)
    drop_uv.append(uv[~ok])
    out = []
    for piece in _pieces(ok):
        run, ruv = centres[piece], uv[piece]
        for _ in range(4):  # moves whose middle gouges get a lifted point where it is worst
            if len(run) < 2:
                break
            worst, at = move_clearance(index, run[:-1], run[1:], r, step_mm=step)
            bad = np.flatnonzero(worst < -GOUGE_TOL_MM)
            if not len(bad):
                break
            fix, lift = lift_to_clear(index, at[bad], r, tol=GOUGE_TOL_MM / 10)
            fix[np.isnan(lift)] = np.nan
            mid = 0.5 * (ruv[bad] + ruv[bad + 1])
            lifts.append(lift[np.isfinite(lift)])
            lift_uv.append(mid[np.isfinite(lift)])
            run = np.insert(run, bad + 1, fix, axis=0)
            ruv = np.insert(ruv, bad + 1, mid, axis=0)
        else:
            worst, _ = move_clearance(index, run[:-1], run[1:], r, step_mm=step)
            run[np.flatnonzero(worst < -GOUGE_TOL_MM) + 1] = np.nan
        good = np.all(np.isfinite(run), axis=1)
        drop_uv.append(ruv[~good])
        out += [run[piece] for piece in _pieces(good)]
    return out, np.concatenate(lifts), np.concatenate(lift_uv), np.concatenate(drop_uv).reshape(-1, 2)


def exclude_points(box: tuple[float, float, float, float], uv: np.ndarray, *,
                   margin: float = 1 / 64) -> tuple[float, float, float, float]:
    """The largest of a few boxes inside `box` free of the points (float (k, 2)): every side moved inward
    past the points nearest to it, or one side moved past all of them (for trouble in the middle), each
    `margin` of the width beyond; may come back empty (u0 >= u1 or v0 >= v1)."""
    u0, u1, v0, v1 = box
    wu, wv = u1 - u0, v1 - v0
    q = uv[(uv[:, 0] >= u0) & (uv[:, 0] <= u1) & (uv[:, 1] >= v0) & (uv[:, 1] <= v1)]
    if not len(q):
        return box
    depth = np.stack([(q[:, 0] - u0) / wu, (u1 - q[:, 0]) / wu, (q[:, 1] - v0) / wv, (v1 - q[:, 1]) / wv])
    nearest = np.argmin(depth, axis=0)

    def moved(side: int, d: float, b: list) -> list:
        b = list(b)
        step = (d + margin) * (wu if side < 2 else wv)
        b[side] = b[side] + step if side % 2 == 0 else b[side] - step
        return b

    each = [u0, u1, v0, v1]
    for side in range(4):
        if np.any(nearest == side):
            each = moved(side, float(depth[side, nearest == side].max()), each)
    candidates = [each] + [moved(side, float(depth[side].max()), [u0, u1, v0, v1]) for side in range(4)]
    return tuple(max(candidates, key=lambda b: max(b[1] - b[0], 0.0) * max(b[3] - b[2], 0.0)))


def plan_patch(patch: Patch, index: SurfaceIndex, *, r: float, h: float, chord_fraction: float = 0.1,
               samples_per_line: int = 32, strategy: str = "adaptive", reach_fraction: float = 1.0,
               check_cancel=None, to_part=None) -> PatchPlan:
    """Plan one patch in its setup's machine frame; raises `TooConcave` when the ball does not fit.

    to_part maps machine-frame points (float (3,)) to the part frame the user's files are in, for the
    points the messages name; default: they are named as they are.
    """
    t0 = time.perf_counter()
    check_cancel = check_cancel or (lambda: None)
    h_s, tol = (1 - chord_fraction) * h - ROUNDING_MM, chord_fraction * h
    region = reachable_domain(patch, index, r=r, samples=samples_per_line)
    whole, excluded, tightened, shrinks, hollows = patch, 0, 0, 0, []
    touched = region != _box(patch)  # the reach check already took some of it
    while True:
        if region[0] >= region[1] or region[2] >= region[3]:
            raise Unreachable("the ball cannot follow this patch without touching a neighbouring surface or "
                              "the shank meeting the part" if excluded else
                              "no rectangle of this patch can be reached: the ball would touch a neighbouring "
                              "surface, its shank the part, or the surface faces away from the tool")
        patch = Patch(whole.id, _restrict(whole.surface, region), whole.sign) if region != _box(whole) else whole
        try:
            grid = ring_grid(patch, tool_radius_mm=r, scallop_mm=h_s, samples_per_line=samples_per_line,
                             strategy=strategy, corner_mm=CORNER_SHARE * h_s)
        except TooConcave as exc:
            # A hollow between the samples `finishable_region` looked at: the rectangle gives it up
            # like a lifted position; a hollow it cannot get rid of is reported as it was found.
            shrinks += 1
            if to_part is not None:
                where = to_part(exc.point)
                exc = TooConcave(concave_message(exc.radius_mm, r, where), radius_mm=exc.radius_mm, point=where,
                                 uv=exc.uv)
            smaller = exclude_points(region, exc.uv) if len(exc.uv) else region
            if shrinks > MAX_REPLANS or smaller[0] >= smaller[1] or smaller[2] >= smaller[3] or smaller == region:
                raise exc
            region = smaller
            hollows.append(str(exc))
            continue
        path = ring_path(patch, grid.rects, r=r, corner_mm=CORNER_SHARE * h_s, excursions=strategy == "adaptive",
                         spiral=strategy == "adaptive", claim=grid.claim, check_cancel=check_cancel)
        spacing = _spacing(patch, grid.rects, grid.side_steps)
        # A ball moved by δ moves the surface it cuts by at most δ; a normal line between passes meets
        # a ball at φ from its radius, sin φ ≤ (farthest point from a contact) / r, which is half the
        # largest interval beside a side and up to 0.586 of it in a corner pocket (0.6 taken). So a
        # ball raised by δ leaves at most δ / cos φ more and one moved sideways at most δ·tan φ.
        sin_phi = min(0.6 * spacing[1] / r, 1.0)
        grow = 1 / np.sqrt(1 - sin_phi ** 2) if sin_phi < 0.95 else np.inf
        # The lattice leaves a fifth of the chord share to sideways deviation, which splitting then removes
        # (splitting a move does not lower the lifts its ends share with their other moves).
        lat_u, lat_v = lattices(patch, r=r, tol=0.8 * tol)
        pts = discretize(patch, path.uv, path.kind, r=r, tol=tol, lat_u=lat_u, lat_v=lat_v,
                         lateral_weight=sin_phi * grow if np.isfinite(grow) else 3.0)
        runs, lifts, lift_uv, drop_uv = _clear_path(index, pts.centre, pts.uv, r, step=max(r / 4, 0.1))
        side = float(max(grid.side_scallop.max(initial=0.0), grid.edge_scallop.max()))
        corner = float(path.corner_scallop.max()) if path.corner_scallop.size else 0.0
        chord = float(pts.chord_error.max()) if pts.chord_error.size else 0.0
        bound = max(side, corner) + chord + ROUNDING_MM
        if bound > h:
            # A corner the excursion cannot bring under the scallop share (a full excursion still
            # leaves more than the side gaps): plan the whole patch a little tighter.
            if tightened == 3:
                raise NotPlannable(f"its corner pockets leave {bound:.4g} mm even on tighter rings; "
                                   f"the target is {h:.4g} mm")
            h_s, tightened = h_s - (bound - h) - 1e-3 * h, tightened + 1
            continue
        # Lifts that fit in what the target leaves over are kept and added to the bound (times 1 / cos φ);
        # larger ones, and dropped positions, are cut out of the rectangle.
        big = lifts * grow > h - bound
        off = np.concatenate([lift_uv[big], drop_uv])
        if not len(off):
            bound += grow * float(lifts.max(initial=0.0))
            break
        # Where the ball was lifted more or left out, it does not touch the patch as planned: the
        # rectangle gives up the strip holding those positions and is planned again, so the claim holds.
        excluded += len(off)
        shrinks += 1
        if shrinks > MAX_REPLANS:
            raise Unreachable(f"the ball touches a neighbouring surface or the shank meets the part inside this "
                              f"patch; after {MAX_REPLANS} smaller rectangles it still does")
        check_cancel()
        region = exclude_points(region, off)
    z = np.array([0.0, 0.0, r])
    passes = [run - z for run in runs]
    length = float(sum(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in passes))
    return PatchPlan(patch=patch.id, passes=passes, centres=runs, certified_scallop_mm=bound, region=region,
                     side_scallop_mm=side, corner_scallop_mm=corner, chord_error_mm=chord,
                     lift_mm=float(lifts.max(initial=0.0)), spacing_mm=spacing, rings=len(grid.rects),
                     excursions=path.excursions, path_length_mm=length, reach_fraction=reach_fraction,
                     replans=shrinks, excluded_points=excluded, strategy=strategy,
                     time_s=time.perf_counter() - t0, hollows=tuple(dict.fromkeys(hollows)),
                     touched=touched or excluded > 0)


def _claim(surface, plan: PatchPlan, trimmed: Region | None) -> dict | None:
    """What a patch planned on a sub-rectangle claims: the rectangle, its share of the patch's area and
    why the rest is left (None when the whole patch is planned). Verify holds the program to this claim."""
    planned = plan.region
    (u0, u1), (v0, v1) = surface.domain
    full = (u0, u1, v0, v1)
    scale = max(u1 - u0, v1 - v0)
    if np.allclose(planned, full, rtol=0, atol=1e-12 * scale):
        return None
    reasons = [trimmed.reason] if trimmed is not None else []
    inside = trimmed.box if trimmed is not None else full
    if not np.allclose(planned, inside, rtol=0, atol=1e-12 * scale):
        reasons += list(plan.hollows)
        if plan.touched or not plan.hollows:
            reasons.append("beyond it the ball would touch a neighbouring surface or its shank the part")
    return {"region": [float(x) for x in planned], "kept": area_share(surface, planned), "reason": "; ".join(reasons)}


def _plan_beside(patch: Patch, region, whole_surface, index: SurfaceIndex, *, trimmed: Region | None,
                 min_share: float = BESIDE_SHARE, **options) -> tuple[list[PatchPlan], list[dict]]:
    """Plans and claims of the four strips of `patch` beside its planned rectangle `region` (left and right
    of it over the whole height, below and above it over its width) that hold at least `min_share` of the
    patch's area, each planned like a patch of its own and kept when its claim holds that share too.

    A band the ball cannot reach across the middle of a patch (a face turned away from the tool, a rib
    standing on it) leaves usable pieces on both sides, and one rectangle takes only the larger. A strip
    the planner cannot finish is left without a word of its own: the first claim's reason covers it.
    """
    (u0, u1), (v0, v1) = patch.domain
    a, b, c, d = region
    plans, claims = [], []
    for strip in ((u0, a, v0, v1), (b, u1, v0, v1), (a, b, v0, c), (a, b, d, v1)):
        if strip[0] >= strip[1] or strip[2] >= strip[3] or area_share(whole_surface, strip) < min_share:
            continue
        try:
            pp = plan_patch(Patch(patch.id, _restrict(patch.surface, strip), patch.sign), index, **options)
        except (TooConcave, Unreachable, NotPlannable):
            continue
        claim = _claim(whole_surface, pp, trimmed)
        if pp.passes and claim is not None and claim["kept"] >= min_share:
            plans.append(pp)
            claims.append({"patch": patch.id, **claim})
    return plans, claims


def _box(patch: Patch) -> tuple[float, float, float, float]:
    (u0, u1), (v0, v1) = patch.domain
    return (u0, u1, v0, v1)


def _restrict(surface, region):
    """The same surface on a parameter sub-rectangle (knot insertion free: a reparameterising wrapper)."""
    from cam.spline.geometry import SubSurface

    return SubSurface(surface, region)


def _largest_rectangle(ok: np.ndarray) -> tuple[int, int, int, int] | None:
    """Largest all-True block of a bool (n, m) grid: inclusive (i0, i1, j0, j1), or None when none is True."""
    n, m = ok.shape
    heights = np.zeros(m, dtype=np.int64)
    best, out = 0, None
    for i in range(n):
        heights = np.where(ok[i], heights + 1, 0)
        stack: list[int] = []  # column indices with increasing heights
        for j in range(m + 1):
            hj = heights[j] if j < m else 0
            while stack and heights[stack[-1]] >= hj:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = int(heights[top]) * (j - left)
                if area > best:
                    best, out = area, (i - int(heights[top]) + 1, i, left, j - 1)
            stack.append(j)
    return out


def reachable_domain(patch: Patch, index: SurfaceIndex, *, r: float, samples: int = 32,
                     steps: int = 24, rounds: int = 8) -> tuple[float, float, float, float]:
    """A parameter rectangle whose four boundary lines the tangent ball reaches everywhere.

    At a hollow sharp edge the ball touching one patch cuts the next one, and part of a patch may face
    away from the tool. The rectangle starts as the largest block of a samples × samples grid of
    contact points the ball reaches, each side then pushed outwards to where its iso-line stops being
    reachable (bisection). Where a side's line is blocked between grid points it moves inward instead,
    one side per round, the one that gives up the least area. What lies outside is reported by verify
    as unreachable; the rings then run along the reachable boundary, and trouble left inside is found
    when the passes are planned (see `plan_patch`).
    """
    (u0, u1), (v0, v1) = patch.domain

    def reached(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Whether the tangent ball at each contact (u, v) faces up, clears every surface and its shank."""
        fr = frame(patch, u, v)
        c = fr.p + r * fr.n
        ok = np.all(np.isfinite(c), axis=1) & (fr.n[:, 2] > 1e-6)
        ok[ok] = clearance(index, c[ok], r) >= -GOUGE_TOL_MM
        ok[ok] = shank_clear(index, c[ok], r)
        return ok

    gu, gv = np.linspace(u0, u1, samples), np.linspace(v0, v1, samples)
    uu, vv = np.meshgrid(gu, gv, indexing="ij")
    block = _largest_rectangle(reached(uu.ravel(), vv.ravel()).reshape(samples, samples))
    if block is None:
        return (u0, u0, v0, v0)
    i0, i1, j0, j1 = block
    box = [gu[i0], gu[i1], gv[j0], gv[j1]]

    def line_ok(along: str, fixed: float, lo: float, hi: float) -> bool:
        q = np.linspace(lo, hi, samples)
        return bool(np.all(reached(q, np.full_like(q, fixed)) if along == "u" else reached(np.full_like(q, fixed), q)))

    def line(side: int) -> tuple[str, float, float]:
        along = "u" if side >= 2 else "v"  # sides 0, 1 are u = const lines (running along v)
        lo, hi = (box[2], box[3]) if along == "v" else (box[0], box[1])
        return along, lo, hi

    # Outwards: each side of the block up to the grid line beyond it, where its line stops being reachable.
    limits = [u0, u1, v0, v1]
    beyond = [gu[max(i0 - 1, 0)], gu[min(i1 + 1, samples - 1)], gv[max(j0 - 1, 0)], gv[min(j1 + 1, samples - 1)]]
    for side in range(4):
        along, lo, hi = line(side)
        inner = box[side]
        if inner == limits[side] or not line_ok(along, inner, lo, hi):
            continue
        outer = beyond[side]
        if line_ok(along, outer, lo, hi):
            box[side] = outer
            continue
        for _ in range(12):
            mid = 0.5 * (inner + outer)
            inner, outer = (mid, outer) if line_ok(along, mid, lo, hi) else (inner, mid)
        box[side] = inner

    def inset(side: int) -> float | None:
        """Smallest reachable inset of `side` as a fraction of the way to the opposite side; 0 when it holds."""
        along, lo, hi = line(side)
        start, other = box[side], box[side ^ 1]
        if line_ok(along, start, lo, hi):
            return 0.0
        ts = np.linspace(0, 1, steps + 1)[1:] * 0.5
        good = next((t for t in ts if line_ok(along, start + t * (other - start), lo, hi)), None)
        if good is None:
            return None
        a, b = good - 0.5 / steps, good
        for _ in range(12):
            mid = 0.5 * (a + b)
            a, b = (a, mid) if line_ok(along, start + mid * (other - start), lo, hi) else (mid, b)
        return b

    # Inwards: a line blocked between grid points.
    for _ in range(rounds):
        if box[0] >= box[1] or box[2] >= box[3]:
            break
        moves = {side: inset(side) for side in range(4)}
        if all(t == 0.0 for t in moves.values()):
            return tuple(box)
        width = {0: box[3] - box[2], 1: box[3] - box[2], 2: box[1] - box[0], 3: box[1] - box[0]}
        loss = {side: t * abs(box[side ^ 1] - box[side]) * width[side] for side, t in moves.items() if t}
        if not loss:
            break
        side = min(loss, key=loss.get)
        box[side] = box[side] + moves[side] * (box[side ^ 1] - box[side])
    return box_empty(box)


def box_empty(box):
    return (box[0], box[0], box[2], box[2])


def program_name(position: int) -> str:
    """`program.nc` for the first setup, `program-setup2.nc`, ... after it (DESIGN)."""
    return "program.nc" if position == 0 else f"program-setup{position + 1}.nc"


def plan_job(ids: list[int], surfaces: list[BSplineSurface], setups: list[Setup], *, tool_radius_mm: float,
             scallop_height_mm: float, chord_fraction: float = 0.1, samples_per_line: int = 32,
             strategy: str = "adaptive", clearance_mm: float = 5.0, retract_mm: float = 1.0,
             min_reach: float = 0.5, signs: np.ndarray | None = None, progress=None, check_cancel=None) -> Plan:
    """Plan every patch (part-frame surfaces with ids) over the setups; see the module docstring.

    signs: +1/−1 per surface making S_u × S_v outward (see `geometry.orientation_signs`); default +1.
    progress(fraction, message) and check_cancel() are called between patches.
    """
    r, h = float(tool_radius_mm), float(scallop_height_mm)
    if not 0 < h < r:
        raise ValueError(f"scallop height must lie in (0, r = {r}) mm, got {h}")
    if not 0 < chord_fraction < 1:
        raise ValueError(f"chord_fraction must lie in (0, 1), got {chord_fraction}")
    if len(ids) != len(surfaces):
        raise ValueError(f"{len(ids)} patch ids for {len(surfaces)} surfaces")
    signs = np.ones(len(surfaces)) if signs is None else np.asarray(signs, dtype=np.float64)
    progress = progress or (lambda f, m=None: None)
    check_cancel = check_cancel or (lambda: None)
    progress(0.02, "setups and accessibility")
    unmachined, partial = [], []
    trimmed: dict[int, Region] = {}
    whole = list(surfaces)  # what the tool must not cut: every surface, whole
    surfaces = list(surfaces)  # what it finishes
    for k, (i, s, g) in enumerate(zip(ids, surfaces, signs)):
        # Folds and hollows tighter than the ball are left out (the sides move in past them) or, when
        # they are inside, the patch is reported: never cut, never given a bound it cannot keep.
        region = finishable_region(Patch(int(i), s, float(g)), r)
        if region.box is None or region.kept < min_reach:
            unmachined.append({"patch": int(i), "reason": region.reason if region.box is None else
                               f"only {region.kept:.0%} of it can be finished: {region.reason}"})
            continue
        if region.reason:
            surfaces[k] = sub_surface(s, region.box)
            trimmed[int(i)] = region
    assignment: Assignment = assign_setups(ids, surfaces, signs, setups, r=r, min_reach=min_reach, obstacles=whole,
                                           skip={u["patch"] for u in unmachined})
    unmachined += assignment.unmachined
    total = max(sum(len(v) for v in assignment.patches.values()), 1)
    done = 0
    out_setups = []
    for position, setup in enumerate(assignment.setups):
        mine = assignment.patches.get(setup.id, [])
        patches = machine_patches(ids, surfaces, signs, setup)
        solid = machine_patches(ids, whole, signs, setup)  # trimmed-off strips are still part of the part
        index = build_index(solid, spacing_mm=max(r / 6, 0.2))
        to_part = setup.to_part  # messages name points in the part's frame, as finishable_region's do
        plans = []
        for p in patches:
            if p.id not in mine:
                continue
            check_cancel()
            progress(0.05 + 0.9 * done / total, f"setup {setup.id}: patch {p.id}")
            share = assignment.reach.get(p.id, 1.0) * (trimmed[p.id].kept if p.id in trimmed else 1.0)
            try:
                plans.append(plan_patch(p, index, r=r, h=h, chord_fraction=chord_fraction,
                                        samples_per_line=samples_per_line, strategy=strategy, reach_fraction=share,
                                        check_cancel=check_cancel, to_part=to_part))
            except (TooConcave, Unreachable, NotPlannable) as exc:
                unmachined.append({"patch": p.id, "reason": str(exc)})
            else:
                claim = _claim(whole[ids.index(p.id)], plans[-1], trimmed.get(p.id))
                if claim is not None:
                    partial.append({"patch": p.id, **claim})
                    more, claims = _plan_beside(p, plans[-1].region, whole[ids.index(p.id)], index,
                                                trimmed=trimmed.get(p.id), r=r, h=h, chord_fraction=chord_fraction,
                                                samples_per_line=samples_per_line, strategy=strategy,
                                                reach_fraction=share, check_cancel=check_cancel,
                                                to_part=to_part)
                    plans += more
                    partial += claims
            done += 1
        plans = [pp for pp in plans if pp.passes]
        top = max(float(np.max(q.surface.control_points[..., 2])) for q in solid)
        clearance_z = top + clearance_mm
        entries = np.array([pp.passes[0][0] for pp in plans]).reshape(-1, 3)
        exits = np.array([pp.passes[-1][-1] for pp in plans]).reshape(-1, 3)
        plans = [plans[i] for i in order_patches(entries, exits)]

        def stay_down(a, b, index=index):
            if np.linalg.norm(b - a) > 2 * r:
                return False
            z = np.array([0.0, 0.0, r])
            worst, _ = move_clearance(index, (a + z)[None], (b + z)[None], r, step_mm=max(r / 8, 0.05))
            return bool(worst[0] >= -GOUGE_TOL_MM)

        moves = link_passes([(pp.patch, pp.passes) for pp in plans], clearance_z=clearance_z,
                            retract_mm=retract_mm, stay_down=stay_down)
        out_setups.append(SetupPlan(setup=setup, patches=plans, moves=moves, program=program_name(position)))
    progress(0.97, "linking done")
    return Plan(setups=out_setups, unmachined=unmachined, tool_radius_mm=r, scallop_height_mm=h,
                scallop_share_mm=(1 - chord_fraction) * h - ROUNDING_MM, chord_tolerance_mm=chord_fraction * h,
                strategy=strategy, partial=partial)
