"""Programs that finish the part: measured on the part's mesh by verify's own check, from the G-code.

Each case plans on a CSG part made here (no patches: the mesh strategies alone), writes the programs,
parses them back and measures them on the mesh: the share of what the ball reaches that is left within
the scallop height, and that nothing cuts into the part.
"""

from __future__ import annotations

import numpy as np
import pytest

manifold3d = pytest.importorskip("manifold3d")

from cam.gcode import parse_program, write_program  # noqa: E402
from cam.params import ToolParams, ToolpathParams  # noqa: E402
from cam.plan import plan_job  # noqa: E402
from cam.verify.part import ProgramIn, measure_part  # noqa: E402

R, H = 3.0, 0.16


def _mesh(solid) -> tuple[np.ndarray, np.ndarray]:
    m = solid.to_mesh()
    return np.asarray(m.vert_properties, dtype=np.float64)[:, :3], np.asarray(m.tri_verts, dtype=np.int64)


def _measure(vertices, faces, plan, toolpath: ToolpathParams):
    programs = [ProgramIn(setup=p.setup, program=parse_program(write_program(p.moves, header={})),
                          tool_radius_mm=p.tool_radius_mm, role=p.role, name=p.name) for p in plan.programs]
    width = 2.0 * np.sqrt(H * (2 * R - H))
    return measure_part(vertices, faces, programs, plan.setups, tool_radius_mm=R,
                        rest_radius_mm=plan.rest_radius_mm, target_mm=H, spacing_mm=width / 4,
                        rapid_margin_mm=toolpath.rapid_margin_mm).report


def _finish(solid, **toolpath):
    vertices, faces = _mesh(solid)
    tp = ToolpathParams(scallop_height_mm=H, **toolpath)
    plan = plan_job(vertices, faces, ToolParams(radius_mm=R), tp)
    return plan, _measure(vertices, faces, plan, tp)


def _assert_finished(report, share=0.99):
    assert report["finished_share_of_reachable"] >= share, report["summary"]
    assert report["max_scallop_mm"] <= H
    assert report["max_gouge_mm"] <= 0.01 and report["max_rapid_gouge_mm"] <= 0.01
    assert all(p["rapid_margin_violation_mm"] <= 0.01 for p in report["programs"])


def test_a_box_with_vertical_walls_is_finished_walls_and_all():
    box = manifold3d.Manifold.cube([24.0, 18.0, 10.0], center=True)
    plan, report = _finish(box, max_setups=1)
    _assert_finished(report)
    # From one setup the ball reaches the face towards the tool and the walls down to one radius above the
    # table; the setup chosen is the axis along which that is most (the longest: x).
    size = {"x": 24.0, "y": 18.0, "z": 10.0}
    reach = {a: np.prod([v for b, v in size.items() if b != a]) + 2 * sum(v for b, v in size.items() if b != a)
             * (size[a] - R) for a in size}
    assert max(reach, key=reach.get) == "x"
    assert abs(plan.setups[0].tool_axis_part[0]) == pytest.approx(1.0)
    assert report["reachable_share"] == pytest.approx(reach["x"] / box.surface_area(), abs=0.01)
    assert {"raster", "waterline"} <= set(plan.programs[0].strategy)


def test_a_pocket_with_corners_tighter_than_the_ball_is_finished_where_the_ball_reaches():
    block = manifold3d.Manifold.cube([30.0, 24.0, 12.0], center=True)
    pocket = manifold3d.Manifold.cube([14.0, 10.0, 8.0], center=True).translate([0, 0, 4.0])
    plan, report = _finish(block - pocket, max_setups=1)
    _assert_finished(report)
    # The pocket's sharp inner corners and edges are out of the ball's reach, and said so.
    assert report["unfinished_mm2"]["unreachable_by_main_ball_mm2"] > 0
    # Part of what the ball cannot touch there (the foot of the pocket's walls, beside the sharp edge) is
    # left within the target all the same; the summary says how much of the whole part is.
    finished = report["finished_share"]
    assert finished > report["reachable_share"] + 0.01
    assert report["summary"].endswith(f"; {100 * finished:.1f} % of the whole part is left within {H:g} mm")


def test_a_rest_ball_finishes_the_corners_the_main_ball_cannot_reach():
    block = manifold3d.Manifold.cube([30.0, 24.0, 12.0], center=True)
    pocket = manifold3d.Manifold.cube([14.0, 10.0, 8.0], center=True).translate([0, 0, 4.0])
    vertices, faces = _mesh(block - pocket)
    # Two setups (the default): between them the balls reach every face but the pocket's inner edges.
    tp = ToolpathParams(scallop_height_mm=H)
    plan = plan_job(vertices, faces, ToolParams(radius_mm=R, rest_radius_mm=1.0), tp)
    assert sorted(p.role for p in plan.programs) == ["main", "main", "rest", "rest"]
    report = _measure(vertices, faces, plan, tp)
    _assert_finished(report)
    # Beside a sharp inner edge a ball of radius r leaves a band r wide on each face unreachable: the 1 mm
    # ball reaches all but a third of what the 3 mm one cannot, and finishes what it reaches.
    lost = report["unfinished_mm2"]
    assert lost["unreachable_by_any_ball_mm2"] <= 0.5 * lost["unreachable_by_main_ball_mm2"]
    assert lost["left_for_rest_tool_mm2"] <= 0.01 * lost["unreachable_by_main_ball_mm2"]
    assert "1 mm rest ball" in report["summary"]


def test_a_dome_with_a_ripple_is_finished_over_the_ripple():
    base = manifold3d.Manifold.cube([30.0, 30.0, 6.0], center=True).translate([0, 0, -3.0])
    dome = manifold3d.Manifold.sphere(20.0, 128).translate([0, 0, -14.0]) ^ manifold3d.Manifold.cube(
        [30.0, 30.0, 40.0], center=True).translate([0, 0, 20.0])
    vertices, faces = _mesh(base + dome)
    # A 0.01 mm ripple over the dome (a wave of 2 mm): no hollow the ball cannot follow.
    top = vertices[:, 2] > 0.01
    vertices[top, 2] += 0.01 * np.sin(np.pi * vertices[top, 0]) * np.sin(np.pi * vertices[top, 1])
    tp = ToolpathParams(scallop_height_mm=H)
    plan = plan_job(vertices, faces, ToolParams(radius_mm=R), tp)
    _assert_finished(_measure(vertices, faces, plan, tp))


def test_a_planted_gouge_fails_against_the_mesh():
    box = manifold3d.Manifold.cube([20.0, 16.0, 8.0], center=True)
    vertices, faces = _mesh(box)
    tp = ToolpathParams(scallop_height_mm=H, max_setups=1)
    plan = plan_job(vertices, faces, ToolParams(radius_mm=R), tp)
    program = plan.programs[0]
    text = write_program(program.moves, header={})
    top = float((vertices @ program.setup.rotation.T + program.setup.translation)[:, 2].max())
    # A cut 0.3 mm into the top face, in the middle of the program.
    planted = text.replace("M5\n", f"G0 X0.0000 Y0.0000 Z{top + 5:.4f}\nG1 Z{top - 0.3:.4f} F300.0\n"
                                   f"G1 X2.0000\nG0 Z{top + 5:.4f}\nM5\n")
    bad = ProgramIn(setup=program.setup, program=parse_program(planted), tool_radius_mm=R, role="main",
                    name="bad.nc")
    width = 2.0 * np.sqrt(H * (2 * R - H))
    report = measure_part(vertices, faces, [bad], plan.setups, tool_radius_mm=R, rest_radius_mm=None, target_mm=H,
                          spacing_mm=width / 4, rapid_margin_mm=tp.rapid_margin_mm).report
    assert report["max_gouge_mm"] == pytest.approx(0.3, abs=0.02)


def test_waterline_levels_in_forked_processes_give_the_same_programs():
    # The levels are worked on side by side (processes=2); each level is the one computed alone, so the
    # programs are the serial run's, move for move.
    solid = manifold3d.Manifold.cylinder(12.0, 10.0, 10.0, 48) + manifold3d.Manifold.cube([30.0, 24.0, 4.0], center=True)
    vertices, faces = _mesh(solid)
    tp = ToolpathParams(scallop_height_mm=H, max_setups=1)
    serial = plan_job(vertices, faces, ToolParams(radius_mm=R), tp)
    forked = plan_job(vertices, faces, ToolParams(radius_mm=R), tp, processes=2)
    assert "waterline" in serial.programs[0].strategy
    assert [write_program(p.moves, header={}) for p in forked.programs] == \
        [write_program(p.moves, header={}) for p in serial.programs]
