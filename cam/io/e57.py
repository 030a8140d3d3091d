"""Read ASTM E57 scans: every 3D scan of the file, placed by its pose and merged into one cloud.

pye57 (MIT, bundling libE57Format under the Boost licence and Xerces-C under Apache 2.0) opens the file;
the points are read scan by scan in blocks, so memory follows the points kept, not the scan's size.

E57 coordinates are metres (ASTM E2807, 8.4.1), so the points are converted to mm and ``ingest.units`` does
not apply. Each scan's points are in its own frame; its pose (a unit quaternion ``w x y z`` and a
translation) takes them to the file's frame: ``p_file = R(q) p_scan + t``. Spherical coordinates (range,
azimuth from +x towards +y, elevation from the xy plane towards +z) are converted; points whose
``cartesianInvalidState`` / ``sphericalInvalidState`` is not 0 (no return, or direction only) are dropped.
Intensity, colour, row/column indices and images are ignored.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from cam.io._files import read_head
from cam.io.errors import ReadError
from cam.io.records import InputData

__all__ = ["read_e57"]

_SIGNATURE = b"ASTM-E57"
_HEADER = struct.Struct("<8sIIQQQQ")
_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
_MM_PER_METRE = 1000.0
# Points read per block: big enough that the per-call overhead vanishes, small enough to stay a few MB.
_BLOCK = 1 << 18


def read_e57(path: str | os.PathLike[str], *, max_points: int | None = None) -> InputData:
    """Read every 3D scan of an E57 file into one point cloud in the file's frame, in mm.

    Parameters
    ----------
    path : str or os.PathLike
        The E57 file.
    max_points : int or None, keyword-only
        Stop and refuse once more valid points than this have been read (the operator's ``max_points``);
        invalid points do not count, since a structured scan holds many.

    Returns
    -------
    data : InputData
        ``points`` (n, 3) float64 in mm (``in_mm`` True), the scans' valid points in file order after each
        scan's pose; ``normals`` and ``colors`` None; ``format`` ``"e57"``; ``notes`` say how many scans
        were merged, how many points were dropped as invalid and that metres became mm.

    Raises
    ------
    ReadError
        For a missing file, a file shorter than its header says (truncated) or with a damaged page, a file
        with no 3D scan, scans without x/y/z or range/azimuth/elevation, a pose that is not a rotation, no
        valid point at all, or more valid points than `max_points`.
    """
    target = Path(path)
    _check_header(target)
    from pye57 import libe57  # only uploads of this format pay for the import

    try:
        image = libe57.ImageFile(str(target), "r")
    except libe57.E57Exception as exc:
        raise ReadError(f"the E57 file cannot be opened ({_first_line(exc)}); it is corrupt or truncated") from None
    try:
        return _read_scans(image, libe57, max_points=max_points)
    except libe57.E57Exception as exc:
        raise ReadError(
            f"the E57 file's point data cannot be read ({_first_line(exc)}); it is corrupt or truncated"
        ) from None
    finally:
        image.close()


def _first_line(exc: Exception) -> str:
    # libE57's message goes on with debug lines naming source files and the server's paths.
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _check_header(target: Path) -> None:
    head, size = read_head(target, _HEADER.size)
    if not head.startswith(_SIGNATURE):
        raise ReadError(f"{target.name} does not start with E57's signature 'ASTM-E57'; it is not an E57 file")
    if len(head) < _HEADER.size:
        raise ReadError(
            f"the E57 header is cut short: the file has {size} bytes, the header alone needs {_HEADER.size} "
            "(file truncated?)"
        )
    _, major, minor, length, xml_offset, xml_length, page_size = _HEADER.unpack(head)
    if major != 1:
        raise ReadError(f"E57 version {major}.{minor} is not one we read (1.x)")
    if size < length:
        raise ReadError(
            f"the E57 file is truncated: its header says {length} bytes, the file has {size} (upload cut off?)"
        )
    if size != length or page_size == 0 or xml_offset + xml_length > length:
        raise ReadError(
            f"the E57 header is inconsistent (file length {length} for {size} bytes, XML section at "
            f"{xml_offset} of {xml_length} bytes, page size {page_size}); the file is corrupt"
        )


def _read_scans(image, libe57, *, max_points: int | None) -> InputData:
    root = image.root()
    if not root.isDefined("data3D") or root["data3D"].childCount() == 0:
        raise ReadError("the E57 file holds no 3D scan (its data3D list is empty); there are no points to read")
    scans = root["data3D"]
    blocks: list[np.ndarray] = []
    kept = stored = 0
    for index in range(scans.childCount()):
        scan = scans[index]
        points, count = _read_scan(image, libe57, scan, index, budget=None if max_points is None
                                   else max_points - kept)
        stored += count
        kept += len(points)
        if max_points is not None and kept > max_points:
            raise ReadError(
                f"the E57 file holds more than {max_points} valid points (the limit; reached in scan "
                f"{index + 1} of {scans.childCount()}); subsample it below {max_points} points (e.g. "
                "CloudCompare's Subsample tool) and upload again; the limit is set by whoever runs the service"
            )
        blocks.append(points)
    if stored == 0:
        raise ReadError(f"the E57 file's {scans.childCount()} scan(s) hold no points: the scan is empty")
    if kept == 0:
        raise ReadError(
            f"all {stored} points of the E57 file's {scans.childCount()} scan(s) are flagged invalid "
            "(cartesianInvalidState or sphericalInvalidState): the scan has no measured point"
        )
    notes = [
        (f"E57: {scans.childCount()} scan(s) merged, each placed by its pose; {kept} points read"
         + (f", {stored - kept} flagged invalid dropped" if stored > kept else "")),
        ("E57 coordinates are metres by the standard: converted to mm (x1000); ingest.units does not apply; "
         "intensity and colour are ignored"),
    ]
    return InputData(points=np.concatenate(blocks) * _MM_PER_METRE, format="e57", notes=tuple(notes), in_mm=True)


def _read_scan(image, libe57, scan, index: int, *, budget: int | None) -> tuple[np.ndarray, int]:
    """One scan's valid points in the file's frame, metres, and how many points it stores."""
    if not scan.isDefined("points"):
        raise ReadError(f"E57 scan {index + 1} has no points node; the file is malformed")
    node = scan["points"]
    prototype = libe57.StructureNode(node.prototype())
    fields = {prototype.get(i).elementName() for i in range(prototype.childCount())}
    if set(_CARTESIAN) <= fields:
        coordinates, state = _CARTESIAN, "cartesianInvalidState"
    elif set(_SPHERICAL) <= fields:
        coordinates, state = _SPHERICAL, "sphericalInvalidState"
    else:
        raise ReadError(
            f"E57 scan {index + 1} has neither cartesianX/Y/Z nor sphericalRange/Azimuth/Elevation fields "
            f"(it has {', '.join(sorted(fields)) or 'none'}); cannot find the coordinates"
        )
    rotation, translation = _pose(scan, index)
    count = node.childCount()
    if count == 0:
        return np.empty((0, 3)), 0
    capacity = min(count, _BLOCK)
    arrays = {name: np.empty(capacity, np.float64) for name in coordinates}
    if state in fields:
        # float64, not int64: pye57 maps numpy's 'l' code to a 32-bit long and would misread int64 buffers.
        arrays[state] = np.empty(capacity, np.float64)
    buffers = libe57.VectorSourceDestBuffer()
    for name, array in arrays.items():
        buffers.append(libe57.SourceDestBuffer(image, name, array, capacity, True, True))
    reader = node.reader(buffers)
    blocks = []
    kept = 0
    try:
        while (got := reader.read()) > 0:
            valid = arrays[state][:got] == 0 if state in arrays else np.ones(got, dtype=bool)
            block = np.column_stack([arrays[name][:got][valid] for name in coordinates])
            if coordinates is _SPHERICAL:
                block = _spherical_to_cartesian(block)
            blocks.append(block)
            kept += len(block)
            if budget is not None and kept > budget:
                break  # the caller refuses the file; reading on would only cost memory
    finally:
        reader.close()
    points = np.concatenate(blocks) if blocks else np.empty((0, 3))
    return points @ rotation.T + translation, count


def _spherical_to_cartesian(rae: np.ndarray) -> np.ndarray:
    """(n, 3) range, azimuth, elevation (m, rad, rad) to (n, 3) x, y, z in m (E57's convention)."""
    r, azimuth, elevation = rae[:, 0], rae[:, 1], rae[:, 2]
    planar = r * np.cos(elevation)
    return np.column_stack([planar * np.cos(azimuth), planar * np.sin(azimuth), r * np.sin(elevation)])


def _pose(scan, index: int) -> tuple[np.ndarray, np.ndarray]:
    """The (3, 3) rotation and (3,) translation of a scan's pose; identity where the file gives none."""
    rotation, translation = np.eye(3), np.zeros(3)
    if not scan.isDefined("pose"):
        return rotation, translation
    pose = scan["pose"]
    if pose.isDefined("rotation"):
        q = np.array([_number(pose["rotation"], k, default=1.0 if k == "w" else 0.0) for k in "wxyz"])
        norm = float(np.linalg.norm(q))
        # The standard asks for a unit quaternion; writers round it, so only a clearly wrong one is refused.
        if not np.isfinite(q).all() or abs(norm - 1.0) > 1e-3:
            raise ReadError(
                f"E57 scan {index + 1}'s pose rotation (w, x, y, z) = {q.tolist()} is not a unit quaternion; "
                "the scan cannot be placed"
            )
        rotation = _quaternion_matrix(q / norm)
    if pose.isDefined("translation"):
        translation = np.array([_number(pose["translation"], k, default=0.0) for k in "xyz"])
        if not np.isfinite(translation).all():
            raise ReadError(f"E57 scan {index + 1}'s pose translation {translation.tolist()} is not finite")
    return rotation, translation


def _number(node, name: str, *, default: float) -> float:
    return float(node[name].value()) if node.isDefined(name) else default


def _quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
