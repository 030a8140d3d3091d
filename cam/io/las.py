"""Read ASPRS LAS 1.0-1.4 and LAZ (LASzip-compressed LAS) point clouds.

laspy parses the file and lazrs decompresses LAZ (both permissive licences; laspy is told to use only
lazrs, never the LGPL LASzip bindings). The header is checked first, from its fixed layout, so that a
truncated file, an empty one or one over the point limit is refused by name before anything is decoded.

Units: LAS coordinates are integers times the header's scale plus its offset, in the unit of the file's
coordinate reference system. When a CRS record states that unit (metre, foot, US survey foot, ...) the
points are converted to mm and a note says so; ``ingest.units`` then does not apply. A file without a CRS
(as part scanners and CloudCompare write them) is taken to be in ``ingest.units``, like any other format,
and a note says that too. A geographic CRS (longitude/latitude in degrees) is refused.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from cam.io._files import read_head
from cam.io._lascrs import read_crs_units
from cam.io.errors import ReadError
from cam.io.records import InputData

__all__ = ["read_las"]

_SIGNATURE = b"LASF"
_MIN_HEADER = 227
_HEADER_14 = 375
_WKT_BIT = 1 << 4
_COMPRESSED_BITS = 0xC0


def read_las(path: str | os.PathLike[str], *, max_points: int | None = None) -> InputData:
    """Read a LAS or LAZ file's point coordinates.

    Parameters
    ----------
    path : str or os.PathLike
        The LAS or LAZ file (told apart by the header's compression bit, not the name).
    max_points : int or None, keyword-only
        Refuse, before decoding, a file whose header declares more points than this (the operator's
        ``max_points``: LAS holds no placeholder points, so every declared point would be kept).

    Returns
    -------
    data : InputData
        ``points`` (n, 3) float64: the stored integers times the header's scale plus its offset, converted
        to mm (``in_mm`` True) when the file's CRS states its unit, else in the file's unit. ``normals`` and
        ``colors`` are None (intensity, colour, classification and the other attributes are ignored).
        ``format`` is ``"las"`` or ``"laz"``; ``comments`` hold the header's generating software and
        system identifier; ``notes`` say how the unit was decided.

    Raises
    ------
    ReadError
        For a missing file, a header shorter than LAS's, a version other than 1.0-1.4, a file that declares
        no points or more than `max_points`, point data shorter than declared (file truncated), compressed
        data that cannot be decoded, a zero or non-finite scale, or a geographic CRS.
    """
    target = Path(path)
    header = _read_header(target)
    declared = header["count"]
    kind = "laz" if header["compressed"] else "las"
    if declared == 0:
        raise ReadError(f"the {kind.upper()} file holds no points (its header declares 0)")
    if max_points is not None and declared > max_points:
        raise ReadError(
            f"the {kind.upper()} file holds {declared} points, more than the limit of {max_points}; subsample it "
            f"below {max_points} points (e.g. CloudCompare's Subsample tool or PDAL's filters.sample) and upload "
            "again; the limit is set by whoever runs the service"
        )
    if not header["compressed"]:
        _check_point_data_length(header, target.stat().st_size)
    scales = np.asarray(header["scales"], dtype=np.float64)
    offsets = np.asarray(header["offsets"], dtype=np.float64)
    if not (np.isfinite(scales).all() and (scales != 0).all() and np.isfinite(offsets).all()):
        raise ReadError(
            f"the {kind.upper()} header's scale {scales.tolist()} or offset {offsets.tolist()} is zero or not "
            "finite; the coordinates cannot be recovered from it"
        )
    raw, records = _decode(target, kind)
    if len(raw) != declared:
        raise ReadError(
            f"the {kind.upper()} file decodes to {len(raw)} points but its header declares {declared} "
            "(file truncated?)"
        )
    # The coordinates are the stored integers times the scale plus the offset (LAS 1.4, section 2.2).
    points = raw.astype(np.float64) * scales + offsets
    points, in_mm, unit_note = _convert_units(points, records, prefer_wkt=header["wkt"])
    summary = (f"{kind.upper()} {header['version']}, point format {header['point_format']}: {declared} points; "
               "intensity, colour and classification are ignored")
    notes = [summary, unit_note]
    comments = tuple(text for text in (header["software"], header["system"]) if text)
    return InputData(points=points, format=kind, comments=comments, notes=tuple(notes), in_mm=in_mm)


def _read_header(target: Path) -> dict:
    head, _ = read_head(target, _HEADER_14)
    if not head.startswith(_SIGNATURE):
        raise ReadError(f"{target.name} does not start with LAS's signature 'LASF'; it is not a LAS/LAZ file")
    if len(head) < _MIN_HEADER:
        raise ReadError(
            f"the LAS header is cut short: the file has {len(head)} bytes, a LAS header needs at least "
            f"{_MIN_HEADER} (file truncated?)"
        )
    major, minor = head[24], head[25]
    if major != 1 or minor > 4:
        raise ReadError(f"LAS version {major}.{minor} is not one we read (1.0-1.4)")
    (encoding,) = struct.unpack_from("<H", head, 6)
    header_size, point_offset, _vlr_count, point_format, record_length = struct.unpack_from("<HIIBH", head, 94)
    if header_size < _MIN_HEADER or point_offset < header_size:
        raise ReadError(
            f"the LAS header gives a header size of {header_size} bytes and point data at byte {point_offset} "
            f"(a header needs at least {_MIN_HEADER}, and the points follow it); the header is corrupt"
        )
    (count,) = struct.unpack_from("<I", head, 107)
    if minor >= 4 and header_size >= _HEADER_14 and len(head) >= _HEADER_14:
        # LAS 1.4 keeps a 64-bit count; the legacy 32-bit one is 0 for point formats 6-10.
        (count,) = struct.unpack_from("<Q", head, 247)
    return {
        "version": f"{major}.{minor}",
        "compressed": bool(point_format & _COMPRESSED_BITS),
        "point_format": point_format & ~_COMPRESSED_BITS,
        "point_offset": point_offset,
        "record_length": record_length,
        "count": count,
        "scales": struct.unpack_from("<3d", head, 131),
        "offsets": struct.unpack_from("<3d", head, 155),
        "wkt": bool(encoding & _WKT_BIT),
        "system": head[26:58].split(b"\0", 1)[0].decode("ascii", errors="replace").strip(),
        "software": head[58:90].split(b"\0", 1)[0].decode("ascii", errors="replace").strip(),
    }


def _check_point_data_length(header: dict, size: int) -> None:
    needed = header["point_offset"] + header["count"] * header["record_length"]
    if header["record_length"] == 0:
        raise ReadError("the LAS header gives a point record length of 0 bytes; the header is corrupt")
    if size < needed:
        whole = max(0, size - header["point_offset"]) // header["record_length"]
        raise ReadError(
            f"the LAS file ends after {whole} of {header['count']} points ({size} of {needed} bytes; "
            "file truncated?)"
        )


def _decode(target: Path, kind: str) -> tuple[np.ndarray, list[tuple[str, int, bytes]]]:
    """The (n, 3) int32 stored coordinates and every (E)VLR as ``(user_id, record_id, data)``."""
    import laspy  # only uploads of this format pay for the import
    from laspy.errors import LaspyException

    try:
        # lazrs only: laspy would otherwise try the LGPL LASzip bindings when they are installed.
        las = laspy.read(target, laz_backend=(laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs))
    except (LaspyException, RuntimeError, ValueError, EOFError, OSError, struct.error) as exc:
        # lazrs raises a RuntimeError subclass for a cut-off or corrupt compressed stream.
        what = "compressed point data" if kind == "laz" else "file"
        raise ReadError(f"the {kind.upper()} {what} cannot be decoded ({exc}); the file is truncated or "
                        "corrupt") from None
    raw = np.column_stack([np.asarray(las.X), np.asarray(las.Y), np.asarray(las.Z)])
    records = [(v.user_id, v.record_id, v.record_data_bytes()) for v in las.header.vlrs]
    records += [(v.user_id, v.record_id, v.record_data_bytes()) for v in (las.evlrs or [])]
    return raw, records


def _convert_units(points: np.ndarray, records, *, prefer_wkt: bool) -> tuple[np.ndarray, bool, str]:
    units = read_crs_units(records, prefer_wkt=prefer_wkt)
    if units is None:
        has_crs = any(user_id.rstrip("\0") == "LASF_Projection" for user_id, _, _ in records)
        why = "its CRS states no length unit we can read" if has_crs else "it has no CRS record"
        return points, False, (f"the LAS file's unit is unknown ({why}): its coordinates are taken to be in "
                               "ingest.units")
    (h_name, h_metres), (v_name, v_metres) = units.horizontal, units.vertical
    factors = np.array([h_metres, h_metres, v_metres]) * 1000.0
    with np.errstate(over="ignore"):
        points = points * factors
    if h_name == v_name:
        unit = f"{h_name} (x{factors[0]:.10g} to mm)"
    else:
        unit = f"{h_name} horizontally and {v_name} vertically (x{factors[0]:.10g} and x{factors[2]:.10g} to mm)"
    return points, True, (f"the LAS file's CRS ({units.crs}) gives its coordinates in {unit}: converted to mm; "
                          "ingest.units does not apply")
