"""Patch passes: the paper's contour-parallel rings on every fitted patch of every setup (`plan_patches`).

Part-frame surfaces and setups in; per setup the passes (tool tips, machine frame), the certified scallop
bound of every patch (`cam.plan.patch`) and the linked move list out; what it does not finish is listed
with the reason (`unmachined`, and `partial` for patches finished on parameter rectangles only). The
whole job (`cam.plan.job.plan_job`) runs this first on the patches that fit the mesh, then finishes the
rest of the part on the mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam import CheckCancel, GeometryError, Progress, map_forked
from cam.gcode.moves import MoveList
from cam.gcode.setup import Setup
from cam.params import ToolParams, ToolpathParams
from cam.plan.access import Assignment, assign_setups
from cam.plan.errors import NotPlannable, TooConcave, Unreachable
from cam.plan.gouge import GOUGE_TOL_MM, SurfaceIndex, build_index, move_clearance
from cam.plan.link import link_passes, order_patches
from cam.plan.patch import ROUNDING_MM, PatchPlan, plan_patch, restrict_patch
from cam.plan.region import Region, finishable_region
from cam.spline.geometry import Patch, area_share, machine_patches
from cam.spline.knots import sub_surface
from cam.spline.surface import BSplineSurface

__all__ = ["PatchesPlan", "SetupPatches", "plan_patches", "program_name"]

BESIDE_SHARE = 0.1  # a strip beside a patch's planned rectangle is planned too when it holds this share of it


@dataclass
class SetupPatches:
    """The plan of one setup: its patches' passes and the linked move list of its program.

    Attributes
    ----------
    setup : Setup
        The setup (how the part sits on the machine).
    patches : list of PatchPlan
        The planned patches (and strips beside them), in cutting order.
    moves : MoveList
        The linked moves of the program: tool tips, mm, machine frame.
    program : str
        The program's file name (`program_name`).
    """

    setup: Setup
    patches: list[PatchPlan]
    moves: MoveList
    program: str


@dataclass
class PatchesPlan:
    """What `plan_patches` returns: the plan of every setup, and what is not finished, with the reason.

    Attributes
    ----------
    setups : list of SetupPatches
        One per setup in use, in program order.
    unmachined : list of dict
        ``{"patch": id, "reason": str}`` for every patch not finished at all.
    tool_radius_mm : float
        Ball radius, mm.
    scallop_height_mm : float
        The target scallop height h, mm.
    scallop_share_mm : float
        The share the rings are planned with, (1 − chord_fraction)·h − `ROUNDING_MM`, mm.
    chord_tolerance_mm : float
        The share of the straight moves, chord_fraction·h, mm.
    strategy : str
        'adaptive' or 'paper'.
    stats : dict
        Further numbers; `plan_patches` leaves it empty.
    partial : list of dict
        ``{"patch": id, "region": [u0, u1, v0, v1], "kept": share of the area, "reason": str}`` for
        every patch finished on parameter rectangles only (one entry per rectangle).
    """

    setups: list[SetupPatches]
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
        """The largest certified scallop bound of any planned patch, mm; 0.0 when none is planned."""
        vals = [p.certified_scallop_mm for s in self.setups for p in s.patches]
        return max(vals) if vals else 0.0


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


def _plan_beside(patch: Patch, region, whole_surface, index: SurfaceIndex, tool: ToolParams,
                 toolpath: ToolpathParams, *, trimmed: Region | None, min_share: float = BESIDE_SHARE,
                 **options) -> tuple[list[PatchPlan], list[dict]]:
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
            pp = plan_patch(restrict_patch(patch, strip), index, tool, toolpath, **options)
        except (TooConcave, Unreachable, NotPlannable):
            continue
        claim = _claim(whole_surface, pp, trimmed)
        if pp.passes and claim is not None and claim["kept"] >= min_share:
            plans.append(pp)
            claims.append({"patch": patch.id, **claim})
    return plans, claims


def program_name(position: int, *, rest: bool = False) -> str:
    """`program.nc` for the first setup, `program-setup2.nc`, ... after it (DESIGN); `-rest` before `.nc`
    for the rest ball's program of that setup (`program-rest.nc`, `program-setup2-rest.nc`, ...).

    Parameters
    ----------
    position : int
        The setup's place in the plan, 0 for the first.
    rest : bool
        The rest ball's program.

    Returns
    -------
    str
        The program's file name.
    """
    base = "program" if position == 0 else f"program-setup{position + 1}"
    return base + ("-rest" if rest else "") + ".nc"


@dataclass
class _Finishable:
    """The surfaces to finish (part frame; a patch with a fold or a tight hollow cut to the rectangle
    without it), the patches so trimmed, and those left out with the reason."""

    surfaces: list[BSplineSurface]
    trimmed: dict[int, Region]
    unmachined: list[dict]


def _finishable(ids: list[int], surfaces: list[BSplineSurface], signs: np.ndarray, *, r: float,
                min_reach: float) -> _Finishable:
    out = _Finishable(list(surfaces), {}, [])
    for k, (i, s, g) in enumerate(zip(ids, surfaces, signs)):
        # Folds and hollows tighter than the ball are left out (the sides move in past them) or, when
        # they are inside, the patch is reported: never cut, never given a bound it cannot keep.
        region = finishable_region(Patch(int(i), s, float(g)), r)
        if region.box is None or region.kept < min_reach:
            out.unmachined.append({"patch": int(i), "reason": region.reason if region.box is None else
                                   f"only {region.kept:.0%} of it can be finished: {region.reason}"})
            continue
        if region.reason:
            out.surfaces[k] = sub_surface(s, region.box)
            out.trimmed[int(i)] = region
    return out


def _plan_one_patch(p: Patch, setup: Setup, whole: dict[int, BSplineSurface], index: SurfaceIndex, tool: ToolParams,
                    toolpath: ToolpathParams, *, finish: _Finishable, assignment: Assignment,
                    check_cancel: CheckCancel, progress: Progress
                    ) -> tuple[list[PatchPlan], list[dict], list[dict]]:
    """One patch's plans (its rectangle, then the strips beside it that it leaves), what of it cannot be
    planned (`unmachined` entries) and each rectangle that is not the whole patch (`partial` entries)."""
    progress(0.0, f"patch {p.id}: its rings")
    trimmed = finish.trimmed.get(p.id)
    share = assignment.reach.get(p.id, 1.0) * (trimmed.kept if trimmed is not None else 1.0)
    options = {"reach_fraction": share, "check_cancel": check_cancel, "to_part": setup.to_part}
    try:
        plans = [plan_patch(p, index, tool, toolpath, **options)]
    except (TooConcave, Unreachable, NotPlannable) as exc:
        return [], [{"patch": p.id, "reason": str(exc)}], []
    partial = []
    claim = _claim(whole[p.id], plans[0], trimmed)
    if claim is not None:
        partial.append({"patch": p.id, **claim})
        progress(0.6, f"patch {p.id}: the strips beside its rectangle")
        more, claims = _plan_beside(p, plans[0].region, whole[p.id], index, tool, toolpath, trimmed=trimmed,
                                    **options)
        plans += more
        partial += claims
    return plans, [], partial


def _plan_setup_patches(setup: Setup, mine: list[int], patches: list[Patch], whole: dict[int, BSplineSurface],
                        index: SurfaceIndex, tool: ToolParams, toolpath: ToolpathParams, *,
                        finish: _Finishable, assignment: Assignment, unmachined: list[dict], partial: list[dict],
                        processes: int, progress: Progress, check_cancel: CheckCancel) -> list[PatchPlan]:
    """The plans of one setup's patches (`mine`), `processes` patches at once (`cam.map_forked`: the same
    plans as one after another); what cannot be planned goes to `unmachined`, each rectangle that is not a
    whole patch to `partial`, in patch order."""
    todo = [p for p in patches if p.id in mine]
    results = map_forked(lambda k, cc, pr: _plan_one_patch(todo[k], setup, whole, index, tool, toolpath,
                                                           finish=finish, assignment=assignment, check_cancel=cc,
                                                           progress=pr),
                         len(todo), processes=processes, check_cancel=check_cancel, progress=progress,
                         item_progress=True)
    plans = []
    for got, lost, part in results:
        plans += got
        unmachined += lost
        partial += part
    return [pp for pp in plans if pp.passes]


def _patches_progress(progress: Progress, setup_id: int, before: int, n: int, total: int) -> Progress:
    """progress(share of this setup's n patches done, `cam.map_forked`'s message) as a share of all `total`
    patches, `before` of them done."""

    def report(fraction: float, message: str | None = None) -> None:
        progress(0.05 + 0.9 * (before + fraction * n) / total, f"setup {setup_id}: patches {message}" if message
                 else f"setup {setup_id}: patches")

    return report


def _link_setup(plans: list[PatchPlan], solid: list[Patch], index: SurfaceIndex, *, r: float,
                toolpath: ToolpathParams) -> tuple[list[PatchPlan], MoveList]:
    """The patches in cutting order (nearest entry next) and the move list that links their passes."""
    top = max(float(np.max(q.surface.control_points[..., 2])) for q in solid)
    entries = np.array([pp.passes[0][0] for pp in plans]).reshape(-1, 3)
    exits = np.array([pp.passes[-1][-1] for pp in plans]).reshape(-1, 3)
    plans = [plans[i] for i in order_patches(entries, exits)]

    def stay_down(a, b):
        if np.linalg.norm(b - a) > 2 * r:
            return False
        z = np.array([0.0, 0.0, r])
        worst, _ = move_clearance(index, (a + z)[None], (b + z)[None], r, step_mm=max(r / 8, 0.05))
        return bool(worst[0] >= -GOUGE_TOL_MM)

    moves = link_passes([(pp.patch, pp.passes) for pp in plans], clearance_z=top + toolpath.clearance_mm,
                        retract_mm=toolpath.retract_mm, stay_down=stay_down)
    return plans, moves


def plan_patches(ids: list[int], surfaces: list[BSplineSurface], setups: list[Setup], tool: ToolParams,
                 toolpath: ToolpathParams, *, signs: np.ndarray | None = None, add_setups: bool = True,
                 processes: int = 1, progress: Progress | None = None, check_cancel: CheckCancel | None = None
                 ) -> PatchesPlan:
    """PatchesPlan every patch (part-frame surfaces with ids) over the setups; see the module docstring.

    Parameters
    ----------
    ids, surfaces : list of int, list of BSplineSurface
        Patch ids and their B-spline surfaces (part frame, mm), one each.
    setups : list of Setup
        The setups `segment` chose; the planner may add the opposite one.
    tool, toolpath : ToolParams, ToolpathParams
        The job's `tool` and `toolpath` parameter groups (ball radius, scallop height, chord share, ...).
    signs : (len(surfaces),) float or None
        +1/−1 per surface making S_u × S_v outward
        (see `cam.spline.geometry.orientation_signs`); default +1.
    processes : int
        Patches planned at once, in forked processes (the plans are those of one process).
    progress, check_cancel : callable or None
        cam's callbacks (see `cam`): progress between patches and within each as it is planned, check_cancel
        while each is planned.

    Returns
    -------
    PatchesPlan
        Per setup the patches' passes (tool tips, mm, machine frame) and the linked move list, the
        bounds, and the patches left unmachined or finished in part (`PatchesPlan.partial`).

    Raises
    ------
    GeometryError
        When the scallop height does not lie in (0, tool radius).
    ValueError
        When `ids` and `surfaces` differ in length, or `setups` is empty.
    """
    r, h, chord_fraction = float(tool.radius_mm), float(toolpath.scallop_height_mm), float(toolpath.chord_fraction)
    if not 0 < h < r:
        raise GeometryError(f"the scallop height toolpath.scallop_height_mm must lie in (0, tool.radius_mm = {r}) "
                            f"mm, got {h}")
    if len(ids) != len(surfaces):
        raise ValueError(f"{len(ids)} patch ids for {len(surfaces)} surfaces")
    signs = np.ones(len(surfaces)) if signs is None else np.asarray(signs, dtype=np.float64)
    progress = progress or (lambda f, m=None: None)
    check_cancel = check_cancel or (lambda: None)
    progress(0.02, "setups and accessibility")
    finish = _finishable(ids, surfaces, signs, r=r, min_reach=toolpath.min_reach_fraction)
    assignment = assign_setups(ids, finish.surfaces, signs, setups, r=r, min_reach=toolpath.min_reach_fraction,
                               obstacles=list(surfaces), skip={u["patch"] for u in finish.unmachined},
                               add_opposite=add_setups)
    unmachined, partial = finish.unmachined + assignment.unmachined, []
    whole = {int(i): s for i, s in zip(ids, surfaces)}  # what the tool must not cut: every surface, whole
    total, done = max(sum(len(v) for v in assignment.patches.values()), 1), 0

    out_setups = []
    for position, setup in enumerate(assignment.setups):
        solid = machine_patches(ids, surfaces, signs, setup)  # trimmed-off strips are still part of the part
        index = build_index(solid, spacing_mm=max(r / 6, 0.2))
        mine = assignment.patches.get(setup.id, [])
        check_cancel()
        plans = _plan_setup_patches(setup, mine, machine_patches(ids, finish.surfaces, signs, setup), whole, index,
                                    tool, toolpath, finish=finish, assignment=assignment, unmachined=unmachined,
                                    partial=partial, processes=processes,
                                    progress=_patches_progress(progress, setup.id, done, len(mine), total),
                                    check_cancel=check_cancel)
        done += len(mine)
        plans, moves = _link_setup(plans, solid, index, r=r, toolpath=toolpath)
        out_setups.append(SetupPatches(setup=setup, patches=plans, moves=moves, program=program_name(position)))
    progress(0.97, "linking done")
    return PatchesPlan(setups=out_setups, unmachined=unmachined, tool_radius_mm=r, scallop_height_mm=h,
                scallop_share_mm=(1 - chord_fraction) * h - ROUNDING_MM, chord_tolerance_mm=chord_fraction * h,
                strategy=toolpath.strategy, partial=partial)
