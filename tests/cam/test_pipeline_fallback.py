"""A part whose quad layout fails still ends with a verified program: the mesh strategies machine all of it.

The whole pipeline runs in-process (`cloud2cnc run`) on a CSG mesh made here, with remesh made to fail
(its Hausdorff check can accept nothing). remesh, segment and fit then skip with a reason, plan machines
the part by raster and waterline on the mesh alone, and verify passes. The programs are then measured
again on the CSG part itself, not only on the job's own mesh.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

manifold3d = pytest.importorskip("manifold3d")
trimesh = pytest.importorskip("trimesh")

from cam.gcode import parse_program  # noqa: E402
from cam.io import read_setups  # noqa: E402
from cam.verify.part import ProgramIn, measure_part  # noqa: E402
from core.config import Settings  # noqa: E402
from worker.local import run_local  # noqa: E402

R, H = 3.0, 0.16


def test_a_part_whose_remesh_fails_is_still_finished(tmp_path):
    block = manifold3d.Manifold.cube([30.0, 24.0, 12.0], center=True)
    pocket = manifold3d.Manifold.cube([14.0, 10.0, 8.0], center=True).translate([0, 0, 4.0])
    m = (block - pocket).to_mesh()
    vertices = np.asarray(m.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(m.tri_verts, dtype=np.int64)
    upload = tmp_path / "pocket.stl"
    trimesh.Trimesh(vertices, faces, process=False).export(upload)
    params = {"tool": {"radius_mm": R}, "toolpath": {"scallop_height_mm": H, "max_setups": 1},
              "denoise": {"enabled": False}, "remesh": {"attempts": 1, "candidates": 1, "max_hausdorff_ratio": 1e-9}}
    out = tmp_path / "out"
    reports = run_local(upload, out, params=params, settings=Settings(data_dir=tmp_path / "d"))
    status = {r.name: r.status for r in reports}
    assert status["remesh"] == status["segment"] == status["fit"] == "skipped", reports
    assert "from the input at worst" in next(r.error for r in reports if r.name == "remesh")
    assert status["plan"] == status["verify"] == "succeeded", reports

    verify = json.loads((out / "verify.json").read_text())
    assert verify["passed"] and verify["finished_share_of_reachable"] >= 0.99, verify["summary"]
    doc, setups = read_setups(out / "setup.json")
    programs = [ProgramIn(setup=s, program=parse_program((out / e["program"]).read_text()), tool_radius_mm=R,
                          role="main", name=e["program"]) for e, s in zip(doc["setups"], setups)]
    width = 2.0 * np.sqrt(H * (2 * R - H))
    truth = measure_part(vertices, faces, programs, setups, tool_radius_mm=R, rest_radius_mm=None, target_mm=H,
                         spacing_mm=width / 4, rapid_margin_mm=0.5).report
    assert truth["finished_share_of_reachable"] >= 0.99, truth["summary"]
    assert truth["max_gouge_mm"] <= 0.01 and truth["max_rapid_gouge_mm"] <= 0.01
