"""Tests for cam.remesh.snap: quad edges moved onto the creases of the triangle mesh."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cam.params import RemeshParams
from cam.remesh import remesh_quads
from cam.remesh.check import inspect_quad_mesh
from cam.remesh.creases import measure_crease_conformity
from cam.remesh.snap import snap_to_creases
from tests.quadshapes import quad_box, quad_grid

SIZE = np.array([40.0, 30.0, 20.0])


def _box_triangles() -> trimesh.Trimesh:
    box = trimesh.creation.box(SIZE)
    box.apply_translation(SIZE / 2)
    return box.subdivide().subdivide()


def _pushed_off_the_edges(qv: np.ndarray, push_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The box layout with every vertex on a box edge (not a corner) moved ``push_mm`` into one of its two faces
    (alternately), still on the box; and which vertices those are."""
    bound = np.isclose(qv, 0.0) | np.isclose(qv, SIZE)
    edge = np.flatnonzero(bound.sum(axis=1) == 2)
    moved = qv.copy()
    for k, v in enumerate(edge.tolist()):
        axis = np.flatnonzero(bound[v])[k % 2]  # leave this face's plane: slide into the other face
        moved[v, axis] += push_mm if np.isclose(qv[v, axis], 0.0) else -push_mm
    return moved, edge


def test_quad_edges_pushed_off_a_box_s_edges_are_put_back_on_them():
    qv, qf = quad_box((8, 6, 4), size=tuple(SIZE))
    tri = _box_triangles()
    pushed, edge = _pushed_off_the_edges(qv, 0.4)  # a tenth of a 5 mm quad; 0.2 % of the diagonal is 0.11 mm
    before = measure_crease_conformity(pushed, qf, tri.vertices, tri.faces)
    assert before.recall < 0.5 and len(before.straddling) > 0
    snapped = snap_to_creases(pushed, qf, tri.vertices, tri.faces)
    np.testing.assert_array_equal(snapped.quads, qf)  # an aligned layout needs no collapse
    after = measure_crease_conformity(snapped.vertices, qf, tri.vertices, tri.faces)
    assert after.recall == 1.0 and len(after.straddling) == 0
    # each pushed vertex is back on a box edge, exactly where the layout had it (spaced as it was along the edge)
    np.testing.assert_allclose(snapped.vertices[edge], qv[edge], atol=1e-9)
    report = snapped.report
    assert report["crease_chains"] == report["snapped_chains"] == 12 and report["not_snapped"] == []
    assert report["snapped_length_mm"] == pytest.approx(4 * SIZE.sum())
    assert report["largest_move_mm"] == pytest.approx(0.4)
    # every vertex stays on the box, and no quad folds
    d = np.minimum(np.abs(snapped.vertices), np.abs(snapped.vertices - SIZE)).min(axis=1)
    assert d.max() < 1e-9
    assert inspect_quad_mesh(snapped.vertices, qf).problems == ()


def test_a_layout_laid_diagonally_across_a_crease_collapses_quads_where_it_can_and_reports_the_rest():
    # A roof: two planes meeting at 90° along the x axis, under a quad grid turned 45° to the ridge. Every quad-edge
    # path along the ridge turns inside a quad at every other vertex; collapsing all of those quads would leave the
    # ridge's vertices with two edges, so only pieces whose collapses keep three edges everywhere are snapped.
    gv, gf = quad_grid(12, 12, size=(12.0, 12.0))
    gv -= [6.0, 6.0, 0.0]
    turn = np.array([[1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, np.sqrt(2.0)]]) / np.sqrt(2.0)
    qv = gv @ turn.T
    qv[:, 2] = -np.abs(qv[:, 1])
    tv, quads = quad_grid(36, 36, size=(18.0, 18.0))  # a grid line on y = 0: the ridge is a chain of edges
    tv -= [9.0, 9.0, 0.0]
    tv[:, 2] = -np.abs(tv[:, 1])
    tf = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    snapped = snap_to_creases(qv, gf, tv, tf)
    report = snapped.report
    # each collapse removes one quad and one vertex, and the layout stays a manifold quad mesh of one border loop
    assert report["collapsed_quads"] > 0
    assert len(gf) - len(snapped.quads) == len(qv) - len(snapped.vertices) == report["collapsed_quads"]
    check = inspect_quad_mesh(snapped.vertices, snapped.quads, expected_boundary_loops=1)
    assert check.problems == () and check.euler_characteristic == inspect_quad_mesh(qv, gf).euler_characteristic
    # every vertex is still on the roof, and the snapped pieces' length is followed by quad edges
    np.testing.assert_allclose(snapped.vertices[:, 2], -np.abs(snapped.vertices[:, 1]), atol=1e-9)
    conformity = measure_crease_conformity(snapped.vertices, snapped.quads, tv, tf)
    assert measure_crease_conformity(qv, gf, tv, tf).recall == 0.0
    assert 0.0 < report["snapped_length_mm"] / 18.0 <= conformity.recall < 1.0
    # the rest is reported piece by piece, and adds up to the ridge
    assert report["not_snapped"] and all(c["why"] == "no quad-edge path runs along it" for c in report["not_snapped"])
    assert report["snapped_length_mm"] + sum(c["length_mm"] for c in report["not_snapped"]) == pytest.approx(18.0)


def _box_pocket_fillet() -> tuple[np.ndarray, np.ndarray]:
    """A 50 × 40 × 20 box with a 30 × 20 × 8 pocket whose vertical corners are rounded 4 mm."""
    manifold3d = pytest.importorskip("manifold3d")
    pocket = manifold3d.Manifold.cube([30.0, 20.0, 10.0]).translate([10.0, 10.0, 12.0])
    rounded = manifold3d.Manifold.hull(manifold3d.Manifold.batch_hull([
        manifold3d.Manifold.cylinder(10.0, 4.0, circular_segments=48).translate([x, y, 12.0])
        for x in (14.0, 36.0) for y in (14.0, 26.0)]))
    solid = manifold3d.Manifold.cube([50.0, 40.0, 20.0]) - (pocket ^ rounded)
    mesh = solid.to_mesh()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def test_remesh_snaps_its_layout_onto_a_pocketed_part_s_creases():
    tv, tf = _box_pocket_fillet()
    result = remesh_quads(tv, tf, RemeshParams(target_faces=1200, seed=0, timeout_s=120, snap_creases=True))
    report, snap = result.report, result.report["snap"]
    # measured again on the returned layout: the report's recall and straddling quads are the snapped layout's
    conformity = measure_crease_conformity(result.vertices, result.faces, tv, tf)
    assert report["crease_recall"] == conformity.recall and report["straddling_quads"] == len(conformity.straddling)
    assert conformity.recall > snap["crease_recall_before"]
    assert len(conformity.straddling) < snap["straddling_quads_before"]
    # what was not snapped is reported, piece by piece, with a reason
    unsnapped = snap["crease_chain_length_mm"] - snap["snapped_length_mm"]
    assert unsnapped == pytest.approx(sum(c["length_mm"] for c in snap["not_snapped"]), abs=1e-2)
    assert all(c["why"] for c in snap["not_snapped"])
    # the check and counts are the returned layout's, collapsed quads and all
    check = inspect_quad_mesh(result.vertices, result.faces)
    assert check.problems == () and report["check"] == check.as_dict()
    assert report["faces"] == len(result.faces) and report["vertices"] == len(result.vertices)
    assert report["hausdorff_ratio"] < RemeshParams().max_hausdorff_ratio


def test_bad_input_names_what_it_saw():
    qv, qf = quad_box((2, 2, 2))
    tri = _box_triangles()
    with pytest.raises(ValueError, match=r"quad vertices \(n, 3\) and integer quads"):
        snap_to_creases(qv[:, :2], qf, tri.vertices, tri.faces)
    with pytest.raises(ValueError, match="quads index vertices"):
        snap_to_creases(qv, qf + 100, tri.vertices, tri.faces)
    with pytest.raises(ValueError, match="gentle_angle_deg"):
        snap_to_creases(qv, qf, tri.vertices, tri.faces, crease_angle_deg=30.0, gentle_angle_deg=40.0)


def _states(path: list[int], turned_at: set[int]) -> tuple[tuple[int, int, bool], dict]:
    """The search's last state and parent links for a path, turning (a collapse) at the path positions given."""
    states = [(-1, path[0], False)] + [(path[k - 1], path[k], k - 1 in turned_at) for k in range(1, len(path))]
    return states[-1], dict(zip(states[1:], states[:-1], strict=True))


def test_a_path_s_collapses_are_read_back_at_their_positions_and_a_path_that_passes_a_vertex_twice_has_none():
    from cam.remesh import snap

    gv, gf = quad_grid(3, 3)  # vertex (i, j) is 4 i + j; quad 4 is [5, 9, 10, 6]
    layout = snap._Layout(gv, gf)
    # 8, 9, 10, 6, 2 turns inside quad 4 at 10: its fourth corner 5 merges into 10
    assert snap._walk_back(layout, *_states([8, 9, 10, 6, 2], {2})) == ([8, 9, 10, 6, 2], [(4, 10, 5)])
    # the same turn on a path that comes back through 10 (straight on, 11, 10, 9) is refused
    assert snap._walk_back(layout, *_states([8, 9, 10, 6, 7, 11, 10, 9, 13], {2})) is None
    # without a collapse a path is read back as it runs
    assert snap._walk_back(layout, *_states([8, 9, 10, 11], set())) == ([8, 9, 10, 11], [])
