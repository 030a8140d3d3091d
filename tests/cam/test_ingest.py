"""The ingest core: what is dropped, counted and refused."""

from __future__ import annotations

import json
from typing import get_args

import numpy as np
import pydantic
import pytest
import trimesh

from cam import GeometryError
from cam.ingest.clean import MM_PER_UNIT, IngestError, clean_cloud, clean_mesh
from cam.params import IngestParams

RNG = np.random.default_rng(11)


def _cloud(points, normals=None, units="mm", **options):
    settings = {"min_points": 1, "max_points": 10_000} | options
    return clean_cloud(points, normals, IngestParams(units=units), **settings)


def _reasons(report):
    return {d["reason"]: d["count"] for d in report["dropped"]}


def test_nan_and_inf_rows_are_dropped_and_counted():
    points = RNG.normal(size=(100, 3))
    points[[3, 50]] = np.nan
    points[70, 1] = np.inf
    result = _cloud(points, format="xyz")
    assert len(result.points) == 97 and np.isfinite(result.points).all()
    assert np.array_equal(result.points, np.delete(points, [3, 50, 70], axis=0))
    report = result.report
    assert report["counts"] == {"read": 100, "kept": 97}
    assert report["dropped"] == [{"reason": "non-finite coordinates", "count": 3, "of": "points"}]
    assert report["kind"] == "cloud" and report["format"] == "xyz" and report["units"] == "mm"
    json.dumps(report)  # ingest.json must serialise


def test_all_non_finite_is_an_error():
    with pytest.raises(IngestError, match="all 5 points have non-finite coordinates"):
        _cloud(np.full((5, 3), np.nan))


def test_too_few_points_names_the_numbers():
    points = np.vstack([RNG.normal(size=(40, 3)), np.full((10, 3), np.nan)])
    with pytest.raises(IngestError) as info:
        _cloud(points, min_points=100)
    message = str(info.value)
    assert "only 40 usable points remain of 50 read" in message
    assert "10 non-finite coordinates" in message and "at least 100" in message


def test_too_many_points_names_the_limit():
    with pytest.raises(IngestError, match="2000 points remain of 2000 read, more than the limit of 1000"):
        _cloud(RNG.normal(size=(2000, 3)), max_points=1000)


def test_inch_scaling_is_exact():
    points = RNG.normal(size=(200, 3))
    result = _cloud(points, units="inch")
    assert np.array_equal(result.points, points * 25.4)
    assert result.report["units"] == "inch" and result.report["scale_to_mm"] == 25.4
    bbox = result.report["bbox_mm"]
    assert bbox["min"] == (points * 25.4).min(axis=0).tolist()
    assert np.isclose(bbox["diagonal"], np.linalg.norm(np.subtract(bbox["max"], bbox["min"])))


def test_unknown_units_are_refused_and_every_known_unit_has_a_scale():
    # The scale is derived from IngestParams.units, so a bad scale can no longer reach clean_cloud.
    with pytest.raises(pydantic.ValidationError, match="units"):
        IngestParams(units="furlong")
    assert set(MM_PER_UNIT) == set(get_args(IngestParams.model_fields["units"].annotation))


def test_user_errors_are_geometry_errors():
    assert issubclass(IngestError, GeometryError)


def test_exact_duplicates_are_removed_keeping_the_first():
    points = np.array([[0.0, 0, 0], [1, 2, 3], [1, 2, 3], [-0.0, 0, 0], [4, 5, 6]])
    normals = np.array([[0, 0, 2.0], [0, 1, 0], [1, 0, 0], [0, 0, 1], [3, 0, 0]])
    result = _cloud(points, normals)
    assert np.array_equal(result.points, [[0, 0, 0], [1, 2, 3], [4, 5, 6]])
    assert np.array_equal(result.normals, [[0, 0, 1], [0, 1, 0], [1, 0, 0]])
    assert _reasons(result.report) == {"exact duplicate points": 2}
    assert result.report["has_normals"] and result.report["normals_note"] is None


def test_any_bad_normal_discards_all_normals_with_a_note():
    points = RNG.normal(size=(10, 3))
    normals = RNG.normal(size=(10, 3))
    normals[4] = 0.0
    result = _cloud(points, normals)
    assert result.normals is None and not result.report["has_normals"]
    assert "1 of 10 points" in result.report["normals_note"]
    assert len(result.points) == 10


def test_bad_normal_on_a_dropped_row_does_not_matter():
    points = RNG.normal(size=(10, 3))
    normals = RNG.normal(size=(10, 3))
    points[2] = np.nan
    normals[2] = np.nan
    result = _cloud(points, normals)
    assert result.normals is not None
    assert np.allclose(np.linalg.norm(result.normals, axis=1), 1.0)


def test_normals_shape_must_match():
    # A reader hands over one normal per point, so a mismatch is a caller's bug, not the user's.
    with pytest.raises(ValueError, match="2 normals for 3 points") as info:
        _cloud(np.zeros((3, 3)), np.ones((2, 3)))
    assert not isinstance(info.value, GeometryError)


def _mesh(vertices, faces, units="mm", **options):
    settings = {"max_points": 10_000} | options
    return clean_mesh(vertices, faces, IngestParams(units=units), **settings)


def test_clean_box_is_untouched():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    result = _mesh(box.vertices, box.faces, format="stl_binary")
    assert result.report["dropped"] == [] and result.report["kind"] == "mesh"
    assert result.report["counts"] == {"read": 8, "kept": 8, "faces_read": 12, "faces_kept": 12}
    assert trimesh.Trimesh(result.vertices, result.faces, process=False).is_watertight
    json.dumps(result.report)


def test_mesh_degenerate_and_broken_faces_are_dropped():
    box = trimesh.creation.box()
    # 8: a NaN vertex, 9: a stray vertex no face uses, 10: a bit-identical copy of vertex 0.
    vertices = np.vstack([box.vertices, [[np.nan, 0, 0], [9, 9, 9]], box.vertices[:1]])
    faces = np.vstack([
        box.faces,
        [[0, 0, 1], [1, 2, 2]],    # repeated vertex
        [[0, 1, 8]],               # touches the NaN vertex
        [[0, 10, 1]],              # repeated vertex once 10 is merged into 0
        box.faces[:1, ::-1],       # the first face again, reversed
    ])  # fmt: skip
    result = _mesh(vertices, faces)
    assert _reasons(result.report) == {
        "non-finite vertex coordinates": 1,
        "faces with non-finite vertices": 1,
        "exact duplicate vertices merged": 1,
        "degenerate faces (repeated vertex)": 3,
        "duplicate faces": 1,
        "unreferenced vertices": 1,
    }
    assert result.report["counts"] == {"read": 11, "kept": 8, "faces_read": 17, "faces_kept": 12}
    assert trimesh.Trimesh(result.vertices, result.faces, process=False).is_watertight


def test_mesh_zero_area_faces_are_dropped():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]])
    faces = np.array([[0, 1, 3], [0, 1, 2]])
    result = _mesh(vertices, faces, units="inch")
    assert _reasons(result.report) == {"degenerate faces (zero area)": 1, "unreferenced vertices": 1}
    assert np.array_equal(result.vertices, vertices[[0, 1, 3]] * 25.4)
    assert np.array_equal(result.faces, [[0, 1, 2]])


def test_mesh_with_no_usable_face_is_an_error():
    with pytest.raises(IngestError, match="no usable face remains of 2 read"):
        _mesh(np.zeros((3, 3)), np.array([[0, 1, 2], [0, 0, 1]]))


def test_mesh_limits_and_bad_indices():
    box = trimesh.creation.box()
    with pytest.raises(IngestError, match="8 vertices, more than the limit of 5"):
        _mesh(box.vertices, box.faces, max_points=5)
    with pytest.raises(IngestError, match="mesh has 8 vertices"):
        _mesh(box.vertices, box.faces + 1)


@pytest.mark.parametrize("collide", [False, True])
def test_duplicate_detection_is_exact_even_when_hashes_collide(monkeypatch, collide):
    import cam.mesh.rows

    if collide:
        monkeypatch.setattr(cam.mesh.rows, "_row_hash", lambda bits: np.zeros(len(bits), dtype=np.uint64))
    points = RNG.integers(-3, 4, size=(3000, 3)).astype(np.float64)
    result = _cloud(points)
    _, first = np.unique(points, axis=0, return_index=True)
    assert np.array_equal(result.points, points[np.sort(first)])
    assert _reasons(result.report) == {"exact duplicate points": 3000 - len(first)}
