"""The `plan` stage without its files: programs that finish the part, setup by setup (`plan_job`).

1. Samples of the part (`mesh.ply`) and the setups that reach most of them (`setups.choose_setups`,
   segment's setup considered first).
2. The paper's contour-parallel passes on the fitted patches that hold their fit tolerance
   (`patch_job.plan_patches`), every ball centre lifted onto the mesh's drop-cutter height so that no
   pass cuts the part where a surface lies below it.
3. Per setup, whole-part finishing on the mesh (`finish.finish_setup`: raster, waterlines, clean-up) of
   every sample that setup reaches and no earlier pass left within the target.
4. With a rest ball (`tool.rest_radius_mm`), the same for what the main ball leaves over the target,
   in a program of its own per setup.
5. Linking (`link_part.link_setup`): passes in greedy order, feeding across or riding over the part where
   that is short and clear, otherwise off the part to where a rapid keeps the rapid margin, across, and
   down again.

The planner measures what its passes leave on every sample (the ball's swept volume met by the
sample's normal line); the bound a program header states is the largest of those on the samples it
finishes. `verify` measures the G-code again, independently, on its own samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam import (
    CheckCancel,
    GeometryError,
    Progress,
    progress_between,
    progress_labelled,
)
from cam.gcode.moves import MoveList
from cam.gcode.setup import Setup
from cam.mesh.samples import SurfaceSamples, sample_surface
from cam.params import ToolParams, ToolpathParams
from cam.plan.coverage import left_on_samples
from cam.plan.finish import finish_setup
from cam.plan.lines import follow_part
from cam.plan.link import order_passes
from cam.plan.link_part import link_setup
from cam.plan.part import SetupPart, setup_part
from cam.plan.patch import ROUNDING_MM
from cam.plan.patch_job import PatchesPlan, plan_patches, program_name
from cam.plan.scallop import flat_spacing
from cam.plan.setups import choose_setups, setup_reach
from cam.spline.surface import BSplineSurface

__all__ = ["JobPlan", "ProgramPlan", "SurfacesIn", "plan_job"]


@dataclass(frozen=True)
class SurfacesIn:
    """The fitted patches the patch passes may use: ids, surfaces (part frame), outward signs, and which
    hold the fit tolerance (only those get patch passes)."""

    ids: list[int]
    surfaces: list[BSplineSurface]
    signs: np.ndarray
    good: np.ndarray


@dataclass
class ProgramPlan:
    """One program: one setup, one ball.

    Attributes
    ----------
    setup : Setup
    name : str
        Its file name (`program_name`).
    role : str
        "main" or "rest".
    tool_radius_mm : float
    passes : list of (n_i, 3) float64
        Tool tips, mm, machine frame, in cutting order.
    strategy : list of str
        Per pass: "patch <id>", "raster", "waterline" or "cleanup".
    moves : MoveList
    bound_mm : float
        The largest material the planner measured its passes leave on the samples it counts finished.
    stats : dict
    """

    setup: Setup
    name: str
    role: str
    tool_radius_mm: float
    passes: list[np.ndarray]
    strategy: list[str]
    moves: MoveList
    bound_mm: float
    stats: dict = field(default_factory=dict)


@dataclass
class JobPlan:
    """Every program of the job and what the planner measured they finish.

    Attributes
    ----------
    programs : list of ProgramPlan
    setups : list of Setup
    patches : PatchesPlan or None
        The patch passes' own plan (their certificates, what they left out).
    coverage : dict
        The planner's measurement on its samples: shares of the part, by tool and reason.
    tool_radius_mm, rest_radius_mm, scallop_height_mm, scallop_share_mm, chord_tolerance_mm : float
    """

    programs: list[ProgramPlan]
    setups: list[Setup]
    patches: PatchesPlan | None
    coverage: dict
    tool_radius_mm: float
    rest_radius_mm: float | None
    scallop_height_mm: float
    scallop_share_mm: float
    chord_tolerance_mm: float


@dataclass
class _Passes:
    """Ball-centre passes of one setup and ball, with their strategy names."""

    centres: list[np.ndarray] = field(default_factory=list)
    strategy: list[str] = field(default_factory=list)


def _machine(samples: SurfaceSamples, setup: Setup) -> tuple[np.ndarray, np.ndarray]:
    return setup.to_machine(samples.points), setup.to_machine(samples.normals, direction=True)


def _patch_passes(surfaces: SurfacesIn | None, setups: list[Setup], parts: list[SetupPart], tool: ToolParams,
                  toolpath: ToolpathParams, *, chord_mm: float, processes: int, check_cancel, progress=None
                  ) -> tuple[PatchesPlan | None, list]:
    """The patch passes per setup, lifted onto the mesh's drop-cutter height and refined against it."""
    out = [_Passes() for _ in setups]
    if surfaces is None or not toolpath.patch_passes or not surfaces.good.any():
        return None, out
    keep = np.flatnonzero(surfaces.good)
    plan = plan_patches([surfaces.ids[k] for k in keep], [surfaces.surfaces[k] for k in keep], setups, tool,
                        toolpath, signs=surfaces.signs[keep], add_setups=False, processes=processes,
                        check_cancel=check_cancel, progress=progress)
    by_id = {s.id: k for k, s in enumerate(setups)}
    for sp in plan.setups:
        k = by_id[sp.setup.id]
        for pp in sp.patches:
            for centres in pp.centres:
                lifted = centres.copy()
                lifted[:, 2] = np.maximum(lifted[:, 2], parts[k].drop(lifted[:, :2]))
                lifted, _ = follow_part(parts[k], lifted, chord_mm=chord_mm)
                out[k].centres.append(lifted)
                out[k].strategy.append(f"patch {pp.patch}")
    return plan, out


def _finish_rest_of_part(parts: list[SetupPart], samples: SurfaceSamples, reach: list[np.ndarray],
                         passes: list[_Passes], left: np.ndarray, *, h: float, scallop_mm: float, chord_mm: float,
                         processes: int, progress, check_cancel) -> list[dict]:
    """Whole-part finishing, setup by setup, of what each reaches and no earlier pass finished; updates
    `passes` and `left` in place and returns each setup's stats."""
    stats = []
    for k, part in enumerate(parts):
        progress(k / max(len(parts), 1), f"setup {k + 1}: finishing on the mesh")
        points, normals = _machine(samples, part.setup)
        if passes[k].centres:
            left[:] = np.minimum(left, left_on_samples(passes[k].centres, points, normals,
                                                       tool_radius_mm=part.radius_mm, reach_mm=h))
        target = reach[k] & ~(left <= h)
        done = finish_setup(part, points[target], normals[target], scallop_mm=scallop_mm, chord_mm=chord_mm,
                            target_mm=h, processes=processes, check_cancel=check_cancel,
                            progress=progress_labelled(progress, k / len(parts), (k + 1) / len(parts),
                                                       f"setup {k + 1}: finishing on the mesh"))
        passes[k].centres += done.passes
        passes[k].strategy += done.strategy
        left[target] = np.minimum(left[target], done.left)
        stats.append({"targets": int(target.sum()), **done.stats,
                      "strategy_bound_mm": {s: round(v, 6) for s, v in done.certified_mm.items()}})
    return stats


def _program(part: SetupPart, passes: _Passes, name: str, role: str, toolpath: ToolpathParams, *,
             top_z: float, bound_mm: float, stats: dict) -> ProgramPlan:
    """Order and link one setup's passes for one ball into a program."""
    r = part.radius_mm
    tips = [c - np.array([0.0, 0.0, r]) for c in passes.centres if len(c)]
    names = [s for c, s in zip(passes.centres, passes.strategy) if len(c)]
    order = order_passes(tips)
    ordered = [tips[k][::-1] if turned else tips[k] for k, turned in order]
    moves = link_setup(part, ordered, toolpath, top_z=top_z)
    strategy = [names[k] for k, _ in order]
    return ProgramPlan(setup=part.setup, name=name, role=role, tool_radius_mm=r, passes=ordered,
                       strategy=strategy, moves=moves, bound_mm=bound_mm, stats=stats)


def plan_job(vertices: np.ndarray, faces: np.ndarray, tool: ToolParams, toolpath: ToolpathParams, *,
             surfaces: SurfacesIn | None = None, given_setups: list[Setup] = (), processes: int = 1,
             progress: Progress | None = None, check_cancel: CheckCancel | None = None) -> JobPlan:
    """Programs that finish every surface of the part the ball reaches, within the scallop height.

    Parameters
    ----------
    vertices, faces : (n, 3) float, (m, 3) int
        The part (`mesh.ply`): closed, outward, mm, part frame.
    tool, toolpath : ToolParams, ToolpathParams
        The job's groups: ball and rest-ball radii, scallop height, setups, margins.
    surfaces : SurfacesIn, optional
        The fitted patches, for the patch passes; None when the job has none.
    given_setups : list of Setup
        Setups to consider first (segment's).
    processes : int
        Patches, waterline levels and candidate setups worked on at once, in forked processes
        (`cam.map_forked`; the programs are the same).
    progress, check_cancel : callable, optional
        cam's callbacks (see `cam`).

    Returns
    -------
    JobPlan

    Raises
    ------
    GeometryError
        When the scallop height is not below the ball radius, or no setup reaches any of the part.
    """
    progress = progress or (lambda f, m=None: None)
    check_cancel = check_cancel or (lambda: None)
    r, h = float(tool.radius_mm), float(toolpath.scallop_height_mm)
    if not 0 < h < r:
        raise GeometryError(f"the scallop height toolpath.scallop_height_mm must lie in (0, tool.radius_mm = {r}) "
                            f"mm, got {h}")
    chord_mm = toolpath.chord_fraction * h
    scallop_mm = (1 - toolpath.chord_fraction) * h - ROUNDING_MM
    width = float(flat_spacing(scallop_mm, r))
    progress(0.01, "sampling the part")
    samples = sample_surface(vertices, faces, spacing_mm=width / 3)
    setups = choose_setups(samples, vertices, faces, tool_radius_mm=r, max_setups=toolpath.max_setups,
                           given=list(given_setups), processes=processes, check_cancel=check_cancel)
    check_cancel()
    parts = [setup_part(vertices, faces, s, tool_radius_mm=r) for s in setups]
    choice = setup_reach(samples, parts)
    if not choice.setups or not choice.any().any():
        raise GeometryError(f"no setup reaches any of the part with a ball of radius {r} mm")
    progress(0.05, "patch passes")
    patch_plan, passes = _patch_passes(surfaces, choice.setups, parts, tool, toolpath, chord_mm=chord_mm,
                                       processes=processes, check_cancel=check_cancel,
                                       progress=progress_labelled(progress, 0.05, 0.2, "patch passes"))
    left = np.full(len(samples.area), np.inf)
    stats = _finish_rest_of_part(parts, samples, choice.reach, passes, left, h=h, scallop_mm=scallop_mm,
                                 chord_mm=chord_mm, processes=processes, progress=progress_between(progress, 0.2, 0.8),
                                 check_cancel=check_cancel)
    reach_main = choice.any()
    finished = left <= h
    top_z = [float(s.to_machine(vertices)[:, 2].max()) for s in choice.setups]
    programs = [_program(part, passes[k], program_name(k), "main", toolpath, top_z=top_z[k],
                         bound_mm=float(np.max(left[finished & choice.reach[k]], initial=0.0)), stats=stats[k])
                for k, part in enumerate(parts)]
    rest_left, rest_programs = _rest(vertices, faces, samples, choice.setups, left, tool, toolpath, h=h,
                                     scallop_mm=scallop_mm, chord_mm=chord_mm, top_z=top_z, processes=processes,
                                     progress=progress_between(progress, 0.8, 0.97), check_cancel=check_cancel)
    coverage = _coverage(samples, reach_main, left, rest_left, h)
    progress(0.98, "linked")
    return JobPlan(programs=[p for p in programs + rest_programs if p.passes], setups=choice.setups,
                   patches=patch_plan, coverage=coverage, tool_radius_mm=r, rest_radius_mm=tool.rest_radius_mm,
                   scallop_height_mm=h, scallop_share_mm=scallop_mm, chord_tolerance_mm=chord_mm)


def _rest(vertices, faces, samples: SurfaceSamples, setups: list[Setup], left: np.ndarray, tool: ToolParams,
          toolpath: ToolpathParams, *, h: float, scallop_mm: float, chord_mm: float, top_z: list[float],
          processes: int, progress, check_cancel) -> tuple[np.ndarray | None, list[ProgramPlan]]:
    """The rest ball's programs for what the main ball leaves over the target; None without a rest ball."""
    if tool.rest_radius_mm is None:
        return None, []
    r2 = float(tool.rest_radius_mm)
    if not h < r2:
        raise GeometryError(f"the scallop height {h} mm must be below tool.rest_radius_mm = {r2} mm")
    rest_left = np.where(left <= h, left, np.inf)
    programs = []
    for k, setup in enumerate(setups):
        part = setup_part(vertices, faces, setup, tool_radius_mm=r2)
        points, normals = _machine(samples, setup)
        target = ~(rest_left <= h) & part.reaches(points, normals)
        progress(k / len(setups), f"setup {k + 1}: rest ball")
        done = finish_setup(part, points[target], normals[target], scallop_mm=scallop_mm, chord_mm=chord_mm,
                            target_mm=h, processes=processes, check_cancel=check_cancel,
                            progress=progress_labelled(progress, k / len(setups), (k + 1) / len(setups),
                                                       f"setup {k + 1}: rest ball"))
        rest_left[target] = np.minimum(rest_left[target], done.left)
        finished = target.copy()
        finished[target] = done.left <= h
        programs.append(_program(part, _Passes(done.passes, done.strategy), program_name(k, rest=True), "rest",
                                 toolpath, top_z=top_z[k], bound_mm=float(np.max(rest_left[finished], initial=0.0)),
                                 stats={"targets": int(target.sum()), **done.stats}))
    return rest_left, programs


def _coverage(samples: SurfaceSamples, reach: np.ndarray, left: np.ndarray, rest_left: np.ndarray | None,
              h: float) -> dict:
    """The planner's shares of the part's area: reached by the main ball, finished, and what is left why."""
    area = samples.area
    total = float(area.sum())
    finished = reach & (left <= h)
    out = {"samples": len(area), "area_mm2": total,
           "reachable_share": float(area[reach].sum() / total),
           "finished_share_of_reachable": float(area[finished].sum() / max(area[reach].sum(), 1e-300)),
           "unfinished_reachable_mm2": float(area[reach & ~finished].sum()),
           "unreachable_mm2": float(area[~reach].sum())}
    if rest_left is not None:
        by_rest = ~finished & (rest_left <= h)
        out["finished_by_rest_mm2"] = float(area[by_rest].sum())
        out["finished_share_with_rest"] = float(area[finished | by_rest].sum() / total)
    return out
