"""Read PCD point clouds (the Point Cloud Library format, v0.5 to v0.7)."""

from __future__ import annotations

import io
import os

import numpy as np

from cam.io._files import read_bytes
from cam.io.errors import ReadError
from cam.io.records import InputData

__all__ = ["read_pcd"]

_KEYWORDS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4",
          ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}  # fmt: skip
_NORMALS = ("normal_x", "normal_y", "normal_z")


def read_pcd(path: str | os.PathLike[str]) -> InputData:
    """Read a PCD file with ``DATA ascii`` or ``DATA binary``.

    Parameters
    ----------
    path : str or os.PathLike
        The PCD file.

    Returns
    -------
    data : InputData
        ``points`` (n, 3) float64 from fields ``x y z``, ``normals`` (n, 3) float64 from ``normal_x
        normal_y normal_z`` when present, ``colors`` (n, 3) uint8 from a packed ``rgb`` or ``rgba``
        field when present; other fields are ignored. Organised clouds keep their NaN placeholder points
        (ingest drops and counts them). The header's ``#`` lines become ``comments``.

    Raises
    ------
    ReadError
        For a missing file, ``DATA binary_compressed`` (with how to convert) or an unknown ``DATA``, a
        malformed header, missing x/y/z fields, or a body shorter than ``POINTS``.
    """
    data = read_bytes(path)
    header, body_offset = _parse_header(data)
    fields = header["FIELDS"]
    codes = _field_codes(header)
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    n = _point_count(header)
    kind = header["DATA"][0].lower()
    if kind == "binary_compressed":
        raise ReadError(
            "PCD 'DATA binary_compressed' is not supported; convert the file to binary or ascii "
            "first, e.g. `pcl_convert_pcd_ascii_binary in.pcd out.pcd 1` (PCL), or save it as PLY "
            "from CloudCompare"
        )
    if kind == "binary":
        columns = _binary_columns(data[body_offset:], fields, codes, counts, n)
    elif kind == "ascii":
        columns = _ascii_columns(data[body_offset:], fields, codes, counts, n)
    else:
        raise ReadError(f"PCD 'DATA {kind}' is unknown; expected ascii, binary or binary_compressed")
    missing = [a for a in "xyz" if a not in columns]
    if missing:
        raise ReadError(
            f"the PCD file has no {'/'.join(missing)} field (fields: {' '.join(fields)}); "
            "cannot find the coordinates"
        )
    points = np.column_stack([columns[a].astype(np.float64) for a in "xyz"])
    normals = None
    if all(name in columns for name in _NORMALS):
        normals = np.column_stack([columns[name].astype(np.float64) for name in _NORMALS])
    packed = columns.get("rgb", columns.get("rgba"))
    colors = _unpack_rgb(packed) if packed is not None else None
    return InputData(
        points=points,
        normals=normals,
        colors=colors,
        faces=None,
        format="pcd",
        comments=tuple(header.get("#", [])),
    )


def _parse_header(data: bytes) -> tuple[dict[str, list[str]], int]:
    header: dict[str, list[str]] = {"#": []}
    position = 0
    while position < len(data):
        end = data.find(b"\n", position)
        end = len(data) if end < 0 else end
        line = data[position:end].decode("ascii", errors="replace").strip()
        position = end + 1
        if not line:
            continue
        if line.startswith("#"):
            header["#"].append(line.lstrip("# "))
            continue
        keyword, *values = line.split()
        if keyword.upper() not in _KEYWORDS:
            raise ReadError(
                f"PCD header line {line[:60]!r} starts with unknown keyword {keyword!r}; "
                "the header is malformed or the file is truncated"
            )
        header[keyword.upper()] = values
        if keyword.upper() == "DATA":
            break
    else:
        raise ReadError("the PCD header has no DATA line; the file is truncated or not a PCD file")
    for required in ("FIELDS", "SIZE", "TYPE"):
        if required not in header:
            raise ReadError(f"the PCD header has no {required} line; the header is malformed")
    if not header["DATA"]:
        raise ReadError("the PCD DATA line names no encoding; expected ascii or binary")
    return header, position


def _field_codes(header: dict[str, list[str]]) -> list[str]:
    fields, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT", ["1"] * len(fields))
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise ReadError(
            f"the PCD header lists {len(fields)} FIELDS but {len(sizes)} SIZE, {len(types)} TYPE "
            f"and {len(counts)} COUNT entries; the header is malformed"
        )
    codes = []
    for name, size, kind, count in zip(fields, sizes, types, counts, strict=True):
        code = _TYPES.get((kind.upper(), int(size) if size.isdigit() else -1))
        if code is None or not count.isdigit() or int(count) < 1:
            raise ReadError(
                f"PCD field {name!r} has TYPE {kind} SIZE {size} COUNT {count}, which is not a "
                "valid combination (TYPE F/I/U, SIZE 1/2/4/8, COUNT >= 1)"
            )
        codes.append(code)
    return codes


def _point_count(header: dict[str, list[str]]) -> int:
    try:
        if "POINTS" in header:
            return int(header["POINTS"][0])
        return int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0])
    except (KeyError, IndexError, ValueError):
        raise ReadError(
            "the PCD header gives no valid POINTS (or WIDTH and HEIGHT) count"
        ) from None


def _binary_columns(body: bytes, fields, codes, counts, n) -> dict[str, np.ndarray]:
    # PCL writes binary PCD in the machine's byte order, which is little-endian in practice.
    dtype = np.dtype(
        [(f"f{i}", "<" + code, (count,)) if count > 1 else (f"f{i}", "<" + code)
         for i, (code, count) in enumerate(zip(codes, counts, strict=True))]
    )  # fmt: skip
    available = len(body) // dtype.itemsize
    if available < n:
        raise ReadError(f"binary PCD ends after {available} of {n} points (file truncated?)")
    table = np.frombuffer(body, dtype=dtype, count=n)
    columns: dict[str, np.ndarray] = {}
    for i, name in enumerate(fields):
        if counts[i] == 1:
            columns.setdefault(name, table[f"f{i}"].astype(codes[i]))
    return columns


def _ascii_columns(body: bytes, fields, codes, counts, n) -> dict[str, np.ndarray]:
    width = sum(counts)
    try:
        table = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments="#")
    except ValueError as exc:
        raise ReadError(
            f"the ascii PCD body is malformed ({exc}); each row needs {width} numbers"
        ) from None
    if n and (table.size == 0 or table.shape[1] != width):
        got = table.shape[1] if table.size else 0
        raise ReadError(f"ascii PCD rows have {got} values but the header's fields need {width}")
    if len(table) < n:
        raise ReadError(
            f"ascii PCD header declares {n} points but the file holds only {len(table)} rows "
            "(file truncated?)"
        )
    columns: dict[str, np.ndarray] = {}
    start = 0
    for name, code, count in zip(fields, codes, counts, strict=True):
        if count == 1:
            column = table[:n, start]
            if name in ("rgb", "rgba") and code == "f4":
                # Packed colours are a float whose bit pattern holds the bytes.
                column = column.astype(np.float32)
            columns.setdefault(name, column)
        start += count
    return columns


def _unpack_rgb(packed: np.ndarray) -> np.ndarray:
    is_float = packed.dtype.kind == "f"
    bits = packed.astype(np.float32).view(np.uint32) if is_float else packed.astype(np.uint32)
    return np.column_stack([(bits >> 16) & 255, (bits >> 8) & 255, bits & 255]).astype(np.uint8)
