"""The plan and verify stage adapters end to end on a two-patch analytic part (files in, files out)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cam.io import read_input
from cam.spline import analytic
from core.params import JobParams
from worker.context import StageContext, StageError


def _ctx(tmp_path, stage, inputs, dialect="linuxcnc"):
    params = {"tool": {"radius_mm": 3.0, "tool_number": 2, "spindle_rpm": 10000, "feed_mm_min": 1000,
                       "plunge_mm_min": 250},
              "toolpath": {"scallop_height_mm": 0.16, "dialect": dialect}}
    out = tmp_path / stage
    out.mkdir()
    return StageContext(job_id="job-1", stage=stage, inputs=inputs, out_dir=out,
                        params=JobParams.model_validate(params), settings={})


def test_plan_then_verify(tmp_path):
    surfaces = [analytic.plane(12, 10, z=0.0), analytic.cylinder(20.0, 10.0, 40.0)]
    doc = {"surfaces": [{"patch": i, **s.to_json(), "max_error_mm": 0.0} for i, s in enumerate(surfaces)]}
    # The cylinder sits beside the plane: move its control points 20 mm along x.
    doc["surfaces"][1]["control_points"] = (np.array(doc["surfaces"][1]["control_points"]) + [30, 0, 0]).tolist()
    (tmp_path / "surfaces.json").write_text(json.dumps(doc))
    (tmp_path / "setup.json").write_text(json.dumps({"setups": [{"id": 1, "rotation": np.eye(3).tolist(),
                                                                 "translation": [0, 0, 10]}]}))
    from worker.stages.plan import run_plan
    from worker.stages.verify import run_verify

    ctx = _ctx(tmp_path, "plan", {"surfaces.json": tmp_path / "surfaces.json", "setup.json": tmp_path / "setup.json"})
    out = run_plan(ctx)
    assert set(out) == {"program.nc", "toolpath.json", "toolpath.csv", "setup.json"}
    tp = json.loads(out["toolpath.json"].read_text())
    assert tp["certified_scallop_mm"] <= 0.16 and len(tp["setups"][0]["patches"]) == 2
    text = out["program.nc"].read_text()
    assert "(certified scallop bound:" in text and "T2 M6" in text
    assert out["toolpath.csv"].read_text().startswith("setup,patch,pass,x,y,z")
    vctx = _ctx(tmp_path, "verify", {"surfaces.json": tmp_path / "surfaces.json", "setup.json": out["setup.json"],
                                     "program.nc": out["program.nc"]})
    vout = run_verify(vctx)
    report = json.loads(vout["verify.json"].read_text())
    assert report["passed"] and report["max_scallop_mm"] <= report["certified_scallop_mm"]
    heat = read_input(vout["scallop.ply"])
    assert heat.faces is not None and heat.colors is not None and len(heat.points) == report["setups"][0]["samples"]

    # A planted gouge fails the stage but still leaves the report.
    (tmp_path / "bad.nc").write_text(text.replace("M5\n", "G0 X5.0000 Y5.0000 Z20.0000\nG1 Z9.5000 F300.0\n"
                                                  "G1 X9.0000\nG0 Z20.0000\nM5\n"))
    bctx = _ctx(tmp_path, "verify-bad", {"surfaces.json": tmp_path / "surfaces.json", "setup.json": out["setup.json"],
                                         "program.nc": tmp_path / "bad.nc"})
    with pytest.raises(StageError, match=r"cutting move cuts 0\.49") as err:
        run_verify(bctx)
    assert "verify.json" in err.value.outputs


def test_a_partly_finished_patch_is_claimed_and_verified_on_its_claim(tmp_path):
    from cam.spline.surface import clamped_uniform_knots, make_bspline_surface
    from worker.stages.plan import run_plan
    from worker.stages.verify import run_verify

    g = np.linspace(0, 10, 8)
    X, Y = np.meshgrid(g, g, indexing="ij")
    P = np.stack([X, Y, np.zeros_like(X)], -1)
    P[6, :, 0] = 10.6  # a lip that folds back along u = 1
    k = clamped_uniform_knots(8)
    lip = make_bspline_surface(P, k, k)
    (tmp_path / "surfaces.json").write_text(json.dumps({"surfaces": [{"patch": 5, **lip.to_json(),
                                                                      "max_error_mm": 0.0}]}))
    (tmp_path / "setup.json").write_text(json.dumps({"setups": [{"id": 1, "rotation": np.eye(3).tolist(),
                                                                 "translation": [0, 0, 10]}]}))
    out = run_plan(_ctx(tmp_path, "plan", {"surfaces.json": tmp_path / "surfaces.json",
                                           "setup.json": tmp_path / "setup.json"}))
    (entry,) = json.loads(out["setup.json"].read_text())["setups"][:1]
    (claim,) = entry["partial"]
    assert claim["patch"] == 5 and claim["region"][1] < 1.0 and "folds over itself" in claim["reason"]
    report = json.loads(run_verify(_ctx(tmp_path, "verify", {
        "surfaces.json": tmp_path / "surfaces.json", "setup.json": out["setup.json"],
        "program.nc": out["program.nc"]}))["verify.json"].read_text())
    assert report["passed"] and report["max_scallop_mm"] <= report["certified_scallop_mm"] <= 0.16
    assert report["max_gouge_mm"] < 1e-3


def test_a_patch_claimed_on_two_rectangles_is_verified_on_both(tmp_path):
    # A floor with a rib standing across it: the ball finishes the floor on both sides of the rib, two
    # claims of one patch in setup.json; verify measures the program on exactly those two rectangles.
    from cam.spline import analytic
    from worker.stages.plan import run_plan
    from worker.stages.verify import run_verify

    floor = analytic.plane(20.0, 16.0)
    rib = analytic.fit_grid(lambda u, v: np.stack([np.full_like(u, 8.0), 16 * u, 6 * v], -1), n=(4, 4))
    (tmp_path / "surfaces.json").write_text(json.dumps({"surfaces": [
        {"patch": 1, **floor.to_json(), "max_error_mm": 0.0}, {"patch": 2, **rib.to_json(), "max_error_mm": 0.0}]}))
    (tmp_path / "setup.json").write_text(json.dumps({"setups": [{"id": 1, "rotation": np.eye(3).tolist(),
                                                                 "translation": [0, 0, 0]}]}))
    out = run_plan(_ctx(tmp_path, "plan", {"surfaces.json": tmp_path / "surfaces.json",
                                           "setup.json": tmp_path / "setup.json"}))
    entry = json.loads(out["setup.json"].read_text())["setups"][0]
    claims = [q for q in entry["partial"] if q["patch"] == 1]
    assert len(claims) == 2 and entry["patches"].count(1) == 1
    report = json.loads(run_verify(_ctx(tmp_path, "verify", {
        "surfaces.json": tmp_path / "surfaces.json", "setup.json": out["setup.json"],
        "program.nc": out["program.nc"]}))["verify.json"].read_text())
    assert report["passed"] and report["max_scallop_mm"] <= report["certified_scallop_mm"] <= 0.16
    # Every sample of both claims is reached: the rectangle before the rib is machined, not left over.
    assert report["setups"][0]["fraction_never_reached"] == 0 and report["uncut_area_mm2"] == 0
    assert report["max_gouge_mm"] < 1e-3
    assert [x["patch"] for x in report["setups"][0]["patches"]].count(1) == 2  # each claim measured
