"""The fit stage on files as segment writes them: surfaces.json, surfaces.igs, surfaces.step, and the failures a
user can act on."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cam.io import write_ply_mesh
from cam.spline.surface import surface_from_json
from core.params import JobParams, merge_params
from tests.cam.test_fit_shapes import case, cylinder, quads_of, ridge
from worker.context import StageContext, StageError
from worker.stages.fit import run_fit


def _job(tmp_path, shape, *, blocks, extent=(30, 15), quads=(14, 7), fit=None, valid=None, sharp=False,
         shift=0.0):
    V, ids, MV, MF = case(shape, extent, quads, refine=3)
    if shift:
        # The remesher's version of row 7, `shift` mm along s from where the mesh has it (still on the part).
        s7 = 7 * extent[0] / quads[0]
        V[ids[7]] = shape(np.full(quads[1] + 1, s7 + shift), np.linspace(0, extent[1], quads[1] + 1))
    Q = quads_of(ids)
    face_of = {tuple(sorted(q)): f for f, q in enumerate(Q.tolist())}
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in V.tolist()]
    lines += ["f " + " ".join(str(i + 1) for i in q) for q in Q.tolist()]
    (tmp_path / "quads.obj").write_text("\n".join(lines) + "\n")
    patches = []
    for n, (r0, r1) in enumerate(blocks):
        g = ids[r0:r1 + 1]
        faces = [face_of[tuple(sorted(q))] for q in quads_of(g).tolist()]
        patches.append({"id": 10 * (n + 1), "faces": faces, "rows": r1 - r0, "cols": quads[1],
                        "corners": [int(g[0, 0]), int(g[0, -1]), int(g[-1, -1]), int(g[-1, 0])],
                        "sharp_boundary": False, **({} if valid is None else {"valid": valid[n], "problems": ["x"]})})
    edges = [[int(a), int(b)] for a, b in zip(ids[7, :-1], ids[7, 1:])] if sharp else []
    (tmp_path / "patches.json").write_text(json.dumps({"patches": patches, "base_faces": [], "sharp_edges": edges}))
    write_ply_mesh(tmp_path / "mesh.ply", MV, MF)
    out = tmp_path / "out"
    out.mkdir()
    names = ("quads.obj", "patches.json", "mesh.ply")
    ctx = StageContext(job_id="j", stage="fit", inputs={n: tmp_path / n for n in names}, out_dir=out,
                       params=JobParams.model_validate({"fit": fit or {}}), settings={})
    return ctx, MV, MF


def _changed(params: JobParams, **groups) -> JobParams:
    """`params` with the fields in `groups` ({group: {name: value}}) changed, validated again."""
    return JobParams.model_validate(merge_params(params.model_dump(), groups))


def test_stage_writes_surfaces_json_iges_and_step(tmp_path):
    ctx, MV, MF = _job(tmp_path, cylinder(25.0), blocks=[(0, 7), (7, 14)])
    seen = []
    ctx.progress = lambda f, m=None: seen.append(f)
    out = run_fit(ctx)
    assert set(out) == {"surfaces.json", "surfaces.igs", "surfaces.step"}
    doc = json.loads(out["surfaces.json"].read_text())
    assert [s["patch"] for s in doc["surfaces"]] == [10, 20]
    assert doc["max_c0_gap_mm"] <= 1e-9 and doc["over_tolerance"] == [] and doc["units"] == "mm"
    first = doc["surfaces"][0]
    assert first["degree"] == [3, 3] and first["neighbours"] == [20] and first["within_tolerance"]
    assert first["max_error_mm"] <= 0.032 and first["knots_u"][0] == 0.0 and first["knots_u"][-1] == 1.0
    assert doc["tolerance_mm"] == pytest.approx(0.16 / 5)  # unset: a fifth of the default scallop height
    assert doc["folded"] == [] and first["folded_fraction"] == 0.0
    # Where the largest error is, and no crease near it: a cylinder has none (JSON null, not Infinity).
    assert len(first["worst_point_mm"]) == 3 and first["worst_crease_mm"] is None
    s = surface_from_json(first)
    assert s.control_points.shape[2] == 3
    assert out["surfaces.igs"].read_bytes().count(b"     128") == 4  # two entities, two DE lines each
    step = out["surfaces.step"].read_text()
    assert step.count("=B_SPLINE_SURFACE_WITH_KNOTS('patch 10',") == step.count("=ADVANCED_FACE('patch 20',") == 1
    assert seen == sorted(seen) and seen[-1] == 1.0


def test_a_sharp_border_is_put_on_the_mesh_crease(tmp_path):
    # The roof's crease is at s = 15 mm; the quad mesh has its sharp row 0.8 mm beside it.
    ctx, MV, MF = _job(tmp_path, ridge(15.0, 0.8), blocks=[(0, 7), (7, 14)], sharp=True, shift=0.8)
    doc = json.loads(run_fit(ctx)["surfaces.json"].read_text())
    assert doc["over_tolerance"] == [] and doc["max_c0_gap_mm"] <= 1e-9
    assert max(s["max_error_mm"] for s in doc["surfaces"]) < 0.01
    # Without the sharp edges the border stays where the quads put it, and that is reported.
    doc = json.loads((tmp_path / "patches.json").read_text())
    doc["sharp_edges"] = []
    (tmp_path / "patches.json").write_text(json.dumps(doc))
    assert json.loads(run_fit(ctx)["surfaces.json"].read_text())["over_tolerance"] != []


def test_invalid_patches_are_skipped_and_reported(tmp_path):
    ctx, *_ = _job(tmp_path, cylinder(25.0), blocks=[(0, 7), (7, 14)], valid=[True, False])
    doc = json.loads(run_fit(ctx)["surfaces.json"].read_text())
    assert [s["patch"] for s in doc["surfaces"]] == [10]
    assert doc["skipped"] == [{"patch": 20, "reason": "x"}]


def test_the_default_tolerance_follows_the_scallop_height(tmp_path):
    ctx, *_ = _job(tmp_path, cylinder(25.0), blocks=[(0, 14)])
    ctx.params = _changed(ctx.params, toolpath={"scallop_height_mm": 0.05})
    doc = json.loads(run_fit(ctx)["surfaces.json"].read_text())
    assert doc["tolerance_mm"] == pytest.approx(0.01)


def test_failures_say_what_to_change(tmp_path):
    ctx, *_ = _job(tmp_path, ridge(15.0, 0.8), blocks=[(0, 14)], fit={"tolerance_mm": 0.002, "max_refinements": 1,
                                                                     "require_tolerance": True})
    with pytest.raises(StageError, match="fit.tolerance_mm") as err:
        run_fit(ctx)
    assert set(err.value.outputs) == {"surfaces.json", "surfaces.igs", "surfaces.step"}  # kept for inspection
    # The patch spans the roof's ridge: the message says the layout, not the fit, is at fault there.
    assert "1 of them ([10]) have it at a crease of the mesh" in str(err.value)
    ctx.params = _changed(ctx.params, fit={"require_tolerance": False})
    notes = []
    ctx.progress = lambda f, m=None: notes.append(m)
    doc = json.loads(run_fit(ctx)["surfaces.json"].read_text())
    assert notes[-1] == ("1 patches over tolerance: [10] (1 at a crease of the mesh their layout does not follow: "
                         "[10])")
    assert doc["over_tolerance"] == doc["at_crease"] == [10]
    doc = json.loads((tmp_path / "patches.json").read_text())
    doc["patches"][0]["faces"] = doc["patches"][0]["faces"][:-1]
    doc["patches"][0].pop("grid", None)
    (tmp_path / "patches.json").write_text(json.dumps(doc))
    # A patch that is no grid of quads is left out (plan finishes its area from the mesh); with no other
    # patch the stage ends skipped, saying why, and the job goes on.
    from worker.context import StageSkipped

    with pytest.raises(StageSkipped, match="no patch that is a grid of quads"):
        run_fit(ctx)
    (tmp_path / "quads.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(StageError, match=r"quads.obj: line 4: expected a quad \(4 corners\), got 3"):
        run_fit(ctx)


def test_cancel_stops_the_fit_between_patches(tmp_path):
    from worker.context import StageCanceled

    ctx, *_ = _job(tmp_path, cylinder(25.0), blocks=[(0, 7), (7, 14)])

    def cancel():
        raise StageCanceled()

    ctx.check_cancel = cancel
    with pytest.raises(StageCanceled):
        run_fit(ctx)
    assert not (ctx.out_dir / "surfaces.json").exists()
    # The fit itself asks too (the stage asks once before it): a cancel there stops it as well.
    calls = []

    def cancel_in_the_fit():
        calls.append(None)
        if len(calls) > 1:
            raise StageCanceled()

    ctx.check_cancel = cancel_in_the_fit
    with pytest.raises(StageCanceled):
        run_fit(ctx)
    assert len(calls) == 2 and not (ctx.out_dir / "surfaces.json").exists()


def test_samples_across_a_sharp_border_belong_to_the_face_there(tmp_path):
    # Only the first roof face is a patch; the quads of the second are in none (like a setup base).
    # The remesher put the sharp row 0.8 mm onto the second face; the fit moves the border onto the
    # crease, and the mesh between crease and row belongs to the second face, not to this patch.
    ctx, MV, MF = _job(tmp_path, ridge(15.0, 0.8), blocks=[(0, 7)], sharp=True, shift=0.8)
    doc = json.loads(run_fit(ctx)["surfaces.json"].read_text())
    assert doc["over_tolerance"] == []
    assert doc["surfaces"][0]["max_error_mm"] < 0.01


def test_an_unreadable_patches_file_is_named(tmp_path):
    ctx, *_ = _job(tmp_path, cylinder(25.0), blocks=[(0, 14)])
    (tmp_path / "patches.json").write_text("{not json")
    with pytest.raises(StageError, match="patches.json is not a readable JSON document"):
        run_fit(ctx)
    (tmp_path / "patches.json").write_text(json.dumps({"patches": [{"id": 10}]}))
    with pytest.raises(StageError, match="patches.json is not what segment writes"):
        run_fit(ctx)
