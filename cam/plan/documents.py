"""What the plan stage writes about its programs: headers, `toolpath.json`, `setup.json` and the CSV rows.

DESIGN's fields are kept (`toolpath.json`: tool, scallop_height_mm, setups → patches with passes and
certified_scallop_mm; `setup.json`: setups with id, rotation, translation, program, patches, unmachined);
the mesh strategies' passes are listed per setup beside the patches, each entry naming its strategy and
its ball, and every setup names its rest program where there is one.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cam.gcode.writer import GENERATOR
from cam.params import ToolParams, ToolpathParams
from cam.plan.job import JobPlan, ProgramPlan

__all__ = ["program_header", "setup_document", "toolpath_document", "toolpath_rows"]


def _r(x, d: int = 4) -> list:
    return np.round(np.asarray(x, dtype=np.float64), d).tolist()


def program_header(plan: JobPlan, program: ProgramPlan, *, job_id: str, tool_number: int, dialect: str
                   ) -> dict[str, str]:
    """The comment lines a program starts with ("key: value"): what a machinist and verify need."""
    counts: dict[str, int] = {}
    for s in program.strategy:
        key = "patch" if s.startswith("patch") else s
        counts[key] = counts.get(key, 0) + 1
    role = "rest tool" if program.role == "rest" else "finishing tool"
    return {
        "cloud2cnc finishing program": f"job {job_id}, setup {program.setup.id}, {role}",
        "tool": f"ball end mill radius {program.tool_radius_mm:.4f} mm, T{tool_number}",
        "target scallop": f"{plan.scallop_height_mm:.4f} mm",
        "certified scallop bound": f"{program.bound_mm:.6f} mm",
        "bound": "the largest scallop the planner measured on the part's samples this program finishes "
                 "(exact ball sweep along each sample's normal), verify measures again",
        "budget split": f"scallop {plan.scallop_share_mm:.4f} mm + chord {plan.chord_tolerance_mm:.4f} mm",
        "passes": ", ".join(f"{k} {v}" for k, v in sorted(counts.items())),
        "units": "mm, absolute, tool tip in the machine frame (ball centre = tip + r Z)",
        "dialect": dialect,
        "generator": GENERATOR,
    }


def _strategy_entries(program: ProgramPlan) -> list[dict[str, Any]]:
    groups: dict[str, list] = {}
    for tips, s in zip(program.passes, program.strategy):
        if not s.startswith("patch"):
            groups.setdefault(s, []).append(_r(tips))
    return [{"patch": None, "strategy": s, "tool": program.role, "tool_radius_mm": program.tool_radius_mm,
             "passes": passes, "certified_scallop_mm": program.bound_mm} for s, passes in groups.items()]


def toolpath_document(plan: JobPlan, tool: ToolParams, toolpath: ToolpathParams) -> dict[str, Any]:
    """`toolpath.json`: per setup the patch passes (with their certificates) and the mesh strategies' passes
    of every program, tool tips in the machine frame, in cutting order."""
    patch_plans = {sp.setup.id: sp for sp in plan.patches.setups} if plan.patches else {}
    setups = []
    for setup in plan.setups:
        mine = [p for p in plan.programs if p.setup.id == setup.id]
        patches = []
        for pp in patch_plans[setup.id].patches if setup.id in patch_plans else []:
            patches.append({"patch": pp.patch, "strategy": "contour-parallel", "tool": "main",
                            "passes": [_r(t) for t in pp.passes], "region": list(pp.region),
                            "certified_scallop_mm": pp.certified_scallop_mm,
                            "certified_on": "the fitted surface (exact scallop relations); lifted where the mesh "
                                            "is higher"})
        for program in mine:
            patches += _strategy_entries(program)
        setups.append({"id": setup.id, "programs": [{"name": p.name, "role": p.role,
                                                      "tool_radius_mm": p.tool_radius_mm,
                                                      "bound_mm": p.bound_mm, "stats": {**p.moves.stats(),
                                                                                        **p.stats}}
                                                     for p in mine],
                       "patches": patches})
    return {"tool": {"shape": "ball", "radius_mm": plan.tool_radius_mm, "number": tool.tool_number,
                     "rest_radius_mm": plan.rest_radius_mm, "rest_number": tool.rest_tool_number},
            "scallop_height_mm": plan.scallop_height_mm, "scallop_share_mm": plan.scallop_share_mm,
            "chord_tolerance_mm": plan.chord_tolerance_mm, "coverage": plan.coverage,
            "unmachined": plan.patches.unmachined if plan.patches else [],
            "partial": plan.patches.partial if plan.patches else [], "setups": setups}


def setup_document(plan: JobPlan, base: dict[str, Any] | None = None) -> dict[str, Any]:
    """`setup.json` as plan leaves it (it supersedes segment's): every setup with its programs."""
    patch_plans = {sp.setup.id: sp for sp in plan.patches.setups} if plan.patches else {}
    setups = []
    for setup in plan.setups:
        main = next((p.name for p in plan.programs if p.setup.id == setup.id and p.role == "main"), None)
        rest = next((p.name for p in plan.programs if p.setup.id == setup.id and p.role == "rest"), None)
        patch_ids = list(dict.fromkeys(pp.patch for pp in patch_plans[setup.id].patches)) if setup.id in patch_plans \
            else []
        setups.append({"id": setup.id, "rotation": setup.rotation.tolist(), "translation": setup.translation.tolist(),
                       "tool_axis": setup.tool_axis_part.tolist(), "program": main, "rest_program": rest,
                       "patches": patch_ids, "unmachined": []})
    doc = {k: v for k, v in (base or {}).items() if k not in ("setups",)}
    return {**doc, "setups": setups, "tool_radius_mm": plan.tool_radius_mm, "rest_radius_mm": plan.rest_radius_mm,
            "coverage": plan.coverage}


def toolpath_rows(plan: JobPlan) -> list[list]:
    """CSV rows (header first): setup, program, strategy, pass, x, y, z of every tool tip."""
    rows = [["setup", "program", "strategy", "pass", "x", "y", "z"]]
    for program in plan.programs:
        for j, (tips, s) in enumerate(zip(program.passes, program.strategy)):
            rows += [[program.setup.id, program.name, s, j, f"{x:.4f}", f"{y:.4f}", f"{z:.4f}"] for x, y, z in tips]
    return rows
