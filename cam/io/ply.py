"""Read and write PLY files (ascii, binary little- and big-endian).

Reading is vectorised with numpy structured dtypes; elements whose list
properties vary in length (mixed triangle and quad faces) take a per-record
scan that only computes offsets, after which the values are gathered at once.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cam.io._files import read_bytes
from cam.io._plybody import read_ascii_elements, read_binary_elements
from cam.io._plyheader import PlyHeader, parse_header
from cam.io.atomic import atomic_write
from cam.io.errors import ReadError, WriteError
from cam.io.polygons import fan_triangulate
from cam.io.records import InputData

__all__ = ["read_ply", "write_ply_mesh", "write_ply_points"]

_NORMAL_NAMES = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_COLOR_NAMES = (
    ("red", "green", "blue"),
    ("r", "g", "b"),
    ("diffuse_red", "diffuse_green", "diffuse_blue"),
)
_FACE_LIST_NAMES = ("vertex_indices", "vertex_index")


def read_ply(path: str | os.PathLike[str]) -> InputData:
    """Read a PLY point cloud or mesh (ascii, binary little- or big-endian).

    Parameters
    ----------
    path : str or os.PathLike
        The PLY file.

    Returns
    -------
    data : InputData
        ``points`` (n, 3) float64, ``normals`` (n, 3) float64 when the vertices carry ``nx ny nz``,
        ``colors`` (n, 3) uint8 when they carry ``red green blue`` (float colours in 0..1 are scaled to
        0..255), and ``faces`` (m, 3) int64 when a ``face`` element holds at least one polygon (polygons
        are fan triangulated). Other vertex properties and other elements are skipped.

    Raises
    ------
    ReadError
        For a missing file, a missing or malformed header, an unknown format, a body shorter than the
        header claims, a non-numeric ascii value, or a face index outside the vertex range.
    """
    data = read_bytes(path)
    header = parse_header(data)
    if header.format == "ascii":
        values = read_ascii_elements(data, header)
    else:
        values = read_binary_elements(data, header)
    return _assemble(header, values)


def write_ply_points(
    path: str | os.PathLike[str],
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    comments: Sequence[str] = (),
) -> Path:
    """Write a point cloud as binary little-endian PLY, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The target file.
    points : (n, 3) array_like of numbers
        Finite coordinates, mm; written as double.
    normals : (n, 3) array_like of numbers or None, optional
        Finite normals, one per point; written as float.
    comments : sequence of str, optional
        Header comment lines (ASCII, no line breaks).

    Returns
    -------
    path : pathlib.Path
        The path written.

    Raises
    ------
    WriteError
        For arrays of the wrong shape or type, NaN or Inf values, a normal count that differs from the
        point count, or a comment with a line break or non-ASCII text.
    """
    pts = _finite_rows("points", points)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if normals is not None:
        nrm = _finite_rows("normals", normals)
        if len(nrm) != len(pts):
            raise WriteError(
                f"normals has {len(nrm)} rows but points has {len(pts)}; pass one normal per point"
            )
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    vertex = np.empty(len(pts), dtype=fields)
    vertex["x"], vertex["y"], vertex["z"] = pts.T
    if normals is not None:
        vertex["nx"], vertex["ny"], vertex["nz"] = nrm.T
    header = _header(comments, [("vertex", len(pts), _property_lines(fields))])
    return atomic_write(path, [header, vertex])


def write_ply_mesh(
    path: str | os.PathLike[str],
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    comments: Sequence[str] = (),
) -> Path:
    """Write a triangle mesh as binary little-endian PLY, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The target file.
    vertices : (n, 3) array_like of numbers
        Finite coordinates, mm; written as double.
    faces : (m, 3) array_like of int
        Vertex indices in ``[0, n)``; written as a uchar count and int32 indices, the layout most tools
        read fastest.
    comments : sequence of str, optional
        Header comment lines (ASCII, no line breaks).

    Returns
    -------
    path : pathlib.Path
        The path written.

    Raises
    ------
    WriteError
        For arrays of the wrong shape or type, NaN or Inf coordinates, an index outside the vertices, or
        a comment with a line break or non-ASCII text.
    """
    verts = _finite_rows("vertices", vertices)
    tris = np.asarray(faces)
    if tris.ndim != 2 or tris.shape[1] != 3 or (tris.size and tris.dtype.kind not in "iu"):
        raise WriteError(
            f"faces must be an (m, 3) integer array, got shape {tris.shape} dtype {tris.dtype}"
        )
    if tris.size and (tris.min() < 0 or tris.max() >= len(verts)):
        raise WriteError(
            f"faces index vertices {tris.min()}..{tris.max()} but there are {len(verts)} vertices"
        )
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    vertex = np.empty(len(verts), dtype=fields)
    vertex["x"], vertex["y"], vertex["z"] = verts.T
    face = np.empty(len(tris), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = tris
    header = _header(
        comments,
        [
            ("vertex", len(verts), _property_lines(fields)),
            ("face", len(tris), ["property list uchar int vertex_indices"]),
        ],
    )
    return atomic_write(path, [header, vertex, face])


def _assemble(header: PlyHeader, values: dict) -> InputData:
    vertex = values.get("vertex")
    if vertex is None:
        raise ReadError("the PLY file has no 'vertex' element; it holds no points")
    names = header.element("vertex").names
    missing = [axis for axis in "xyz" if axis not in vertex]
    if missing:
        raise ReadError(
            f"the PLY vertex element has no {'/'.join(missing)} property "
            f"(it has: {', '.join(names) or 'nothing'}); cannot find the coordinates"
        )
    points = _stack(vertex, ("x", "y", "z"))
    normals = next(
        (_stack(vertex, trio) for trio in _NORMAL_NAMES if all(n in vertex for n in trio)), None
    )
    colors = next(
        (_colors(vertex, trio) for trio in _COLOR_NAMES if all(n in vertex for n in trio)), None
    )
    notes: list[str] = []
    faces = None
    face_values = values.get("face")
    if face_values is not None:
        counts, flat = _face_lists(header, face_values)
        if len(counts):
            _check_indices(counts, flat, len(points))
            faces, skipped = fan_triangulate(counts, flat)
            if skipped:
                notes.append(f"{skipped} faces with fewer than 3 vertices were skipped")
            if np.any(counts > 3):
                notes.append(f"{int(np.sum(counts > 3))} polygons were split into triangles")
    return InputData(
        points=points,
        normals=normals,
        colors=colors,
        faces=faces,
        format="ply",
        comments=tuple(header.comments),
        notes=tuple(notes),
    )


def _stack(element: dict, names: Sequence[str]) -> np.ndarray:
    return np.column_stack([np.asarray(element[n], dtype=np.float64) for n in names])


def _colors(element: dict, names: Sequence[str]) -> np.ndarray:
    channels = np.column_stack([np.asarray(element[n]) for n in names])
    if channels.dtype.kind == "f":
        # Float colours are 0..1 by convention (MeshLab, Open3D).
        scaled = np.nan_to_num(channels, nan=0.0) * 255.0
        return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)
    if channels.dtype.itemsize > 1 and channels.max(initial=0) > 255:
        # 16-bit colour channels keep their high byte.
        return (channels >> 8).astype(np.uint8)
    return np.clip(channels, 0, 255).astype(np.uint8)


def _face_lists(header: PlyHeader, face_values: dict) -> tuple[np.ndarray, np.ndarray]:
    element = header.element("face")
    lists = [p.name for p in element.properties if p.is_list]
    name = next((n for n in _FACE_LIST_NAMES if n in lists), None)
    if name is None and len(lists) == 1:
        name = lists[0]
    if name is None:
        raise ReadError(
            "the PLY face element has no 'vertex_indices' list property "
            f"(it has: {', '.join(element.names)}); cannot read the faces"
        )
    counts, flat = face_values[name]
    return counts, flat.astype(np.int64, copy=False)


def _check_indices(counts: np.ndarray, flat: np.ndarray, n_vertices: int) -> None:
    bad = np.flatnonzero((flat < 0) | (flat >= n_vertices))
    if bad.size:
        starts = np.cumsum(counts) - counts
        face = int(np.searchsorted(starts, bad[0], side="right") - 1)
        raise ReadError(
            f"PLY face {face} uses vertex index {int(flat[bad[0]])}, but the file has "
            f"{n_vertices} vertices (valid indices 0..{n_vertices - 1}); the file is corrupt"
        )


def _finite_rows(name: str, array: np.ndarray) -> np.ndarray:
    values = np.asarray(array)
    if values.ndim != 2 or values.shape[1] != 3 or values.dtype.kind not in "fiu":
        raise WriteError(
            f"{name} must be an (n, 3) numeric array, got shape {values.shape} dtype {values.dtype}"
        )
    values = values.astype(np.float64, copy=False)
    if not np.isfinite(values).all():
        bad = int(np.count_nonzero(~np.isfinite(values).all(axis=1)))
        raise WriteError(f"{name} has {bad} rows with NaN or Inf; clean them before writing")
    return values


def _property_lines(fields: Sequence[tuple[str, str]]) -> list[str]:
    names = {"<f8": "double", "<f4": "float"}
    return [f"property {names[code]} {name}" for name, code in fields]


def _header(comments: Sequence[str], elements: Sequence[tuple[str, int, list[str]]]) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0"]
    for comment in comments:
        if "\n" in comment or "\r" in comment:
            raise WriteError(f"PLY comment {comment!r} contains a line break; pass one line each")
        lines.append(f"comment {comment}")
    for name, count, properties in elements:
        lines.append(f"element {name} {count}")
        lines.extend(properties)
    lines.append("end_header")
    try:
        return ("\n".join(lines) + "\n").encode("ascii")
    except UnicodeEncodeError:
        raise WriteError("PLY header comments must be ASCII text") from None
