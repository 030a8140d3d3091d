"""Segmentation into sharp height fields: base, sharp edges, traces, graph, clipping, patches, the stage."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError

from cam import GeometryError
from cam.io.quads import read_quad_obj, write_quad_obj
from cam.mesh.quads import face_normals, quad_topology
from cam.params import RemeshParams, SegmentParams
from cam.segment import segment_quads
from cam.segment.clip import CutState, complete_cuts, patch_labels
from cam.segment.graph import kruskal
from cam.segment.patches import grid_of_patch
from cam.segment.traces import straight_continuation, trace_line
from core.params import JobParams
from tests.conftest import SHARED_DATA
from tests.quadshapes import quad_box, quad_capped_cylinder, quad_grid, quad_torus


def check_partition(v, f, seg):
    """What every segmentation must satisfy; returns the number of patches."""
    topo = quad_topology(f, len(v))
    assert seg.ok, [p.problems for p in seg.invalid]
    domain = np.flatnonzero(seg.labels >= 0)
    covered = np.concatenate([p.faces for p in seg.patches])
    assert np.array_equal(np.sort(covered), domain)  # patches partition the domain
    for p in seg.patches:
        assert p.rows * p.cols == len(p.faces) and len(p.corners) == 4
        assert np.array_equal(np.sort(p.face_grid.reshape(-1)), np.sort(p.faces))
        g = p.grid
        for r in range(p.rows):
            for c in range(p.cols):
                assert set(f[p.face_grid[r, c]].tolist()) == {g[r, c], g[r, c + 1], g[r + 1, c], g[r + 1, c + 1]}
        inner = g[1:-1, 1:-1].reshape(-1)
        assert (topo.valence[inner] == 4).all()  # no extraordinary point inside
        assert (seg.labels[p.faces] == p.id).all()
    # Every sharp edge between two machined faces separates two patches (or a patch from itself along a seam).
    edge_key = {tuple(e) for e in np.sort(seg.cut_edges, axis=1).tolist()}
    for a, b in np.sort(seg.sharp_edges, axis=1).tolist():
        faces = topo.edge_faces[np.flatnonzero((topo.edges[:, 0] == a) & (topo.edges[:, 1] == b))[0]]
        if (seg.labels[faces] >= 0).all():
            assert (a, b) in edge_key
    return len(seg.patches)


# --- whole segmentations ------------------------------------------------------------------------------------

def test_box_segments_into_its_faces_and_rests_on_its_largest_face():
    v, f = quad_box((4, 3, 2), size=(40.0, 30.0, 20.0))
    seg = segment_quads(v, f)
    assert check_partition(v, f, seg) == 5
    # The base is the 40 x 30 face at z = 0 (tied with the top; -z wins), the tool axis is +z.
    assert len(seg.base_faces) == 12 and np.allclose(v[f[seg.base_faces]][..., 2], 0.0)
    assert np.allclose(seg.base.tool_axis, [0, 0, 1])
    assert sorted((p.rows * p.cols) for p in seg.patches) == [6, 6, 8, 8, 12]
    machine = v @ seg.base.rotation.T + seg.base.translation
    assert machine[:, 2].min() == pytest.approx(0.0) and np.allclose(machine.min(0)[:2], -machine.max(0)[:2])
    assert all(any(p.sharp_sides) for p in seg.patches)


def test_box_standing_on_its_side_takes_that_side_as_base():
    v, f = quad_box((1, 4, 2), size=(10.0, 40.0, 20.0))
    seg = segment_quads(v, f)
    check_partition(v, f, seg)
    normals = face_normals(v, f)[seg.base_faces]
    assert np.allclose(np.abs(normals[:, 0]), 1.0)  # one of the two 40 x 20 sides
    assert abs(seg.base.tool_axis[0]) == pytest.approx(1.0)


def test_box_without_base_removal_has_six_patches():
    v, f = quad_box((2, 2, 3), size=(10.0, 10.0, 30.0))
    seg = segment_quads(v, f, SegmentParams(remove_base=False))
    assert check_partition(v, f, seg) == 6 and len(seg.base_faces) == 0


@pytest.mark.parametrize("remove_base", [True, False])
def test_capped_cylinder_segments_with_its_rims_on_boundaries(remove_base):
    v, f = quad_capped_cylinder(2, 2, 4, radius=20.0, height=10.0)
    seg = segment_quads(v, f, SegmentParams(remove_base=remove_base))
    check_partition(v, f, seg)
    assert seg.stats["sharp_edges"] == 2 * 8  # the two rims
    assert seg.stats["cylinder_cuts"] >= 1  # the side band was cut open
    side = [p for p in seg.patches if np.allclose(np.abs(face_normals(v, f)[p.faces][:, 2]), 0.0)]
    assert side and all(p.rows * p.cols == len(p.faces) for p in side)
    if remove_base:
        assert np.allclose(v[f[seg.base_faces]][..., 2], 0.0) and np.allclose(seg.base.tool_axis, [0, 0, 1])


def test_torus_traces_terminate_and_the_torus_segments():
    v, f = quad_torus(12, 8)
    topo = quad_topology(f, len(v))
    straight = straight_continuation(topo)
    for h in range(0, 4 * len(f), 5):
        t = trace_line(topo, straight, h, stop=lambda g: False)
        assert t.reason == "self" and t.end == t.vertices[0] and len(t.half_edges) in (8, 12)
    capped = trace_line(topo, straight, 0, stop=lambda g: False, max_steps=3)
    assert capped.reason == "steps" and len(capped.half_edges) == 3
    for remove_base in (True, False):
        seg = segment_quads(v, f, SegmentParams(remove_base=remove_base))
        check_partition(v, f, seg)


def test_methods_agree_on_validity_and_the_baseline_cuts_more():
    v, f = quad_capped_cylinder(3, 2, 4, radius=20.0, height=30.0)
    counts = {}
    for method in ("mst", "greedy", "motorcycle"):
        seg = segment_quads(v, f, SegmentParams(method=method, remove_base=False))
        counts[method] = len(seg.patches)
        assert seg.stats["sharp_on_boundary"] == seg.stats["sharp_in_domain"]
    assert counts["mst"] <= counts["motorcycle"]


def test_bad_inputs_are_named():
    v, f = quad_box((1, 1, 1))
    # The group is validated once, when it is made: segment_quads and its steps do not check its values again.
    with pytest.raises(ValidationError, match="method"):
        SegmentParams(method="magic")
    for bad in ({"sharp_angle_deg": 0.0}, {"min_sharp_fragment_edges": -1}, {"base_clusters": 0}, {"mu": -0.1},
                {"gamma": -0.1}, {"sc": 0.0}, {"nc": 0.0}, {"ac": 0.0}):
        with pytest.raises(ValidationError, match=next(iter(bad))):
            SegmentParams(**bad)
    with pytest.raises(ValueError, match="faces must be a non-empty"):
        segment_quads(v, f[:, :3])
    # What the user can act on (the mesh, the parameters) is a GeometryError; array shapes stay ValueError.
    with pytest.raises(GeometryError, match="inconsistently oriented"):
        segment_quads(v, np.vstack([f[:1], f[1:, ::-1]]))
    with pytest.raises(ValueError, match="index vertices") as info:
        segment_quads(v, f + 1)
    assert not isinstance(info.value, GeometryError)
    g, q = quad_grid(3, 3)
    with pytest.raises(GeometryError, match="removing the base leaves no faces"):
        segment_quads(g, q)


# --- the pieces -----------------------------------------------------------------------------------------------

def test_kruskal_builds_a_minimum_spanning_forest():
    edges = [(4.0, 0, 1), (1.0, 1, 2), (2.0, 0, 2), (7.0, 3, 4), (0.5, 2, 0)]
    assert sorted(kruskal(5, edges)) == [1, 3, 4]


def test_a_loose_clipping_line_is_extended_straight_to_the_boundary():
    v, f = quad_grid(6, 4)
    topo = quad_topology(f, len(v))
    cut = np.zeros(len(topo.edges), dtype=bool)
    # One edge sticking into the grid from the bottom boundary at x = 3.
    target = np.flatnonzero((v[topo.edges[:, 0], 0] == 3 * 1 / 6) & (v[topo.edges[:, 1], 0] == 3 / 6)
                            & (np.minimum(v[topo.edges[:, 0], 1], v[topo.edges[:, 1], 1]) == 0))
    cut[target] = True
    state = CutState(topo, straight_continuation(topo), v, cut)
    assert complete_cuts(state) == 1
    added = topo.edges[state.cut & ~topo.boundary_edge]
    assert np.allclose(v[added.reshape(-1), 0], 0.5) and len(added) == 4  # straight across to the top
    labels = patch_labels(topo, state.cut)
    assert labels.max() == 1


def test_grid_check_names_an_l_shape():
    v, f = quad_grid(2, 2)
    topo = quad_topology(f, len(v))
    faces = np.array([0, 1, 2])  # three of the four quads: an L
    inside = np.zeros(len(f), dtype=bool)
    inside[faces] = True
    ef = topo.edge_faces
    cut = topo.boundary_edge | (inside[ef[:, 0]] != inside[np.maximum(ef[:, 1], 0)])
    result = grid_of_patch(topo, cut, np.zeros(len(topo.edges), dtype=bool), faces)
    assert not result.valid and "not a rectangle" in result.problems[0] or "covers" in result.problems[0]
    whole = grid_of_patch(topo, topo.boundary_edge, np.zeros(len(topo.edges), dtype=bool), np.arange(4))
    assert whole.valid and (whole.rows, whole.cols) == (2, 2) and len(set(whole.corners)) == 4


# --- the stage ------------------------------------------------------------------------------------------------

def _ctx(tmp_path, v, f, params, **callbacks):
    from worker.context import StageContext

    src = write_quad_obj(tmp_path / "quads.obj", v, f)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    return StageContext(job_id="j", stage="segment", inputs={"quads.obj": src}, out_dir=out_dir,
                        params=JobParams.model_validate({"segment": params}), settings={}, **callbacks)


def test_segment_stage_writes_the_design_fields(tmp_path):
    from worker.stages.segment import run_segment

    v, f = quad_box((4, 3, 2), size=(40.0, 30.0, 20.0))
    out = run_segment(_ctx(tmp_path, v, f, {"sharp_angle_deg": 50.0}))
    assert set(out) == {"patches.json", "segments.ply", "setup.json"}
    doc = json.loads(out["patches.json"].read_text())
    assert len(doc["patches"]) == 5 and len(doc["base_faces"]) == 12 and len(doc["sharp_edges"]) == 36
    assert doc["params"] == SegmentParams(sharp_angle_deg=50.0).model_dump(mode="json")
    for p in doc["patches"]:
        assert {"id", "faces", "rows", "cols", "corners", "sharp_boundary"} <= set(p)
        assert len(p["corners"]) == 4 and p["rows"] * p["cols"] == len(p["faces"]) and p["sharp_boundary"]
        assert len(p["boundary"]) == 4 and p["neighbors"]
    setup = json.loads(out["setup.json"].read_text())
    s = setup["setups"][0]
    assert s["program"] == "program.nc" and sorted(s["patches"]) == [0, 1, 2, 3, 4] and s["unmachined"] == []
    assert np.allclose(np.asarray(s["rotation"]), np.eye(3)) and len(s["translation"]) == 3
    header = out["segments.ply"].read_bytes().split(b"end_header")[0]
    assert b"element face 52" in header and b"property uchar red" in header


def test_failed_segmentation_still_writes_segments_ply(tmp_path):
    # No patch is a sharp height field: the stage ends skipped (plan finishes the part from the mesh) and
    # keeps segments.ply and patches.json for inspection.
    from worker.context import StageSkipped
    from worker.stages.segment import run_segment

    v, f = quad_torus(12, 8)
    with pytest.raises(StageSkipped) as info:
        run_segment(_ctx(tmp_path, v, f, {"method": "motorcycle", "remove_base": False}))
    assert "not sharp height fields" in str(info.value) and "patch 0" in str(info.value)
    assert set(info.value.outputs) == {"segments.ply", "patches.json"}
    assert info.value.outputs["segments.ply"].exists()
    doc = json.loads(info.value.outputs["patches.json"].read_text())
    assert not doc["patches"][0]["valid"] and doc["patches"][0]["problems"]


def test_segment_stage_reports_unreadable_input(tmp_path):
    from worker.context import StageContext, StageError
    from worker.stages.segment import run_segment

    (tmp_path / "quads.obj").write_text("v 0 0 0\nf 1 1 1\n")
    ctx = StageContext(job_id="j", stage="segment", inputs={"quads.obj": tmp_path / "quads.obj"}, out_dir=tmp_path,
                       params=JobParams(), settings={})
    with pytest.raises(StageError, match="could not read quads.obj"):
        run_segment(ctx)


def test_segment_stage_names_the_file_it_cannot_segment(tmp_path):
    from worker.context import StageSkipped
    from worker.stages.segment import run_segment

    g, q = quad_grid(3, 3)
    with pytest.raises(StageSkipped, match=r"^cannot segment quads.obj \(removing the base leaves no faces to machine; "
                                           r"set segment.remove_base to false\); plan finishes the part from mesh.ply "
                                           "without patch passes$"):
        run_segment(_ctx(tmp_path, g, q, {}))


def test_segment_stage_lets_the_cancel_through(tmp_path):
    from worker.context import StageCanceled
    from worker.stages.segment import run_segment

    def canceled():
        raise StageCanceled

    v, f = quad_box((4, 3, 2), size=(40.0, 30.0, 20.0))
    with pytest.raises(StageCanceled):
        run_segment(_ctx(tmp_path, v, f, {}, check_cancel=canceled))
    assert not (tmp_path / "out" / "patches.json").exists()


# --- parts that need QuadriFlow -------------------------------------------------------------------------------

def _quadriflow(vertices, triangles, target):
    pytest.importorskip("pyQuadriFlow")
    from cam.remesh.quadriflow import remesh_quads

    result = remesh_quads(vertices, triangles, RemeshParams(target_faces=target, seed=0, timeout_s=120))
    return result.vertices, result.faces


def test_csg_part_segments_into_valid_patches():
    manifold3d = pytest.importorskip("manifold3d")
    block = manifold3d.Manifold.cube([60.0, 40.0, 20.0])
    boss = manifold3d.Manifold.cube([20.0, 20.0, 12.0]).translate([10.0, 10.0, 20.0])
    hole = manifold3d.Manifold.cylinder(40.0, 7.0, 7.0, 32).translate([42.0, 20.0, -10.0])
    mesh = ((block + boss) - hole).to_mesh()
    v, f = _quadriflow(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), 900)
    seg = segment_quads(v, f)
    check_partition(v, f, seg)
    assert seg.stats["sharp_in_domain"] > 50
    assert np.allclose(seg.base.tool_axis, [0, 0, 1], atol=1e-3)  # rests on its 60 x 40 bottom


@pytest.mark.skipif(not (SHARED_DATA / "fandisk_gt.obj").exists(), reason="../shared/data is absent")
def test_fandisk_segments_into_valid_patches():
    import trimesh

    mesh = trimesh.load(SHARED_DATA / "fandisk_gt.obj", process=False)
    v, f = _quadriflow(mesh.vertices * 10, mesh.faces, 1500)
    mst = segment_quads(v, f)
    check_partition(v, f, mst)
    baseline = segment_quads(v, f, SegmentParams(method="motorcycle"))
    assert len(mst.patches) < len(baseline.patches)


def test_read_back_of_what_the_stage_reads(tmp_path):
    v, f = quad_box((1, 1, 1))
    _v2, f2 = read_quad_obj(write_quad_obj(tmp_path / "q.obj", v, f))
    assert np.array_equal(f2, f)
