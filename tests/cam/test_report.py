"""The setup sheet (report.html): its numbers are verify's, its times the hand computation, its pictures honest."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser

import numpy as np
import pytest

from cam.gcode import parse_program
from cam.verify.picture import render_svg, simplify_mesh
from cam.verify.report import classify_faces, measure_moves


def _cube(n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward unit cube [0, 1]³ with each face split into n × n squares (2 triangles each)."""
    verts, faces, index = [], [], {}

    def vid(p):
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(verts)
            verts.append(p)
        return index[key]

    for axis in range(3):
        for side in (0.0, 1.0):
            u, v = [a for a in range(3) if a != axis]
            for i in range(n):
                for j in range(n):
                    quad = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[axis], p[u], p[v] = side, (i + di) / n, (j + dj) / n
                        quad.append(vid(p))
                    a, b, c, d = quad
                    tris = [(a, b, c), (a, c, d)]
                    for t in tris:  # orient outward
                        P = np.array([verts[k] for k in t])
                        normal = np.cross(P[1] - P[0], P[2] - P[0])
                        faces.append(t if normal[axis] * (1 if side else -1) > 0 else t[::-1])
    return np.array(verts), np.array(faces)


def test_machining_time_of_a_tiny_program_is_the_hand_computation():
    text = ("G21 G90\n"
            "G0 X0 Y0 Z5\n"     # position only: the axes become known here
            "G1 Z0 F300\n"      # 5 mm plunge at 300 mm/min: 1/60 min
            "G1 X60 F1200\n"    # 60 mm at 1200 mm/min: 0.05 min
            "G1 X60 Y80\n"      # 80 mm, same feed: 1/15 min
            "G0 Z10\n"          # rapids: 10 mm ...
            "G0 X0 Y0\nM30\n")  # ... and 100 mm
    cutting, rapid, cutting_min, rapid_min = measure_moves(parse_program(text), rapid_mm_min=5000.0)
    assert cutting == pytest.approx(5 + 60 + 80, abs=1e-12)
    assert rapid == pytest.approx(10 + 100, abs=1e-12)
    assert cutting_min == pytest.approx(5 / 300 + 60 / 1200 + 80 / 1200, abs=1e-12)
    assert rapid_min == pytest.approx(110 / 5000, abs=1e-12)
    with pytest.raises(ValueError, match="rapid_mm_min"):
        measure_moves(parse_program(text), rapid_mm_min=0.0)


def test_inch_programs_are_timed_in_mm():
    text = "G20 G90\nG0 X0 Y0 Z0\nG1 X1 F10\n"  # 1 inch at 10 in/min: 0.1 min
    cutting, _, cutting_min, _ = measure_moves(parse_program(text))
    assert cutting == pytest.approx(25.4) and cutting_min == pytest.approx(0.1)


def test_simplify_mesh_keeps_at_most_max_faces_and_maps_each_face_to_its_source():
    V, F = _cube(12)  # 864 triangles
    V2, F2, src = simplify_mesh(V, F, max_faces=200)
    assert 0 < len(F2) <= 200 and len(src) == len(F2) and src.max() < len(F)
    assert F2.min() >= 0 and F2.max() < len(V2)
    assert np.all((F2[:, 0] != F2[:, 1]) & (F2[:, 1] != F2[:, 2]) & (F2[:, 0] != F2[:, 2]))
    assert len(np.unique(np.sort(F2, axis=1), axis=0)) == len(F2)
    # the clusters stay on the part: every vertex inside the cube's box
    assert V2.min() >= -1e-12 and V2.max() <= 1 + 1e-12
    same = simplify_mesh(V, F, max_faces=len(F))
    assert np.array_equal(same[1], F) and np.array_equal(same[2], np.arange(len(F)))
    with pytest.raises(ValueError, match="max_faces"):
        simplify_mesh(V, F, max_faces=0)


def test_a_closed_part_shows_only_the_faces_turned_to_the_viewer():
    V, F = _cube(1)
    svg = render_svg(V, F, direction=(-1.0, -1.0, -1.0), up=(0, 0, 1))
    assert svg.count('<path d="M') == 6  # three faces of the cube, two triangles each
    svg = render_svg(V, F, direction=(0.0, 0.0, -1.0), up=(0, 1, 0))
    assert svg.count('<path d="M') == 2  # straight down: the top only


def test_painter_draws_the_nearer_triangle_last():
    # Two parallel open triangles overlapping on screen; the one at z = 1 is nearer a viewer above.
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], dtype=float)
    F = np.array([[3, 4, 5], [0, 1, 2]])
    colors = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # near red, far blue
    svg = render_svg(V, F, direction=(0, 0, -1), up=(0, 1, 0), face_colors=colors)
    fills = re.findall(r'<path d="M[^"]*" fill="#([0-9a-f]{6})"', svg)
    assert len(fills) == 2
    first, last = (tuple(int(f[k:k + 2], 16) for k in (0, 2, 4)) for f in fills)
    assert first[2] > first[0] and last[0] > last[2]  # blue (far) first, red (near) over it


def test_each_face_takes_the_class_most_of_its_samples_have():
    face = np.array([0, 0, 0, 1, 1, 2, 2, 2])
    left = np.array([0.1, 0.1, 0.5, 0.3, np.inf, 0.05, np.inf, np.inf])
    reach = np.array([True, True, True, True, True, False, False, False])
    cls = classify_faces(face, left, reach, 4, target_mm=0.16)
    # face 0: two finished, one over; face 1: one over, one not cut (tie: the first class); face 2:
    # unreachable twice, finished once (a rest ball's work); face 3 has no sample
    assert cls.tolist() == [0, 1, 3, -1]


class _Numbers(HTMLParser):
    """Every `data-key` / `data-value` pair of a page, and its text."""

    def __init__(self) -> None:
        super().__init__()
        self.values: dict[str, list[float]] = {}
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "data-key" in a:
            self.values.setdefault(a["data-key"], []).append(float(a["data-value"]))

    def handle_data(self, data):
        self.text.append(data)


def test_the_sheet_shows_verify_json_numbers_and_the_programs_times(tmp_path):
    manifold3d = pytest.importorskip("manifold3d")
    from cam.io import write_ply_mesh
    from core.params import JobParams
    from worker.context import StageContext
    from worker.stages.plan import run_plan
    from worker.stages.verify import run_verify

    def ctx(stage, inputs):
        out = tmp_path / stage
        out.mkdir()
        params = {"tool": {"radius_mm": 3.0, "feed_mm_min": 1000, "plunge_mm_min": 250},
                  "toolpath": {"scallop_height_mm": 0.16, "max_setups": 1}}
        return StageContext(job_id="job-7", stage=stage, inputs=inputs, out_dir=out,
                            params=JobParams.model_validate(params), settings={})

    solid = manifold3d.Manifold.cube([26.0, 20.0, 10.0], center=True) - \
        manifold3d.Manifold.cube([10.0, 8.0, 6.0], center=True).translate([0, 0, 4])
    m = solid.to_mesh()
    mesh = write_ply_mesh(tmp_path / "mesh.ply", np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts))
    plan = run_plan(ctx("plan", {"mesh.ply": mesh}))
    out = run_verify(ctx("verify", {"mesh.ply": mesh, "setup.json": plan["setup.json"],
                                    "program.nc": plan["program.nc"]}))
    verify = json.loads(out["verify.json"].read_text())
    html = out["report.html"].read_text()
    page = _Numbers()
    page.feed(html)
    text = " ".join(page.text)
    for key in ("finished_share_of_reachable", "reachable_share", "finished_share", "area_mm2", "target_scallop_mm",
                "certified_scallop_mm", "max_scallop_mm", "p99_scallop_mm", "max_left_on_reachable_mm",
                "max_gouge_mm", "max_rapid_gouge_mm", "min_finished_share"):
        assert page.values[key] and set(page.values[key]) == {verify[key]}, key
    for key, v in verify["unfinished_mm2"].items():
        if key != "left_for_rest_tool_mm2":  # no rest ball: that row is left off
            assert page.values[key] == [v], key
    share = verify["finished_share_of_reachable"]
    assert f"finished {100 * share:.1f} % of what a 3 mm ball can reach" in text
    cutting, rapid, cutting_min, rapid_min = measure_moves(parse_program(plan["program.nc"].read_text()))
    assert page.values["cutting_mm"] == [cutting] and page.values["rapid_mm"] == [rapid]
    assert page.values["machining_min"] == [cutting_min + rapid_min]
    for heading in ("Setup sheet", "The part", "Tools", "Programs", "Certificate", "Coverage", "Unfinished areas",
                    "Setup 1"):
        assert f">{heading}</h" in html, heading
    assert "program.nc" in text and "main ball" in text and "tool axis" in html
    assert not re.search(r"https?://", html) and "<script" not in html  # self-contained, nothing to fetch or run
    assert html.count("<svg") == 4  # the part, its coverage from above and below, setup 1 on the table
    assert len(html) < 600_000
