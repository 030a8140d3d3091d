"""Read OBJ and STL meshes (an OBJ without faces is read as a point cloud)."""

from __future__ import annotations

import io
import os
import re

import numpy as np

from cam.io._files import read_bytes
from cam.io.errors import ReadError
from cam.io.formats import sniff_format
from cam.io.polygons import fan_triangulate
from cam.io.records import InputData
from cam.mesh.rows import first_occurrences

__all__ = ["read_obj", "read_stl"]

# Everything after the first slash of a face corner (texture and normal indices).
_CORNER_TAIL = re.compile(rb"/\S*")
_STL_VERTEX = re.compile(rb"^\s*vertex\s+(\S+)\s+(\S+)\s+(\S+)", re.MULTILINE | re.IGNORECASE)
_STL_FACET = re.compile(rb"^\s*facet\b", re.MULTILINE | re.IGNORECASE)
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])


def read_obj(path: str | os.PathLike[str]) -> InputData:
    """Read a Wavefront OBJ file.

    ``v`` lines give the vertices (a 4th ``w`` value is ignored; 6 values are x y z r g b with colours in
    0..1 or 0..255), ``f`` lines the faces in any of the corner forms ``v``, ``v/vt``, ``v//vn``,
    ``v/vt/vn`` with 1-based or negative (relative) indices; polygons are fan triangulated. Lines,
    points, groups, materials and texture coordinates are ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The OBJ file.

    Returns
    -------
    data : InputData
        ``points`` (n, 3) float64; ``colors`` (n, 3) uint8 when every ``v`` line has 6 values; ``faces``
        (m, 3) int64, or None when the file has no faces (a point cloud). ``normals`` (n, 3) float64 only
        for a point cloud whose ``vn`` count equals its ``v`` count (a mesh's per-corner normals are not
        carried over: the faces define its normals).

    Raises
    ------
    ReadError
        For a missing file, no vertices, a malformed ``v`` or ``f`` line (the message names the line),
        or a face index outside the vertices defined before it.
    """
    data = read_bytes(path).replace(b"\r", b"")
    lines = data.split(b"\n")
    v_rows, vn_rows, f_rows = [], [], []
    v_numbers, f_numbers = [], []
    for number, line in enumerate(lines, start=1):
        head = line[:3].replace(b"\t", b" ")
        if head.startswith(b"v "):
            v_rows.append(line[2:])
            v_numbers.append(number)
        elif head.startswith(b"f "):
            f_rows.append(line[2:])
            f_numbers.append(number)
        elif head == b"vn ":
            vn_rows.append(line[3:])
    if not v_rows:
        raise ReadError("the OBJ file has no vertex ('v') lines; it holds no geometry")
    values = _number_rows(v_rows, v_numbers, what="vertex")
    points = np.ascontiguousarray(values[:, :3])
    colors = _obj_colors(values) if values.shape[1] == 6 else None
    notes: list[str] = []
    faces = None
    if f_rows:
        faces, notes = _obj_faces(f_rows, f_numbers, v_numbers, len(points))
    normals = None
    if faces is None and vn_rows and len(vn_rows) == len(v_rows):
        normals = _number_rows(vn_rows, None, what="normal")[:, :3]
    return InputData(
        points=points, normals=normals, colors=colors, faces=faces, format="obj", notes=tuple(notes)
    )


def read_stl(path: str | os.PathLike[str]) -> InputData:
    """Read an ASCII or binary STL file as an indexed triangle mesh.

    Identical corner coordinates are merged into one vertex (bit-exact, with -0.0 equal to 0.0), so a
    closed STL reads as a watertight mesh.

    Parameters
    ----------
    path : str or os.PathLike
        The STL file.

    Returns
    -------
    data : InputData
        ``points`` (n, 3) float64 and ``faces`` (m, 3) int64; ``format`` is ``"stl_ascii"`` or
        ``"stl_binary"``.

    Raises
    ------
    ReadError
        For a missing file, a binary STL shorter than its header or its triangle count says or with no
        triangles, or an ASCII STL without vertices, with a non-numeric vertex value, or whose facets do
        not hold three vertices each.
    """
    data = read_bytes(path)
    kind = sniff_format(data[:65536], total_size=len(data))
    if kind == "stl_ascii":
        corners = _ascii_stl_corners(data)
    else:
        kind = "stl_binary"
        corners = _binary_stl_corners(data)
    points, inverse = _merge_vertices(corners)
    return InputData(points=points, faces=inverse.reshape(-1, 3), format=kind)


def _number_rows(rows: list[bytes], numbers: list[int] | None, *, what: str) -> np.ndarray:
    try:
        table = np.loadtxt(io.BytesIO(b"\n".join(rows)), dtype=np.float64, ndmin=2, comments="#")
    except ValueError:
        table = None
    if table is not None and len(table) == len(rows) and table.shape[1] >= 3:
        return table
    # Rows of different lengths (some with w, some without): parse one by one to name a bad line.
    parsed = []
    for index, row in enumerate(rows):
        tokens = row.split(b"#")[0].split()
        where = f"line {numbers[index]}" if numbers else f"{what} {index + 1}"
        try:
            floats = [float(t) for t in tokens]
        except ValueError:
            raise ReadError(
                f"OBJ {where}: {row.strip()[:60].decode(errors='replace')!r} is not a list "
                f"of numbers; a {what} needs x y z"
            ) from None
        if len(floats) < 3:
            raise ReadError(f"OBJ {where} has {len(floats)} numbers; a {what} needs x y z")
        parsed.append(floats[:3])
    return np.asarray(parsed, dtype=np.float64)


def _obj_colors(values: np.ndarray) -> np.ndarray:
    rgb = np.nan_to_num(values[:, 3:6])
    if rgb.max(initial=0) <= 1.0:
        rgb = rgb * 255.0
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def _obj_faces(f_rows, f_numbers, v_numbers, n_vertices) -> tuple[np.ndarray | None, list[str]]:
    stripped = _CORNER_TAIL.sub(b"", b"\n".join(row.split(b"#")[0] for row in f_rows))
    corner_rows = stripped.split(b"\n")
    counts = np.fromiter((len(r.split()) for r in corner_rows), dtype=np.int64, count=len(f_rows))
    try:
        flat = np.array(stripped.split(), dtype=np.int64)
    except ValueError:
        bad = next(i for i, r in enumerate(corner_rows) if not all(_is_int(t) for t in r.split()))
        raise ReadError(
            f"OBJ line {f_numbers[bad]}: face corners must be vertex indices such as "
            f"'f 1 2 3' or 'f 1/1/1 2/2/2 3/3/3', got {f_rows[bad].strip()[:60].decode(errors='replace')!r}"
        ) from None
    # A negative index counts back from the last vertex defined before that face line.
    defined = np.searchsorted(np.asarray(v_numbers), np.asarray(f_numbers))
    defined_per_corner = np.repeat(defined, counts)
    resolved = np.where(flat < 0, defined_per_corner + flat, flat - 1)
    bad = np.flatnonzero((flat == 0) | (resolved < 0) | (resolved >= n_vertices))
    if bad.size:
        face = int(np.searchsorted(np.cumsum(counts), bad[0], side="right"))
        raise ReadError(
            f"OBJ line {f_numbers[face]} uses vertex index {int(flat[bad[0]])}, but the file "
            f"has {n_vertices} vertices (OBJ indices start at 1); the file is corrupt"
        )
    faces, skipped = fan_triangulate(counts, resolved)
    notes = []
    if skipped:
        notes.append(f"{skipped} faces with fewer than 3 vertices were skipped")
    if np.any(counts > 3):
        notes.append(f"{int(np.sum(counts > 3))} polygons were split into triangles")
    return (faces if len(faces) else None), notes


def _is_int(token: bytes) -> bool:
    try:
        int(token)
    except ValueError:
        return False
    return True


def _ascii_stl_corners(data: bytes) -> np.ndarray:
    matches = _STL_VERTEX.findall(data)
    facets = len(_STL_FACET.findall(data))
    if not matches:
        raise ReadError("the ASCII STL file holds no 'vertex' lines; it has no triangles")
    if len(matches) != 3 * facets:
        raise ReadError(
            f"the ASCII STL file has {facets} facets but {len(matches)} vertices; every facet "
            "needs exactly 3 (file truncated or not triangulated?)"
        )
    try:
        corners = np.array(matches, dtype=np.float64)
    except ValueError:
        raise ReadError("an ASCII STL vertex line holds a value that is not a number") from None
    return corners


def _binary_stl_corners(data: bytes) -> np.ndarray:
    if len(data) < 84:
        raise ReadError(
            f"the binary STL file is {len(data)} bytes, shorter than its 84-byte header "
            "(file truncated?)"
        )
    count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
    available = (len(data) - 84) // _STL_RECORD.itemsize
    if available < count:
        raise ReadError(
            f"binary STL ends after {available} of {count} triangles (file truncated?)"
        )
    if count == 0:
        raise ReadError("the binary STL file holds 0 triangles; export the part again")
    records = np.frombuffer(data, dtype=_STL_RECORD, count=count, offset=84)
    return records["vertices"].reshape(-1, 3).astype(np.float64)


def _merge_vertices(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    first, inverse = first_occurrences(corners, inverse=True)
    return corners[first] + 0.0, inverse
