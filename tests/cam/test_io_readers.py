"""Readers and writers: every input is built in the test, so each case is explicit."""

from __future__ import annotations

import os
import struct
import time

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from cam.io import (
    ReadError,
    WriteError,
    atomic_write,
    read_input,
    read_obj,
    read_pcd,
    read_ply,
    read_stl,
    read_xyz,
    write_ply_mesh,
    write_ply_points,
)

RNG = np.random.default_rng(20240501)


# ---------------------------------------------------------------- PLY builders

_CODES = {"float": "f4", "double": "f8", "uchar": "u1", "int": "i4", "uint8": "u1",
          "int32": "i4", "float32": "f4", "float64": "f8", "short": "i2", "uint": "u4"}  # fmt: skip


def _ply_bytes(fmt, vertex_props, vertex_columns, faces=None, face_types=("uchar", "int"),
               face_name="vertex_indices", edges=None, comments=("made in a test",)):  # fmt: skip
    """Build a PLY file: vertex properties [(type, name)], columns (n, k) values,
    faces as a list of index lists (a texcoord list follows them), edges (e, 2) int."""
    n = len(vertex_columns)
    lines = ["ply", f"format {fmt} 1.0"] + [f"comment {c}" for c in comments]
    lines.append(f"element vertex {n}")
    lines += [f"property {t} {name}" for t, name in vertex_props]
    if faces is not None:
        lines += [f"element face {len(faces)}",
                  f"property list {face_types[0]} {face_types[1]} {face_name}",
                  "property list uchar float texcoord", "property uchar flags"]  # fmt: skip
    if edges is not None:
        lines += [f"element edge {len(edges)}", "property int vertex1", "property int vertex2"]
    lines.append("end_header")
    head = ("\n".join(lines) + "\n").encode()
    if fmt == "ascii":
        types = [t for t, _ in vertex_props]
        rows = [" ".join(map(_fmt, row, types)) for row in vertex_columns]
        for face in faces or ():
            rows.append(f"{len(face)} {' '.join(map(str, face))} 2 0.5 0.25 7")
        rows += [f"{a} {b}" for a, b in (edges if edges is not None else ())]
        return head + ("\n".join(rows) + "\n").encode()
    e = "<" if fmt == "binary_little_endian" else ">"
    record = np.dtype([(f"p{i}", e + _CODES[t]) for i, (t, _) in enumerate(vertex_props)])
    table = np.empty(n, dtype=record)
    for i in range(len(vertex_props)):
        table[f"p{i}"] = vertex_columns[:, i]
    body = [table.tobytes()]
    for face in faces or ():
        body.append(np.array([len(face)], e + _CODES[face_types[0]]).tobytes())
        body.append(np.array(face, e + _CODES[face_types[1]]).tobytes())
        body.append(b"\x02" + np.array([0.5, 0.25], e + "f4").tobytes() + b"\x07")
    if edges is not None:
        body.append(np.asarray(edges, e + "i4").tobytes())
    return head + b"".join(body)


def _fmt(value, ply_type):
    if ply_type in ("float", "float32"):
        return repr(float(np.float32(value)))
    if ply_type in ("double", "float64"):
        return repr(float(value))
    return str(int(value))


def _write(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    return path


RICH_PROPS = [("float", "x"), ("float", "y"), ("float", "z"), ("float", "nx"), ("float", "ny"),
              ("float", "nz"), ("uchar", "red"), ("uchar", "green"), ("uchar", "blue"),
              ("uchar", "alpha"), ("float", "intensity")]  # fmt: skip


def _rich_columns(n):
    xyz = RNG.normal(size=(n, 3)) * 50
    nrm = RNG.normal(size=(n, 3))
    rgba = RNG.integers(0, 256, size=(n, 4))
    intensity = RNG.random((n, 1))
    return np.hstack([xyz, nrm, rgba, intensity])


# ---------------------------------------------------------------- PLY

def test_ply_points_round_trip(tmp_path):
    points = RNG.normal(size=(1000, 3)) * 123.456
    normals = RNG.normal(size=(1000, 3))
    path = tmp_path / "cloud.ply"
    write_ply_points(path, points, normals)
    data = read_input(path)
    assert data.format == "ply" and data.faces is None
    assert data.points.dtype == np.float64 and np.array_equal(data.points, points)
    # Normals are stored as float32 on purpose (directions need no more).
    assert np.array_equal(data.normals, normals.astype(np.float32).astype(np.float64))


def test_ply_mesh_round_trip(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=17.0)
    path = tmp_path / "mesh.ply"
    write_ply_mesh(path, mesh.vertices, mesh.faces, comments=["units mm"])
    data = read_ply(path)
    assert np.array_equal(data.points, mesh.vertices)
    assert data.faces.dtype == np.int64 and np.array_equal(data.faces, mesh.faces)
    assert data.comments == ("units mm",)
    assert trimesh.Trimesh(data.points, data.faces, process=False).is_watertight


def test_writes_leave_no_temporary_files_and_replace_in_place(tmp_path):
    path = tmp_path / "cloud.ply"
    assert write_ply_points(str(path), np.zeros((1, 3))) == path
    assert write_ply_mesh(path, np.eye(3), np.array([[0, 1, 2]])) == path
    write_ply_points(path, np.ones((2, 3)))
    assert os.listdir(tmp_path) == ["cloud.ply"]
    assert len(read_ply(path).points) == 2


def test_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "artifact.bin"
    path.write_bytes(b"old")

    def chunks():
        yield b"new and half"
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(path, chunks())
    assert path.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["artifact.bin"]


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda p: write_ply_points(p, np.zeros((3, 2))), "(n, 3)"),
        (lambda p: write_ply_points(p, np.array([[0, 0, np.nan]])), "NaN"),
        (lambda p: write_ply_points(p, np.zeros((3, 3)), np.zeros((2, 3))), "one normal per point"),
        (lambda p: write_ply_mesh(p, np.zeros((3, 3)), np.array([[0, 1, 3]])), "3 vertices"),
        (lambda p: write_ply_mesh(p, np.zeros((3, 3)), np.array([[0.0, 1, 2]])), "integer"),
    ],
)
def test_writers_reject_bad_arrays(tmp_path, call, message):
    with pytest.raises(WriteError, match=message.replace("(", r"\(").replace(")", r"\)")):
        call(tmp_path / "x.ply")
    assert not any(tmp_path.iterdir())


def test_ply_encodings_with_extra_properties_and_elements_agree(tmp_path):
    columns = _rich_columns(50)
    faces = [[0, 1, 2], [2, 3, 4, 5], [6, 7, 8], [9, 10, 11, 12, 13]]  # mixed: scan path
    edges = np.array([[0, 1], [1, 2], [2, 0]])
    results = []
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        data = _ply_bytes(fmt, RICH_PROPS, columns, faces=faces, edges=edges)
        results.append(read_ply(_write(tmp_path, f"{fmt}.ply", data)))
    expected_faces = np.array([[0, 1, 2], [2, 3, 4], [2, 4, 5], [6, 7, 8],
                               [9, 10, 11], [9, 11, 12], [9, 12, 13]])  # fmt: skip
    for result in results:
        assert np.array_equal(result.points, columns[:, :3].astype(np.float32))
        assert np.array_equal(result.normals, columns[:, 3:6].astype(np.float32))
        assert np.array_equal(result.colors, columns[:, 6:9].astype(np.uint8))
        assert np.array_equal(result.faces, expected_faces)
        assert result.comments == ("made in a test",)


def test_ply_fixed_size_faces_with_sized_type_aliases(tmp_path):
    props = [("float64", "x"), ("float64", "y"), ("float64", "z")]
    columns = RNG.normal(size=(30, 3))
    faces = RNG.integers(0, 30, size=(40, 4)).tolist()
    for fmt in ("ascii", "binary_big_endian"):
        data = _ply_bytes(fmt, props, columns, faces=faces, face_types=("uint8", "int32"),
                          face_name="vertex_index")  # fmt: skip
        result = read_ply(_write(tmp_path, "q.ply", data))
        quads = np.array(faces)
        assert np.array_equal(result.faces[0::2], quads[:, [0, 1, 2]])
        assert np.array_equal(result.faces[1::2], quads[:, [0, 2, 3]])
        assert np.array_equal(result.points, columns)


def test_ply_big_endian_doubles_are_exact(tmp_path):
    columns = RNG.normal(size=(100, 3)) * 1e3
    props = [("double", "x"), ("double", "y"), ("double", "z")]
    result = read_ply(_write(tmp_path, "be.ply", _ply_bytes("binary_big_endian", props, columns)))
    assert np.array_equal(result.points, columns)
    assert result.normals is None and result.colors is None and result.faces is None


def test_ply_truncated_binary(tmp_path):
    props = [("double", "x"), ("double", "y"), ("double", "z")]
    data = _ply_bytes("binary_little_endian", props, RNG.normal(size=(5000, 3)))
    path = _write(tmp_path, "cut.ply", data[: len(data) - 24 * 3800])
    with pytest.raises(ReadError, match=r"binary PLY ends after 1200 of 5000 vertices \(file truncated\?\)"):
        read_ply(path)


def test_ply_truncated_faces(tmp_path):
    props = [("float", "x"), ("float", "y"), ("float", "z")]
    data = _ply_bytes("binary_little_endian", props, RNG.normal(size=(10, 3)), faces=[[0, 1, 2]] * 8)
    with pytest.raises(ReadError, match="of 8 faces"):
        read_ply(_write(tmp_path, "cut.ply", data[:-20]))


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_ply_header_claims_more_vertices(tmp_path, fmt):
    props = [("float", "x"), ("float", "y"), ("float", "z")]
    data = _ply_bytes(fmt, props, RNG.normal(size=(10, 3))).replace(b"vertex 10", b"vertex 25")
    with pytest.raises(ReadError, match="25") as info:
        read_ply(_write(tmp_path, "short.ply", data))
    assert "10" in str(info.value)


def test_ply_face_index_out_of_range(tmp_path):
    props = [("float", "x"), ("float", "y"), ("float", "z")]
    data = _ply_bytes("binary_little_endian", props, np.zeros((4, 3)), faces=[[0, 1, 2], [1, 2, 9]])
    with pytest.raises(ReadError, match="face 1 uses vertex index 9"):
        read_ply(_write(tmp_path, "bad.ply", data))


def test_ply_non_numeric_ascii_token_names_the_line(tmp_path):
    props = [("float", "x"), ("float", "y"), ("float", "z")]
    data = _ply_bytes("ascii", props, np.arange(12.0).reshape(4, 3), comments=())
    data = data.replace(b"4.0", b"four")  # second vertex, line 9 of the file
    with pytest.raises(ReadError, match=r"line 9 holds 'four'"):
        read_ply(_write(tmp_path, "bad.ply", data))


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"PLY\nformat ascii 1.0\n", "does not start with the line 'ply'"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "no 'end_header'"),
        (b"ply\nformat binary_middle_endian 1.0\nend_header\n", "binary_middle_endian"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n", "float128"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n", "no x/y/z"),
        (b"ply\nelement vertex 0\nend_header\n", "no 'format'"),
    ],
)
def test_ply_bad_headers(tmp_path, data, message):
    with pytest.raises(ReadError, match=message):
        read_ply(_write(tmp_path, "h.ply", data))


def test_ply_binary_million_points_read_fast(tmp_path):
    points = RNG.normal(size=(1_000_000, 3))
    path = tmp_path / "big.ply"
    write_ply_points(path, points)
    start = time.perf_counter()
    assert np.array_equal(read_ply(path).points, points)
    assert time.perf_counter() - start < 3.0


# ---------------------------------------------------------------- XYZ / PTS / CSV

@pytest.mark.parametrize("separator", [" ", ",", "\t", ";", ", "])
def test_xyz_separators(tmp_path, separator):
    points = np.round(RNG.normal(size=(20, 3)), 6)
    text = "\n".join(separator.join(repr(v) for v in row) for row in points.tolist())
    data = read_xyz(_write(tmp_path, "c.txt", text.encode()))
    assert np.array_equal(data.points, points)
    assert data.normals is None and data.colors is None and data.comments == ()


def test_xyz_header_lines_are_kept_as_comments(tmp_path):
    text = b"# exported by scanner\nX,Y,Z\n1,2,3\n4,5,6\n"
    data = read_input(_write(tmp_path, "c.csv", text))
    assert data.format == "xyz" and data.comments == ("# exported by scanner", "X,Y,Z")
    assert np.array_equal(data.points, [[1, 2, 3], [4, 5, 6]])


def test_pts_count_line_intensity_and_colours(tmp_path):
    text = b"2\n1 2 3 -1200 10 20 30\n4 5 6 800 40 50 60\n"
    data = read_xyz(_write(tmp_path, "scan.pts", text))
    assert np.array_equal(data.points, [[1, 2, 3], [4, 5, 6]])
    assert np.array_equal(data.colors, [[10, 20, 30], [40, 50, 60]])
    assert data.normals is None and any("column 4 ignored" in n for n in data.notes)


def test_pts_several_blocks_and_a_short_block(tmp_path):
    good = b"2\n1 2 3\n4 5 6\n1\n7 8 9\n"
    assert len(read_xyz(_write(tmp_path, "a.pts", good)).points) == 3
    with pytest.raises(ReadError, match=r"declares 2 points but only 1 rows follow \(file truncated\?\)"):
        read_xyz(_write(tmp_path, "b.pts", b"2\n1 2 3\n4 5 6\n2\n7 8 9\n"))


def test_xyz_six_columns_of_unit_vectors_are_normals(tmp_path):
    points = RNG.normal(size=(50, 3))
    normals = RNG.normal(size=(50, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    text = "\n".join(" ".join(map(repr, row)) for row in np.hstack([points, normals]).tolist())
    data = read_xyz(_write(tmp_path, "n.xyz", text.encode()))
    assert np.array_equal(data.normals, normals) and data.colors is None


def test_xyz_six_integer_columns_are_colours_and_axis_normals_are_not(tmp_path):
    data = read_xyz(_write(tmp_path, "c.xyz", b"0 0 0 255 128 0\n1 1 1 0 0 7\n"))
    assert np.array_equal(data.colors, [[255, 128, 0], [0, 0, 7]]) and data.normals is None
    data = read_xyz(_write(tmp_path, "n.xyz", b"0 0 0 0 0 1\n1 1 1 1 0 0\n"))
    assert np.array_equal(data.normals, [[0, 0, 1], [1, 0, 0]]) and data.colors is None


def test_xyz_named_columns_win_over_values(tmp_path):
    text = b"x y z intensity nx ny nz\n1 2 3 9 0 0 5\n4 5 6 9 0 2 0\n"
    data = read_xyz(_write(tmp_path, "n.xyz", text))
    assert np.array_equal(data.normals, [[0, 0, 5], [0, 2, 0]])
    assert data.notes == ("columns ignored: intensity",)


def test_xyz_unlabelled_scalars_are_ignored_with_a_note(tmp_path):
    data = read_xyz(_write(tmp_path, "s.xyz", b"0 0 0 0.5 7.25 3\n1 1 1 0.1 2 8\n"))
    assert data.normals is None and data.colors is None
    assert "columns 4, 5, 6 ignored" in data.notes[0]


def test_xyz_keeps_nan_and_inf_tokens(tmp_path):
    data = read_xyz(_write(tmp_path, "n.xyz", b"1 2 3\nnan 0 0\n0 -inf 0\nNaN Infinity 1\n"))
    assert np.isnan(data.points[1, 0]) and np.isneginf(data.points[2, 1])
    assert np.isinf(data.points[3, 1])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (b"x y z\n1 2 3\n4 5 6\n7 8\n", "line 4 has 2 columns but line 2 has 3"),
        (b"1 2 3\n4 five 6\n", "line 2: 'five' is not a number"),
        (b"1 2\n3 4\n", "at least x y z"),
        (b"name,comment\nfoo,bar\n", "no row of numbers"),
        (b"12\n1 2 3\n", r"declares 12 points but only 1 rows follow"),
    ],
)
def test_xyz_errors_name_the_line(tmp_path, text, message):
    with pytest.raises(ReadError, match=message):
        read_xyz(_write(tmp_path, "bad.xyz", text))


def test_xyz_hundred_thousand_rows_parse_quickly(tmp_path):
    points = np.round(RNG.normal(size=(100_000, 3)) * 100, 4)
    path = tmp_path / "big.xyz"
    np.savetxt(path, points, fmt="%.4f")
    start = time.perf_counter()
    assert np.allclose(read_input(path).points, points)
    assert time.perf_counter() - start < 2.0


# ---------------------------------------------------------------- PCD

def _pcd_header(kind, n, fields="x y z normal_x normal_y normal_z rgb _",
                size="4 4 4 4 4 4 4 1", types="F F F F F F F U", count="1 1 1 1 1 1 1 3"):  # fmt: skip
    return (
        f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\n"
        f"TYPE {types}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {n}\nDATA {kind}\n"
    ).encode()


def _pcd_points(n):
    xyz = RNG.normal(size=(n, 3)).astype(np.float32)
    nrm = RNG.normal(size=(n, 3)).astype(np.float32)
    rgb = RNG.integers(0, 256, size=(n, 3)).astype(np.uint32)
    packed = ((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).view(np.float32)
    return xyz, nrm, rgb, packed


def test_pcd_binary_and_ascii(tmp_path):
    xyz, nrm, rgb, packed = _pcd_points(40)
    record = np.dtype([("xyz", "<f4", 3), ("n", "<f4", 3), ("rgb", "<f4"), ("pad", "u1", 3)])
    table = np.zeros(40, record)
    table["xyz"], table["n"], table["rgb"] = xyz, nrm, packed
    binary = read_pcd(_write(tmp_path, "b.pcd", _pcd_header("binary", 40) + table.tobytes()))
    ascii_rows = "\n".join(
        " ".join([*(repr(float(v)) for v in (*p, *q)), repr(float(c)), "0 0 0"])
        for p, q, c in zip(xyz, nrm, packed, strict=True)
    )
    ascii_ = read_input(_write(tmp_path, "a.pcd", _pcd_header("ascii", 40) + ascii_rows.encode()))
    for data in (binary, ascii_):
        assert data.format == "pcd"
        assert np.array_equal(data.points, xyz) and np.array_equal(data.normals, nrm)
        assert np.array_equal(data.colors, rgb)


def test_pcd_nan_points_are_kept_for_ingest(tmp_path):
    data = read_pcd(_write(tmp_path, "o.pcd", _pcd_header("ascii", 2, "x y z", "4 4 4", "F F F", "1 1 1")
                           + b"nan nan nan\n1 2 3\n"))  # fmt: skip
    assert np.isnan(data.points[0]).all() and data.normals is None


def test_pcd_binary_compressed_and_truncated(tmp_path):
    with pytest.raises(ReadError, match="binary_compressed' is not supported.*pcl_convert_pcd_ascii_binary"):
        read_pcd(_write(tmp_path, "c.pcd", _pcd_header("binary_compressed", 3) + bytes(40)))
    with pytest.raises(ReadError, match=r"binary PCD ends after 2 of 3 points \(file truncated\?\)"):
        read_pcd(_write(tmp_path, "t.pcd", _pcd_header("binary", 3) + bytes(31 * 2 + 5)))
    with pytest.raises(ReadError, match="declares 3 points but the file holds only 1"):
        read_pcd(_write(tmp_path, "a.pcd", _pcd_header("ascii", 3, "x y z", "4 4 4", "F F F", "1 1 1")
                        + b"1 2 3\n"))  # fmt: skip


# ---------------------------------------------------------------- OBJ

def test_obj_quads_negative_indices_and_corner_forms(tmp_path):
    text = b"""# cube side
mtllib m.mtl
o part
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vn 0 0 1
g top
usemtl steel
f 1//1 2//1 3//1 4//1
v 0 0 1
v 1 0 1
v 1 1 1
f -3/1/1 -2/1/1 -1/1/1
f 5/1 6/1 7/1 # trailing comment
l 1 2
"""
    data = read_input(_write(tmp_path, "part.obj", text))
    assert data.format == "obj" and data.points.shape == (7, 3)
    assert np.array_equal(data.faces, [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 5, 6]])
    assert data.normals is None and "1 polygons were split into triangles" in data.notes


def test_obj_without_faces_is_a_point_cloud(tmp_path):
    data = read_obj(_write(tmp_path, "c.obj", b"v 1 2 3\nvn 0 0 1\nv 4 5 6 0.5 0.5 1\nvn 1 0 0\n"))
    assert data.faces is None and not data.is_mesh
    assert np.array_equal(data.normals, [[0, 0, 1], [1, 0, 0]])


def test_obj_face_index_out_of_range(tmp_path):
    with pytest.raises(ReadError, match="line 3 uses vertex index -4"):
        read_obj(_write(tmp_path, "b.obj", b"v 0 0 0\nv 1 0 0\nf 1 2 -4\nv 0 1 0\n"))


# ---------------------------------------------------------------- STL

@pytest.mark.parametrize("encoding", ["ascii", "binary"])
def test_stl_box_reads_watertight(tmp_path, encoding):
    box = trimesh.creation.box(extents=(10.0, 20.0, 30.0))
    if encoding == "ascii":
        payload = trimesh.exchange.stl.export_stl_ascii(box).encode()
    else:
        payload = trimesh.exchange.stl.export_stl(box)
    data = read_input(_write(tmp_path, "box.stl", payload))
    assert data.format == f"stl_{encoding}" and data.points.shape == (8, 3) and data.faces.shape == (12, 3)
    mesh = trimesh.Trimesh(data.points, data.faces, process=False)
    assert mesh.is_watertight and np.isclose(mesh.volume, 6000.0)


def test_stl_truncated_binary(tmp_path):
    payload = trimesh.exchange.stl.export_stl(trimesh.creation.box())
    with pytest.raises(ReadError, match=r"binary STL ends after 11 of 12 triangles"):
        read_stl(_write(tmp_path, "cut.stl", payload[:-30]))


# ---------------------------------------------------------------- dispatch

def test_read_input_errors(tmp_path):
    with pytest.raises(ReadError, match="the file is empty"):
        read_input(_write(tmp_path, "empty.ply", b""))
    with pytest.raises(ReadError, match=r"not a point cloud or mesh format we read \(PLY, XYZ/PTS/TXT/CSV"):
        read_input(_write(tmp_path, "notes.txt", b"just some words\n"))
    with pytest.raises(ReadError, match="looks like a ZIP archive; unpack it"):
        read_input(_write(tmp_path, "cloud.ply", b"PK\x03\x04" + bytes(100)))
    with pytest.raises(ReadError, match="does not exist"):
        read_input(tmp_path / "missing.ply")


def test_read_input_ignores_the_file_name(tmp_path):
    path = tmp_path / "upload"
    write_ply_points(path, np.eye(3))
    assert read_input(path).format == "ply"


@settings(max_examples=40, deadline=None)
@given(
    hnp.arrays(
        np.float64,
        st.tuples(st.integers(1, 40), st.just(3)),
        elements=st.floats(allow_nan=False, allow_infinity=False),
    )
)
def test_finite_clouds_round_trip_bit_exactly(tmp_path_factory, points):
    path = tmp_path_factory.mktemp("rt") / "cloud.ply"
    write_ply_points(path, points)
    assert np.array_equal(read_input(path).points.view(np.uint64), points.view(np.uint64))


def test_binary_stl_record_layout_is_fifty_bytes():
    assert struct.calcsize("<12fH") == 50
