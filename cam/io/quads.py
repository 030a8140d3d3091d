"""Read and write quad meshes: OBJ with faces of 4, and PLY with a colour per face.

The readers in :mod:`cam.io` fan-triangulate polygons (what ingest wants); the
remesh and segment stages need the quads themselves, so they get their own
small reader and writers here. Writes are atomic (temporary file + rename).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cam.io.atomic import atomic_write
from cam.io.errors import ReadError, WriteError
from cam.io.ply import (  # the same binary PLY layout as the triangle writer
    _header,
    _property_lines,
)

__all__ = ["read_quad_obj", "write_ply_quads_colored", "write_quad_obj"]


def _check_quads(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    verts = np.asarray(vertices, dtype=np.float64)
    quads = np.asarray(faces)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise WriteError(f"vertices must be an (n, 3) array, got shape {verts.shape}")
    if not np.isfinite(verts).all():
        raise WriteError(f"{int((~np.isfinite(verts).all(axis=1)).sum())} vertices have non-finite coordinates")
    if quads.ndim != 2 or quads.shape[1] != 4 or (quads.size and quads.dtype.kind not in "iu"):
        raise WriteError(f"faces must be an (m, 4) integer array, got shape {quads.shape} dtype {quads.dtype}")
    if quads.size and (quads.min() < 0 or quads.max() >= len(verts)):
        raise WriteError(f"faces index vertices {quads.min()}..{quads.max()} but there are {len(verts)} vertices")
    return verts, quads.astype(np.int64, copy=False)


def write_quad_obj(
    path: str | os.PathLike[str],
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    comments: Sequence[str] = (),
) -> Path:
    """Write a quad mesh as Wavefront OBJ (``v`` lines, then ``f a b c d`` 1-based), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The target file.
    vertices : (n, 3) array_like of float
        Coordinates in mm; written with 17 significant digits so that reading the file back gives the
        same doubles.
    faces : (m, 4) array_like of int
        Vertex indices of each quad in counter-clockwise order seen from outside.
    comments : sequence of str, optional
        Lines written as ``# ...`` at the top (no line breaks).

    Returns
    -------
    path : pathlib.Path
        The path written.

    Raises
    ------
    WriteError
        For arrays of the wrong shape or type, non-finite coordinates, or an index outside the vertices.
    """
    verts, quads = _check_quads(vertices, faces)
    head = "".join(f"# {c}\n" for c in comments).encode()
    lines_v = "".join("v {:.17g} {:.17g} {:.17g}\n".format(*p) for p in verts.tolist()).encode()
    lines_f = "".join("f {} {} {} {}\n".format(*q) for q in (quads + 1).tolist()).encode()
    return atomic_write(path, [head, lines_v, lines_f])


def read_quad_obj(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read an OBJ whose faces are all quads.

    Corner forms ``v/vt/vn`` are accepted; negative (relative) indices are resolved.

    Parameters
    ----------
    path : str or os.PathLike
        The OBJ file.

    Returns
    -------
    vertices : (n, 3) float64
        Coordinates as in the file (mm for our files).
    faces : (m, 4) int64
        0-based vertex indices of each quad.

    Raises
    ------
    ReadError
        For an unreadable file, a face that is not a quad (the message gives its line), a malformed
        number, an index outside the vertices, or no faces.
    """
    try:
        text = Path(path).read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise ReadError(f"cannot read {os.fspath(path)!r}: {exc.strerror}") from exc
    verts: list[list[float]] = []
    quads: list[list[int]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        parts = raw.split()
        if not parts:
            continue
        if parts[0] == "v":
            try:
                verts.append([float(x) for x in parts[1:4]])
            except ValueError as exc:
                raise ReadError(f"line {number}: malformed vertex {raw.strip()!r}") from exc
            if len(verts[-1]) != 3:
                raise ReadError(f"line {number}: a vertex needs 3 coordinates, got {raw.strip()!r}")
        elif parts[0] == "f":
            if len(parts) != 5:
                raise ReadError(f"line {number}: expected a quad (4 corners), got {len(parts) - 1} corners")
            try:
                idx = [int(c.split("/")[0]) for c in parts[1:]]
            except ValueError as exc:
                raise ReadError(f"line {number}: malformed face {raw.strip()!r}") from exc
            # Negative indices count back from the vertices defined so far (OBJ rule).
            quads.append([i - 1 if i > 0 else len(verts) + i for i in idx])
    if not quads:
        raise ReadError("the OBJ file has no faces; expected a quad mesh")
    v = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(quads, dtype=np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise ReadError(f"faces index vertices {f.min() + 1}..{f.max() + 1} but the file has {len(v)} vertices")
    return v, f


def write_ply_quads_colored(
    path: str | os.PathLike[str],
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: np.ndarray,
    *,
    labels: np.ndarray | None = None,
    comments: Sequence[str] = (),
) -> Path:
    """Write quads with one RGB colour per face as binary little-endian PLY, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The target file.
    vertices : (n, 3) array_like of float
        Coordinates in mm; written as double.
    faces : (m, 4) array_like of int
        Vertex indices of each quad.
    colors : (m, 3) array_like of int
        The colour of each face (red, green, blue) in 0..255; written as uchar.
    labels : (m,) array_like of int or None, optional
        Written as a face property ``patch`` (int32) so viewers and tests can read the segmentation back
        exactly (-1 = no patch, e.g. base).
    comments : sequence of str, optional
        Header comment lines (ASCII, no line breaks).

    Returns
    -------
    path : pathlib.Path
        The path written.

    Raises
    ------
    WriteError
        For arrays of the wrong shape or type, non-finite coordinates, an index outside the vertices,
        colours outside 0..255, or a comment with a line break or non-ASCII text.
    """
    verts, quads = _check_quads(vertices, faces)
    rgb = np.asarray(colors)
    if rgb.shape != (len(quads), 3):
        raise WriteError(f"colors must be (m, 3) with m = {len(quads)} faces, got shape {rgb.shape}")
    if rgb.size and (rgb.min() < 0 or rgb.max() > 255):
        raise WriteError("colors must lie in 0..255")
    vertex = np.empty(len(verts), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vertex["x"], vertex["y"], vertex["z"] = verts.T
    fields = [("n", "u1"), ("v", "<i4", (4,)), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    props = ["property list uchar int vertex_indices", "property uchar red", "property uchar green",
             "property uchar blue"]
    if labels is not None:
        lab = np.asarray(labels)
        if lab.shape != (len(quads),):
            raise WriteError(f"labels must be (m,) with m = {len(quads)} faces, got shape {lab.shape}")
        fields.append(("patch", "<i4"))
        props.append("property int patch")
    face = np.empty(len(quads), dtype=fields)
    face["n"] = 4
    face["v"] = quads
    face["red"], face["green"], face["blue"] = rgb.astype(np.uint8).T
    if labels is not None:
        face["patch"] = lab
    header = _header(comments, [("vertex", len(verts), _property_lines([("x", "<f8"), ("y", "<f8"), ("z", "<f8")])),
                                ("face", len(quads), props)])
    return atomic_write(path, [header, vertex.tobytes(), face.tobytes()])
