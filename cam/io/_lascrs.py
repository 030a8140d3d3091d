"""The length unit a LAS file's coordinate reference system states, from its WKT or GeoTIFF key records.

LAS stores its CRS in a variable length record of user id ``LASF_Projection``: OGC WKT (record 2112, WKT1 or
WKT2) or GeoTIFF keys (record 34735, with doubles in record 34736). Only the linear unit is read here, with
no projection database: a CRS named only by its EPSG code states no unit unless the code is one whose unit
is fixed by its range (WGS 84 / UTM zones) or a geographic one (degrees).
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass

from cam.io.errors import ReadError

__all__ = ["LAS_PROJECTION", "CrsUnits", "read_crs_units"]

LAS_PROJECTION = "LASF_Projection"
_WKT_RECORD = 2112
_GEOKEYS_RECORD = 34735
_GEODOUBLES_RECORD = 34736

# GeoTIFF keys (GeoTIFF 1.0, section 6.2) and EPSG linear unit codes, in metres per unit.
_MODEL_TYPE, _PROJECTED_CS, _LINEAR_UNITS, _LINEAR_UNIT_SIZE = 1024, 3072, 3076, 3077
_GEOGRAPHIC_TYPE, _GEOG_LINEAR_UNITS, _VERTICAL_UNITS = 2048, 2052, 4099
_MODEL_PROJECTED, _MODEL_GEOGRAPHIC, _MODEL_GEOCENTRIC = 1, 2, 3
_USER_DEFINED = 32767
_EPSG_UNITS = {
    9001: ("metre", 1.0),
    9002: ("foot", 0.3048),
    9003: ("US survey foot", 1200 / 3937),
    9030: ("nautical mile", 1852.0),
    9036: ("kilometre", 1000.0),
    9096: ("yard", 0.9144),
    1025: ("millimetre", 0.001),
    1033: ("centimetre", 0.01),
}
_GEOGRAPHIC_EPSG = frozenset({4326, 4269, 4258, 4283, 4617, 4979, 4937, 7844})

_WKT_TOKEN = re.compile(r'\s*(?:"((?:[^"]|"")*)"|([A-Za-z_][A-Za-z0-9_]*)\s*[\[(]|([\])])|(,)|([^,\[\]()"]+))')
_PROJECTED = {"PROJCS", "PROJCRS", "PROJECTEDCRS"}
_GEOGRAPHIC = {"GEOGCS", "GEOGCRS", "GEOGRAPHICCRS"}
_GEOCENTRIC = {"GEOCCS"}
_GEODETIC = {"GEODCRS", "GEODETICCRS"}
_VERTICAL = {"VERT_CS", "VERTCRS", "VERTICALCRS"}
_COMPOUND = {"COMPD_CS", "COMPOUNDCRS"}
_UNIT_KEYWORDS = {"UNIT", "LENGTHUNIT"}
_ANGULAR_NAMES = ("degree", "radian", "grad", "gon", "arc-second", "arc-minute", "arc second", "arc minute")


@dataclass(frozen=True)
class CrsUnits:
    """The units a CRS states: ``horizontal`` for x and y, ``vertical`` for z, each ``(name, metres per
    unit)``; ``vertical`` is the horizontal unit when the CRS has no vertical part. ``crs`` names the CRS."""

    crs: str
    horizontal: tuple[str, float]
    vertical: tuple[str, float]


def read_crs_units(records: list[tuple[str, int, bytes]], *, prefer_wkt: bool) -> CrsUnits | None:
    """Find the length units of a LAS file's CRS.

    Parameters
    ----------
    records : list of (str, int, bytes)
        Every VLR and EVLR of the file as ``(user_id, record_id, record_data)``.
    prefer_wkt : bool
        The header's WKT bit (LAS 1.4): WKT is read before GeoTIFF keys when both are present.

    Returns
    -------
    units : CrsUnits or None
        None when the file has no CRS record or its CRS states no linear unit.

    Raises
    ------
    ReadError
        When the CRS is geographic (x and y are longitude and latitude in degrees, not lengths), or its
        record cannot be parsed.
    """
    by_id = {record_id: data for user_id, record_id, data in records if user_id.rstrip("\0") == LAS_PROJECTION}
    order = (_WKT_RECORD, _GEOKEYS_RECORD) if prefer_wkt else (_GEOKEYS_RECORD, _WKT_RECORD)
    for record_id in order:
        if record_id not in by_id:
            continue
        if record_id == _WKT_RECORD:
            text = by_id[record_id].split(b"\0", 1)[0].decode("utf-8", errors="replace").strip()
            if text:
                return _units_from_wkt(text)
        else:
            return _units_from_geokeys(by_id[record_id], by_id.get(_GEODOUBLES_RECORD, b""))
    return None


# --- WKT ---------------------------------------------------------------------------------------------


def _units_from_wkt(text: str) -> CrsUnits | None:
    root = _parse_wkt(text)
    name = _node_name(root)
    keyword = root[0]
    if keyword in _COMPOUND:
        parts = [child for child in root[1] if isinstance(child, tuple)]
        horizontal = next((p for p in parts if p[0] not in _VERTICAL), None)
        vertical = next((p for p in parts if p[0] in _VERTICAL), None)
    else:
        horizontal, vertical = root, None
    if horizontal is None:
        return None
    _refuse_geographic(horizontal)
    h_unit = _linear_unit(horizontal)
    v_unit = _linear_unit(vertical) if vertical is not None else None
    if h_unit is None:
        return None
    return CrsUnits(crs=name, horizontal=h_unit, vertical=v_unit or h_unit)


def _refuse_geographic(node: tuple) -> None:
    keyword = node[0]
    ellipsoidal = keyword in _GEODETIC and any(
        isinstance(c, tuple) and c[0] == "CS" and c[1] and str(c[1][0]).lower() == "ellipsoidal" for c in node[1]
    )
    if keyword in _GEOGRAPHIC or ellipsoidal:
        raise ReadError(
            f"the LAS file's coordinates are longitude and latitude in degrees (its CRS is the geographic "
            f"{_node_name(node)!r}), not lengths; reproject the cloud to a projected CRS in metres (e.g. with "
            "PDAL or CloudCompare) and upload it again"
        )


def _linear_unit(node: tuple) -> tuple[str, float] | None:
    """The unit that is a child of `node` (or of its AXIS children), never one of a nested base CRS."""
    candidates = [c for c in node[1] if isinstance(c, tuple) and c[0] in _UNIT_KEYWORDS]
    for axis in (c for c in node[1] if isinstance(c, tuple) and c[0] == "AXIS"):
        candidates += [c for c in axis[1] if isinstance(c, tuple) and c[0] in _UNIT_KEYWORDS]
    if not candidates and node[0] in _GEOCENTRIC | _GEODETIC:
        return ("metre", 1.0)
    for unit in candidates:
        name = str(unit[1][0]) if unit[1] else ""
        if any(word in name.lower() for word in _ANGULAR_NAMES):
            continue
        try:
            factor = float(unit[1][1])
        except (IndexError, TypeError, ValueError):
            raise ReadError(f"the LAS file's CRS gives unit {name!r} without a valid size in metres") from None
        if not (math.isfinite(factor) and factor > 0):
            raise ReadError(f"the LAS file's CRS gives unit {name!r} a size of {factor} metres")
        return (name, factor)
    return None


def _node_name(node: tuple) -> str:
    return str(node[1][0]) if node[1] and isinstance(node[1][0], str) else node[0]


def _parse_wkt(text: str) -> tuple:
    """Parse WKT into nested ``(KEYWORD, [children])``; quoted strings stay str, bare words and numbers too."""
    stack: list[tuple[str, list]] = [("", [])]
    position = 0
    while position < len(text):
        match = _WKT_TOKEN.match(text, position)
        if match is None or match.end() == position:
            if text[position:].strip():
                raise ReadError(f"the LAS file's WKT CRS cannot be parsed near {text[position:position + 30]!r}")
            break
        position = match.end()
        quoted, keyword, close, _comma, bare = match.groups()
        if keyword is not None:
            stack.append((keyword.upper(), []))
        elif close is not None:
            if len(stack) < 2:
                raise ReadError("the LAS file's WKT CRS has an unbalanced closing bracket")
            node = stack.pop()
            stack[-1][1].append(node)
        elif quoted is not None:
            stack[-1][1].append(quoted.replace('""', '"'))
        elif bare is not None and bare.strip():
            stack[-1][1].append(bare.strip())
    if len(stack) != 1 or not stack[0][1] or not isinstance(stack[0][1][0], tuple):
        raise ReadError("the LAS file's WKT CRS is incomplete (unbalanced brackets); the record is cut short")
    return stack[0][1][0]


# --- GeoTIFF keys -----------------------------------------------------------------------------------


def _units_from_geokeys(directory: bytes, doubles: bytes) -> CrsUnits | None:
    if len(directory) < 8:
        raise ReadError("the LAS file's GeoTIFF key directory (record 34735) is shorter than its 8-byte header")
    count = struct.unpack_from("<4H", directory, 0)[3]
    if len(directory) < 8 * (count + 1):
        raise ReadError(
            f"the LAS file's GeoTIFF key directory lists {count} keys but holds only {len(directory) // 8 - 1}"
        )
    keys = {}
    for i in range(count):
        key, location, _count, value = struct.unpack_from("<4H", directory, 8 * (i + 1))
        keys[key] = (location, value)
    values = {key: _key_value(location, value, doubles) for key, (location, value) in keys.items()}
    model = values.get(_MODEL_TYPE)
    projected_cs = values.get(_PROJECTED_CS)
    # A projected CRS names its geographic base too (GeographicTypeGeoKey): only without a model type or a
    # projected CS does that key say the coordinates themselves are angles.
    bare_geographic = model is None and projected_cs is None and values.get(_GEOGRAPHIC_TYPE) in _GEOGRAPHIC_EPSG
    if model == _MODEL_GEOGRAPHIC or bare_geographic:
        raise ReadError(
            "the LAS file's coordinates are longitude and latitude in degrees (its GeoTIFF keys give a "
            "geographic CRS), not lengths; reproject the cloud to a projected CRS in metres (e.g. with PDAL "
            "or CloudCompare) and upload it again"
        )
    crs = f"EPSG:{projected_cs}" if isinstance(projected_cs, int) and projected_cs != _USER_DEFINED else "GeoTIFF keys"
    unit_key = _GEOG_LINEAR_UNITS if model == _MODEL_GEOCENTRIC else _LINEAR_UNITS
    horizontal = _epsg_unit(values.get(unit_key), values.get(_LINEAR_UNIT_SIZE))
    if horizontal is None and model == _MODEL_GEOCENTRIC:
        horizontal = ("metre", 1.0)
    if horizontal is None and isinstance(projected_cs, int) and _is_utm_wgs84(projected_cs):
        horizontal = ("metre", 1.0)
    if horizontal is None:
        return None
    vertical = _epsg_unit(values.get(_VERTICAL_UNITS), None) or horizontal
    return CrsUnits(crs=crs, horizontal=horizontal, vertical=vertical)


def _key_value(location: int, value: int, doubles: bytes) -> int | float | None:
    if location == 0:
        return value
    if location == _GEODOUBLES_RECORD and 8 * (value + 1) <= len(doubles):
        return struct.unpack_from("<d", doubles, 8 * value)[0]
    return None  # ASCII parameters name things; no unit is an ASCII parameter


def _epsg_unit(code, size) -> tuple[str, float] | None:
    if code == _USER_DEFINED and isinstance(size, float) and math.isfinite(size) and size > 0:
        return ("user-defined unit", size)
    return _EPSG_UNITS.get(code) if isinstance(code, int) else None


def _is_utm_wgs84(code: int) -> bool:
    return 32601 <= code <= 32660 or 32701 <= code <= 32760
