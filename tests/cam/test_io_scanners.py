"""Scanner formats: E57 (pye57) and LAS/LAZ (laspy + lazrs), every file written here by those libraries.

The oracles are independent of the readers: LAS coordinates are the integers laspy stored times the
header's scale plus its offset; E57 scan frames are built with scipy's rotations from the part-frame
points, and spherical coordinates with atan2/hypot from known cartesian targets.
"""

from __future__ import annotations

import struct
import tempfile
import uuid
from pathlib import Path

import laspy
import numpy as np
import pye57
import pytest
from pye57 import libe57
from scipy.spatial.transform import Rotation

from cam.io import ReadError, read_e57, read_input, read_las
from cam.io.formats import SNIFF_BYTES, sniff_format

RNG = np.random.default_rng(20261126)
US_FOOT_M = 1200 / 3937


# ---------------------------------------------------------------- builders


def write_las(path: Path, points: np.ndarray, *, version: str = "1.4", point_format: int = 6,
              scale: float = 0.001, offset=(0.0, 0.0, 0.0), vlrs=(), global_wkt: bool = False) -> Path:
    """Write `points` (file units) with laspy; a .laz path is compressed with lazrs."""
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([scale] * 3)
    header.offsets = np.asarray(offset, dtype=np.float64)
    for vlr in vlrs:
        header.vlrs.append(vlr)
    if global_wkt:
        header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = points[:, 0], points[:, 1], points[:, 2]
    las.write(str(path), laz_backend=laspy.LazBackend.Lazrs if str(path).endswith(".laz") else None)
    return path


def las_oracle(points: np.ndarray, *, scale: float, offset) -> np.ndarray:
    """What LAS stores: round((p - offset) / scale) as integers, read back as integer * scale + offset."""
    offset = np.asarray(offset, dtype=np.float64)
    return np.round((points - offset) / scale) * scale + offset


def wkt_vlr(wkt: str):
    return laspy.vlrs.known.WktCoordinateSystemVlr(wkt)


def geokeys_vlr(keys: dict[int, int]):
    """A GeoTIFF key directory (version 1.1.0) whose keys all hold their value inline."""
    data = struct.pack("<4H", 1, 1, 0, len(keys))
    for key, value in sorted(keys.items()):
        data += struct.pack("<4H", key, 0, 1, value)
    return laspy.VLR(user_id="LASF_Projection", record_id=34735, description="GeoKeyDirectoryTag",
                     record_data=data)


WKT_FTUS = (
    'PROJCS["NAD83 / California zone 3 (ftUS)",GEOGCS["NAD83",DATUM["North_American_Datum_1983",'
    'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
    'PROJECTION["Lambert_Conformal_Conic_2SP"],UNIT["US survey foot",0.304800609601219],'
    'AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","2227"]]'
)
WKT_COMPOUND_FT_M = (
    'COMPD_CS["ft + m",PROJCS["some (ft)",GEOGCS["NAD83",UNIT["degree",0.0174532925199433]],'
    'UNIT["foot",0.3048]],VERT_CS["NAVD88",VERT_DATUM["NAVD88",2005],UNIT["metre",1.0],AXIS["Up",UP]]]'
)
WKT2_METRE = (
    'PROJCRS["WGS 84 / UTM zone 33N",BASEGEOGCRS["WGS 84",DATUM["World Geodetic System 1984",'
    'ELLIPSOID["WGS 84",6378137,298.257223563,LENGTHUNIT["metre",1]]],ANGLEUNIT["degree",0.0174532925199433]],'
    'CONVERSION["UTM zone 33N",METHOD["Transverse Mercator"],PARAMETER["False easting",500000,'
    'LENGTHUNIT["metre",1]]],CS[Cartesian,2],AXIS["(E)",east,ORDER[1],LENGTHUNIT["metre",1]],'
    'AXIS["(N)",north,ORDER[2],LENGTHUNIT["metre",1]]]'
)
WKT_GEOGRAPHIC = (
    'GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],PRIMEM["Greenwich",0],'
    'UNIT["degree",0.0174532925199433]]'
)


def write_e57_raw(path: Path, points: np.ndarray, *, rotation=None, translation=None) -> Path:
    """One cartesian scan written with pye57's own writer (single-precision floats)."""
    with pye57.E57(str(path), mode="w") as e57:
        e57.write_scan_raw({"cartesianX": points[:, 0], "cartesianY": points[:, 1], "cartesianZ": points[:, 2]},
                           rotation=rotation, translation=translation)
    return path


def write_e57_scans(path: Path, scans: list[dict]) -> Path:
    """Scans written through libE57's node API, each a dict of fields and an optional pose:
    ``{"fields": {name: array}, "quaternion": (w, x, y, z), "translation": (x, y, z), "scale": s}``; float
    fields are doubles, or scaled integers of quantum ``s`` (as many scanners write them) when given."""
    e57 = pye57.E57(str(path), mode="w")
    image = e57.image_file
    for scan in scans:
        node = libe57.StructureNode(image)
        node.set("guid", libe57.StringNode(image, f"{{{uuid.uuid4()}}}"))
        if "quaternion" in scan:
            pose = libe57.StructureNode(image)
            rotation = libe57.StructureNode(image)
            translation = libe57.StructureNode(image)
            for name, value in zip("wxyz", scan["quaternion"], strict=True):
                rotation.set(name, libe57.FloatNode(image, float(value)))
            for name, value in zip("xyz", scan["translation"], strict=True):
                translation.set(name, libe57.FloatNode(image, float(value)))
            pose.set("rotation", rotation)
            pose.set("translation", translation)
            node.set("pose", pose)
        prototype = libe57.StructureNode(image)
        fields = scan["fields"]
        for name, values in fields.items():
            if values.dtype.kind == "f" and "scale" in scan:
                prototype.set(name, libe57.ScaledIntegerNode(image, 0, -(2**40), 2**40, scan["scale"], 0.0))
            elif values.dtype.kind == "f":
                prototype.set(name, libe57.FloatNode(image, 0.0, libe57.E57_DOUBLE,
                                                     libe57.E57_DOUBLE_MIN, libe57.E57_DOUBLE_MAX))
            else:
                top = int(values.max()) if len(values) else 2
                prototype.set(name, libe57.IntegerNode(image, 0, 0, max(top, 2)))
        points = libe57.CompressedVectorNode(image, prototype, libe57.VectorNode(image, True))
        node.set("points", points)
        e57.data3d.append(node)
        count = len(next(iter(fields.values())))
        if count:
            # int16 buffers: pye57 reads numpy's int64 code 'l' as a 32-bit long.
            arrays = {name: (v.astype(np.float64) if v.dtype.kind == "f" else v.astype(np.int16))
                      for name, v in fields.items()}
            buffers = libe57.VectorSourceDestBuffer()
            for name, array in arrays.items():
                buffers.append(libe57.SourceDestBuffer(image, name, array, count, True, True))
            writer = points.writer(buffers)
            writer.write(count)
            writer.close()
    e57.close()
    return path


def write_e57_without_scans(path: Path) -> Path:
    pye57.E57(str(path), mode="w").close()
    return path


def scanner_bytes(suffix: str, write, *args, **kwargs) -> bytes:
    """The bytes of a file that `write(path, *args, **kwargs)` makes (for upload tests)."""
    with tempfile.TemporaryDirectory() as folder:
        return write(Path(folder) / f"scan{suffix}", *args, **kwargs).read_bytes()


def cartesian(points: np.ndarray, **extra) -> dict[str, np.ndarray]:
    return {"cartesianX": points[:, 0], "cartesianY": points[:, 1], "cartesianZ": points[:, 2], **extra}


def scan_frame(part_points: np.ndarray, rotation: Rotation, translation: np.ndarray) -> np.ndarray:
    """The scanner-frame coordinates of part-frame points seen from pose (rotation, translation)."""
    return rotation.inv().apply(part_points - translation)


def wxyz(rotation: Rotation) -> np.ndarray:
    x, y, z, w = rotation.as_quat()
    return np.array([w, x, y, z])


def box_surface(n: int) -> np.ndarray:
    """n points on the faces of a 0.2 x 0.1 x 0.05 m box (a part-sized scene, metres)."""
    size = np.array([0.2, 0.1, 0.05])
    p = RNG.uniform(0, 1, (n, 3)) * size
    axis = RNG.integers(0, 3, n)
    p[np.arange(n), axis] = RNG.integers(0, 2, n) * size[axis]
    return p


# ---------------------------------------------------------------- LAS / LAZ


@pytest.mark.parametrize(("version", "point_format"), [("1.2", 0), ("1.2", 3), ("1.4", 6), ("1.4", 7)])
def test_las_points_round_trip_to_the_quantum(tmp_path, version, point_format):
    pts = RNG.uniform(-50, 250, (500, 3))
    offset = (100.0, -20.0, 5.0)
    path = write_las(tmp_path / "a.las", pts, version=version, point_format=point_format, scale=0.01, offset=offset)
    data = read_las(path)
    np.testing.assert_array_equal(data.points, las_oracle(pts, scale=0.01, offset=offset))
    assert np.abs(data.points - pts).max() <= 0.005 + 1e-9  # half the scale
    assert data.format == "las" and data.normals is None and data.faces is None
    assert data.in_mm is False and "unit is unknown" in data.notes[1] and "no CRS" in data.notes[1]


def test_laz_equals_las(tmp_path):
    pts = RNG.uniform(0, 80, (3000, 3))
    las = read_las(write_las(tmp_path / "a.las", pts, scale=0.001, offset=(10.0, 10.0, 0.0)))
    laz = read_las(write_las(tmp_path / "a.laz", pts, scale=0.001, offset=(10.0, 10.0, 0.0)))
    np.testing.assert_array_equal(laz.points, las.points)
    assert (las.format, laz.format) == ("las", "laz")
    assert (tmp_path / "a.laz").stat().st_size < (tmp_path / "a.las").stat().st_size / 2


def test_las_in_us_survey_feet_is_converted_to_mm(tmp_path):
    pts = RNG.uniform(0, 3, (200, 3))  # feet
    path = write_las(tmp_path / "ft.las", pts, scale=0.0001, vlrs=[wkt_vlr(WKT_FTUS)], version="1.4",
                     global_wkt=True)
    data = read_las(path)
    np.testing.assert_allclose(data.points, las_oracle(pts, scale=0.0001, offset=(0, 0, 0)) * US_FOOT_M * 1000,
                               rtol=1e-12)
    assert data.in_mm is True
    assert "US survey foot" in data.notes[1] and "converted to mm" in data.notes[1]


def test_compound_crs_scales_horizontal_and_vertical_units_apart(tmp_path):
    pts = RNG.uniform(0, 3, (100, 3))
    data = read_las(write_las(tmp_path / "c.las", pts, vlrs=[wkt_vlr(WKT_COMPOUND_FT_M)], global_wkt=True))
    expected = las_oracle(pts, scale=0.001, offset=(0, 0, 0)) * np.array([304.8, 304.8, 1000.0])
    np.testing.assert_allclose(data.points, expected, rtol=1e-12)
    assert "foot horizontally and metre vertically" in data.notes[1]


def test_wkt2_metres_and_geotiff_feet(tmp_path):
    pts = RNG.uniform(0, 3, (100, 3))
    stored = las_oracle(pts, scale=0.001, offset=(0, 0, 0))
    metres = read_las(write_las(tmp_path / "m.las", pts, vlrs=[wkt_vlr(WKT2_METRE)], global_wkt=True))
    np.testing.assert_allclose(metres.points, stored * 1000.0, rtol=1e-12)
    # GeoTIFF keys: projected model, ProjLinearUnitsGeoKey = 9002 (international foot).
    feet = read_las(write_las(tmp_path / "f.las", pts, version="1.2", point_format=1,
                              vlrs=[geokeys_vlr({1024: 1, 3072: 2227, 3076: 9002})]))
    np.testing.assert_allclose(feet.points, stored * 304.8, rtol=1e-12)
    assert feet.in_mm and "EPSG:2227" in feet.notes[1]
    # An EPSG code alone states no unit (no projection database here), except WGS 84 / UTM's metres.
    unstated = read_las(write_las(tmp_path / "u.las", pts, version="1.2", point_format=1,
                                  vlrs=[geokeys_vlr({1024: 1, 3072: 2227})]))
    assert not unstated.in_mm and "states no length unit" in unstated.notes[1]
    utm = read_las(write_las(tmp_path / "utm.las", pts, version="1.2", point_format=1,
                             vlrs=[geokeys_vlr({1024: 1, 3072: 32633})]))
    np.testing.assert_allclose(utm.points, stored * 1000.0, rtol=1e-12)


@pytest.mark.parametrize("vlr", [wkt_vlr(WKT_GEOGRAPHIC), geokeys_vlr({1024: 2, 2048: 4326})],
                         ids=["wkt", "geotiff"])
def test_las_in_degrees_is_refused(tmp_path, vlr):
    path = write_las(tmp_path / "geo.las", RNG.uniform(0, 1, (50, 3)), vlrs=[vlr], global_wkt=True)
    with pytest.raises(ReadError, match="longitude and latitude in degrees"):
        read_las(path)


def test_truncated_las_names_the_points_it_holds(tmp_path):
    path = write_las(tmp_path / "a.las", RNG.uniform(0, 1, (1000, 3)), version="1.2", point_format=0)
    data = path.read_bytes()
    record = 20  # point format 0
    cut = tmp_path / "cut.las"
    cut.write_bytes(data[: len(data) - 250 * record - 7])
    with pytest.raises(ReadError, match=r"ends after 749 of 1000 points .*truncated"):
        read_las(cut)
    cut.write_bytes(data[:100])
    with pytest.raises(ReadError, match=r"header is cut short.*truncated"):
        read_input(cut)
    corrupt = bytearray(data)
    corrupt[94:96] = struct.pack("<H", 100)  # header size
    cut.write_bytes(bytes(corrupt))
    with pytest.raises(ReadError, match="header size of 100 bytes .* corrupt"):
        read_input(cut)


@pytest.mark.parametrize("keep", [0.5, 0.99])
def test_truncated_laz_is_refused_not_misread(tmp_path, keep):
    path = write_las(tmp_path / "a.laz", RNG.uniform(0, 1, (20000, 3)))
    data = path.read_bytes()
    cut = tmp_path / "cut.laz"
    cut.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ReadError, match="LAZ .*truncated or corrupt"):
        read_las(cut)


def test_empty_las_and_the_point_limit(tmp_path):
    empty = write_las(tmp_path / "e.las", np.empty((0, 3)))
    with pytest.raises(ReadError, match="holds no points"):
        read_input(empty)
    path = write_las(tmp_path / "a.laz", RNG.uniform(0, 1, (1000, 3)))
    with pytest.raises(ReadError, match="1000 points, more than the limit of 999"):
        read_input(path, max_points=999)
    assert len(read_input(path, max_points=1000).points) == 1000


# ---------------------------------------------------------------- E57


def test_e57_points_round_trip_to_single_precision(tmp_path):
    pts = RNG.uniform(-2, 2, (2000, 3))  # metres
    data = read_e57(write_e57_raw(tmp_path / "a.e57", pts))
    # pye57 writes single-precision floats; the reader turns metres into mm.
    np.testing.assert_array_equal(data.points, pts.astype(np.float32).astype(np.float64) * 1000.0)
    assert data.format == "e57" and data.in_mm and data.normals is None and data.colors is None
    assert "metres" in data.notes[1] and "converted to mm" in data.notes[1]


def test_e57_scaled_integer_coordinates_round_trip_to_their_quantum(tmp_path):
    pts = RNG.uniform(-3, 3, (2000, 3))
    data = read_e57(write_e57_scans(tmp_path / "q.e57", [{"fields": cartesian(pts), "scale": 1e-4}]))
    # libE57 stores floor(x / scale + 0.5) and reads back that integer times the scale.
    np.testing.assert_array_equal(data.points, np.floor(pts / 1e-4 + 0.5) * 1e-4 * 1000.0)
    assert np.abs(data.points - pts * 1000.0).max() <= 0.05 + 1e-9  # half the quantum, in mm


def test_two_scans_merge_into_the_part_frame(tmp_path):
    part = box_surface(3000)
    poses = [(Rotation.from_euler("zyx", [30, -10, 5], degrees=True), np.array([1.5, -0.4, 0.3])),
             (Rotation.from_euler("zyx", [-140, 20, 0], degrees=True), np.array([-1.2, 0.9, 0.6]))]
    halves = [part[:1800], part[1800:]]
    scans = [{"fields": cartesian(scan_frame(h, r, t)), "quaternion": wxyz(r), "translation": t}
             for h, (r, t) in zip(halves, poses, strict=True)]
    data = read_e57(write_e57_scans(tmp_path / "two.e57", scans))
    np.testing.assert_allclose(data.points, part * 1000.0, atol=1e-9)
    # Without the poses the scans would not meet: the scanner frames are metres away from the part.
    assert np.abs(scans[0]["fields"]["cartesianX"] - part[:1800, 0]).max() > 0.5
    assert "2 scan(s) merged" in data.notes[0]


def test_pye57_poses_match(tmp_path):
    part = box_surface(500)
    rotation, translation = Rotation.from_euler("xyz", [12, 40, -75], degrees=True), np.array([0.2, 0.3, -1.0])
    local = scan_frame(part, rotation, translation)
    data = read_e57(write_e57_raw(tmp_path / "p.e57", local, rotation=wxyz(rotation), translation=translation))
    # Single-precision scanner-frame coordinates within 1.5 m: under 2e-7 m per coordinate.
    np.testing.assert_allclose(data.points, part * 1000.0, atol=5e-4)


def test_structured_spherical_scan_converts_and_drops_invalid_points(tmp_path):
    rows, cols = 30, 40
    # Targets on a wall in front of the scanner (x = 2 m), seen on a row/column grid.
    y, z = np.meshgrid(np.linspace(-0.8, 0.8, cols), np.linspace(-0.5, 0.6, rows))
    targets = np.column_stack([np.full(y.size, 2.0), y.ravel(), z.ravel()])
    rng_ = np.linalg.norm(targets, axis=1)
    azimuth = np.arctan2(targets[:, 1], targets[:, 0])
    elevation = np.arctan2(targets[:, 2], np.hypot(targets[:, 0], targets[:, 1]))
    invalid = np.zeros(rows * cols, dtype=np.int64)
    invalid[::7] = 2  # no return
    invalid[3::11] = 1  # direction only
    junk = np.where(invalid > 0, 0.0, rng_)
    row, col = np.divmod(np.arange(rows * cols), cols)
    rotation, translation = Rotation.from_euler("z", 90, degrees=True), np.array([0.5, 0.0, 1.0])
    fields = {"sphericalRange": junk, "sphericalAzimuth": azimuth, "sphericalElevation": elevation,
              "rowIndex": row, "columnIndex": col, "sphericalInvalidState": invalid}
    data = read_e57(write_e57_scans(tmp_path / "s.e57", [{"fields": fields, "quaternion": wxyz(rotation),
                                                            "translation": translation}]))
    keep = invalid == 0
    np.testing.assert_allclose(data.points, (rotation.apply(targets[keep]) + translation) * 1000.0, atol=1e-9)
    assert len(data.points) == keep.sum() < rows * cols
    assert f"{(~keep).sum()} flagged invalid dropped" in data.notes[0]


def test_cartesian_invalid_state_is_dropped(tmp_path):
    pts = RNG.uniform(0, 1, (100, 3))
    state = np.zeros(100, dtype=np.int64)
    state[[0, 5, 99]] = [2, 1, 2]
    data = read_e57(write_e57_scans(tmp_path / "i.e57", [{"fields": cartesian(pts, cartesianInvalidState=state)}]))
    np.testing.assert_array_equal(data.points, np.delete(pts, [0, 5, 99], axis=0) * 1000.0)


def test_truncated_e57_is_named(tmp_path):
    data = write_e57_raw(tmp_path / "a.e57", RNG.uniform(0, 1, (5000, 3))).read_bytes()
    cut = tmp_path / "cut.e57"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ReadError, match=rf"truncated: its header says {len(data)} bytes, the file has"):
        read_input(cut)
    cut.write_bytes(data[:30])
    with pytest.raises(ReadError, match="header is cut short"):
        read_input(cut)


def test_damaged_e57_page_is_a_read_error(tmp_path):
    data = bytearray(write_e57_raw(tmp_path / "a.e57", RNG.uniform(0, 1, (5000, 3))).read_bytes())
    data[2000:2100] = bytes(100)  # inside the binary section, the page checksum no longer matches
    bad = tmp_path / "bad.e57"
    bad.write_bytes(bytes(data))
    with pytest.raises(ReadError, match="E57 .*corrupt or truncated"):
        read_input(bad)


def test_empty_e57s_are_named(tmp_path):
    no_scan = write_e57_without_scans(tmp_path / "none.e57")
    with pytest.raises(ReadError, match="holds no 3D scan"):
        read_input(no_scan)
    empty = write_e57_scans(tmp_path / "empty.e57", [{"fields": cartesian(np.empty((0, 3)))}])
    with pytest.raises(ReadError, match="hold no points: the scan is empty"):
        read_input(empty)
    pts = RNG.uniform(0, 1, (50, 3))
    all_invalid = write_e57_scans(tmp_path / "invalid.e57",
                                  [{"fields": cartesian(pts, cartesianInvalidState=np.full(50, 2))}])
    with pytest.raises(ReadError, match="all 50 points .* are flagged invalid"):
        read_input(all_invalid)


def test_e57_point_limit_counts_valid_points(tmp_path):
    pts = RNG.uniform(0, 1, (1000, 3))
    state = (np.arange(1000) % 4 == 0).astype(np.int64)  # 250 invalid, 750 valid
    path = write_e57_scans(tmp_path / "l.e57", [{"fields": cartesian(pts, cartesianInvalidState=state)}])
    assert len(read_input(path, max_points=750).points) == 750
    with pytest.raises(ReadError, match="more than 749 valid points"):
        read_input(path, max_points=749)


def test_bad_pose_is_refused(tmp_path):
    path = write_e57_scans(tmp_path / "q.e57", [{"fields": cartesian(RNG.uniform(0, 1, (10, 3))),
                                                  "quaternion": (2.0, 0, 0, 0), "translation": (0, 0, 0)}])
    with pytest.raises(ReadError, match="not a unit quaternion"):
        read_e57(path)


# ---------------------------------------------------------------- sniffing from content


@pytest.mark.parametrize("name", ["scan", "scan.xyz", "scan.ply", "scan.las", "scan.e57"])
def test_scanner_files_are_recognised_from_content_whatever_their_name(tmp_path, name):
    pts = RNG.uniform(0, 1, (300, 3))
    made = {
        "e57": write_e57_raw(tmp_path / "src.e57", pts),
        "las": write_las(tmp_path / "src.las", pts),
        "laz": write_las(tmp_path / "src.laz", pts),
    }
    for kind, source in made.items():
        renamed = tmp_path / "renamed" / kind / name
        renamed.parent.mkdir(parents=True)
        renamed.write_bytes(source.read_bytes())
        head = renamed.read_bytes()[:SNIFF_BYTES]
        assert sniff_format(head, total_size=renamed.stat().st_size) == kind
        data = read_input(renamed)
        assert data.format == kind and len(data.points) == 300


def test_cut_scanner_headers_are_still_recognised():
    assert sniff_format(b"ASTM-E57") == "e57"
    assert sniff_format(b"LASF" + bytes(60)) == "las"
    # Unknown versions are refused and described, not read.
    assert sniff_format(b"ASTM-E57" + struct.pack("<II", 2, 0) + bytes(40)) is None
    assert sniff_format(b"LASF" + bytes(20) + bytes([2, 0]) + bytes(300)) is None
