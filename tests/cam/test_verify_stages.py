"""The plan and verify stage adapters end to end (files in, files out): a part's mesh, and with patches."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cam.io import read_input, write_ply_mesh
from cam.spline import analytic
from core.params import JobParams
from worker.context import StageContext, StageError

manifold3d = pytest.importorskip("manifold3d")


def _ctx(tmp_path, stage, inputs, **toolpath):
    params = {"tool": {"radius_mm": 3.0, "tool_number": 2, "spindle_rpm": 10000, "feed_mm_min": 1000,
                       "plunge_mm_min": 250},
              "toolpath": {"scallop_height_mm": 0.16, "max_setups": 1, **toolpath}}
    out = tmp_path / stage
    out.mkdir()
    return StageContext(job_id="job-1", stage=stage, inputs=inputs, out_dir=out,
                        params=JobParams.model_validate(params), settings={})


def _mesh(tmp_path, solid):
    m = solid.to_mesh()
    return write_ply_mesh(tmp_path / "mesh.ply", np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts))


def test_plan_then_verify_on_the_mesh(tmp_path):
    from worker.stages.plan import run_plan
    from worker.stages.verify import run_verify

    block = manifold3d.Manifold.cube([26.0, 20.0, 10.0], center=True)
    mesh = _mesh(tmp_path, block - manifold3d.Manifold.cube([10.0, 8.0, 6.0], center=True).translate([0, 0, 4]))
    out = run_plan(_ctx(tmp_path, "plan", {"mesh.ply": mesh}))
    assert set(out) == {"program.nc", "toolpath.json", "toolpath.csv", "setup.json"}
    tp = json.loads(out["toolpath.json"].read_text())
    strategies = {p["strategy"] for s in tp["setups"] for p in s["patches"]}
    assert {"raster", "waterline"} <= strategies and tp["coverage"]["finished_share_of_reachable"] >= 0.99
    text = out["program.nc"].read_text()
    assert "(certified scallop bound:" in text and "T2 M6" in text
    assert out["toolpath.csv"].read_text().startswith("setup,program,strategy,pass,x,y,z")
    setups = json.loads(out["setup.json"].read_text())["setups"]
    assert setups[0]["program"] == "program.nc" and setups[0]["rest_program"] is None
    vout = run_verify(_ctx(tmp_path, "verify", {"mesh.ply": mesh, "setup.json": out["setup.json"],
                                                "program.nc": out["program.nc"]}))
    report = json.loads(vout["verify.json"].read_text())
    assert report["passed"] and report["finished_share_of_reachable"] >= 0.99
    assert report["max_scallop_mm"] <= 0.16 and report["max_gouge_mm"] <= 0.01
    assert report["summary"].startswith("finished ") and "of what a 3 mm ball can reach" in report["summary"]
    heat = read_input(vout["scallop.ply"])
    assert heat.faces is not None and heat.colors is not None and len(heat.points) == len(read_input(mesh).points)

    # A planted gouge fails the stage but still leaves the report: 0.4 mm into the face the tool faces.
    rot, shift = np.array(setups[0]["rotation"]), np.array(setups[0]["translation"])
    machine = read_input(mesh).points @ rot.T + shift
    top, (x, y) = machine[:, 2].max(), machine[machine[:, 2] > machine[:, 2].max() - 1e-6, :2].mean(axis=0)
    (tmp_path / "bad.nc").write_text(text.replace("M5\n", f"G0 X{x:.4f} Y{y:.4f}\nG1 Z{top - 0.4:.4f} F300.0\n"
                                                  f"G1 X{x + 1:.4f}\nG1 Z{top + 20:.4f}\nM5\n"))
    bctx = _ctx(tmp_path, "verify-bad", {"mesh.ply": mesh, "setup.json": out["setup.json"],
                                         "program.nc": tmp_path / "bad.nc"})
    with pytest.raises(StageError, match=r"cutting move cuts 0\.(39|40)\d* mm into the part") as err:
        run_verify(bctx)
    assert "verify.json" in err.value.outputs


def test_patch_passes_come_first_and_the_mesh_strategies_finish_the_rest(tmp_path):
    from worker.stages.plan import run_plan
    from worker.stages.verify import run_verify

    # A block whose top face is an analytic plane patch (the fit's output for it).
    mesh = _mesh(tmp_path, manifold3d.Manifold.cube([20.0, 16.0, 8.0]).translate([0, 0, -8.0]))
    doc = {"surfaces": [{"patch": 7, **analytic.plane(20.0, 16.0).to_json(), "max_error_mm": 0.0}],
           "over_tolerance": []}
    (tmp_path / "surfaces.json").write_text(json.dumps(doc))
    (tmp_path / "setup.json").write_text(json.dumps({"setups": [{"id": 1, "rotation": np.eye(3).tolist(),
                                                                 "translation": [0, 0, 8]}]}))
    out = run_plan(_ctx(tmp_path, "plan", {"mesh.ply": mesh, "surfaces.json": tmp_path / "surfaces.json",
                                           "setup.json": tmp_path / "setup.json"}))
    tp = json.loads(out["toolpath.json"].read_text())
    entries = [p for s in tp["setups"] for p in s["patches"]]
    assert any(p["patch"] == 7 and p["strategy"] == "contour-parallel" for p in entries)
    assert json.loads(out["setup.json"].read_text())["setups"][0]["patches"] == [7]
    report = json.loads(run_verify(_ctx(tmp_path, "verify", {"mesh.ply": mesh, "setup.json": out["setup.json"],
                                                             "program.nc": out["program.nc"]}))["verify.json"]
                        .read_text())
    assert report["passed"] and report["finished_share_of_reachable"] >= 0.99


def test_the_stage_registry_lists_every_program_name_plan_can_write():
    from cam.plan import program_name
    from core.stages import PROGRAMS

    assert set(PROGRAMS) == {program_name(k, rest=rest) for k in range(4) for rest in (False, True)}
