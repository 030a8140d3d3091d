"""The plan's progress moves through its long loops (the raster's lines, the waterline's levels), not only
from one setup to the next, and reporting changes none of the programs."""

from __future__ import annotations

import numpy as np
import pytest

manifold3d = pytest.importorskip("manifold3d")

from cam.params import ToolParams, ToolpathParams  # noqa: E402
from cam.plan import plan_job  # noqa: E402


def _box() -> tuple[np.ndarray, np.ndarray]:
    m = manifold3d.Manifold.cube([24.0, 18.0, 10.0], center=True).to_mesh()
    return np.asarray(m.vert_properties, dtype=np.float64)[:, :3], np.asarray(m.tri_verts, dtype=np.int64)


def test_progress_moves_line_by_line_and_level_by_level_and_changes_no_program():
    vertices, faces = _box()
    tool, toolpath = ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16, max_setups=1)
    seen: list[tuple[float, str | None]] = []
    plan = plan_job(vertices, faces, tool, toolpath, progress=lambda f, m=None: seen.append((f, m)))
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions)
    finishing = [(f, m) for f, m in seen if m and m.startswith("setup 1: finishing on the mesh: ")]
    lines = [f for f, m in finishing if ": raster line " in m]
    levels = [f for f, m in finishing if ": waterline level " in m]
    # The box's top takes raster lines, its walls waterline levels: each one its own report, each further on.
    assert len(lines) > 3 and len(levels) > 3
    assert len(set(lines)) == len(lines) and len(set(levels)) == len(levels) and max(lines) < min(levels)
    # Between the setup's start (0.2 of the plan) and its end (0.8), not only at them.
    assert all(0.2 <= f < 0.8 for f, _ in finishing) and len({f for f, _ in finishing}) > 10

    quiet = plan_job(vertices, faces, tool, toolpath)
    assert len(quiet.programs) == len(plan.programs)
    for a, b in zip(quiet.programs, plan.programs, strict=True):
        assert a.strategy == b.strategy and len(a.passes) == len(b.passes)
        assert all(np.array_equal(p, q) for p, q in zip(a.passes, b.passes, strict=True))
