"""Clean an uploaded point cloud or mesh into millimetres, and report what was dropped.

Pure functions: arrays in, a frozen record with arrays and a JSON-ready report
out. The ``ingest`` stage writes the arrays as ``cloud.ply`` or
``mesh_raw.ply`` and the report as ``ingest.json``.

Normals rule
------------
A cloud's normals are kept only if every kept point has a finite, non-zero
normal; they are then scaled to unit length. If any kept point lacks one, all
normals are discarded (``has_normals`` false, ``normals_note`` says how many
were bad) and ``reconstruct`` estimates and orients normals for the whole
cloud, which is more reliable than mixing given and estimated ones.

What a user can change (a file with too few or too many usable points, a mesh with no usable face,
a corrupt face list) raises :class:`IngestError`, a :class:`~cam.GeometryError`; arrays of the wrong
shape or dtype are a caller's bug and raise ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cam import GeometryError
from cam.mesh.rows import first_occurrences
from cam.params import IngestParams

__all__ = ["MM_PER_UNIT", "CleanCloud", "CleanMesh", "IngestError", "clean_cloud", "clean_mesh"]

#: Millimetres per unit of the uploaded coordinates, for each value of `IngestParams.units`.
MM_PER_UNIT = {"mm": 1.0, "inch": 25.4}


class IngestError(GeometryError):
    """The upload cannot become a usable cloud or mesh; the message tells the user why and what to do."""


@dataclass(frozen=True, eq=False)
class CleanCloud:
    """A cleaned point cloud.

    points: float64 (n, 3), mm, finite, no exact duplicates, in input order.
    normals: float64 (n, 3) unit vectors, or None.
    report: JSON-ready dict (see :func:`clean_cloud`).
    """

    points: np.ndarray
    normals: np.ndarray | None
    report: dict[str, Any]


@dataclass(frozen=True, eq=False)
class CleanMesh:
    """A cleaned triangle mesh.

    vertices: float64 (n, 3), mm, finite, all referenced, no exact duplicates.
    faces: int64 (m, 3) indices into ``vertices``; no repeated index, zero
    area or duplicate triangle.
    report: JSON-ready dict (see :func:`clean_mesh`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    report: dict[str, Any]


def clean_cloud(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    params: IngestParams = IngestParams(),
    *,
    min_points: int,
    max_points: int,
    format: str | None = None,
    notes: tuple[str, ...] | list[str] = (),
) -> CleanCloud:
    """Scale a point cloud to mm and drop what no later stage can use.

    Parameters
    ----------
    points : ndarray, shape (n, 3), any real or integer dtype
        Coordinates in the file's units (``params.units``).
    normals : ndarray, shape (n, 3), any real or integer dtype, or None
        Normals of any length; see the module docstring for when they are kept.
    params : IngestParams
        ``units``: the file's unit, scaled to mm by :data:`MM_PER_UNIT`.
    min_points, max_points : int
        Bounds on the points that remain (the operator's settings).
    format : str or None
        Copied into the report only when given (so a caller's own value
        survives a dict merge).
    notes : sequence of str
        The reader's notes (:attr:`cam.io.InputData.notes`), copied into the report.

    Returns
    -------
    CleanCloud
        ``points`` float64 (k, 3) in mm, ``normals`` float64 (k, 3) unit
        vectors or None, and the report ``{"kind": "cloud", "format", "units",
        "scale_to_mm", "counts": {"read", "kept"}, "dropped": [{"reason",
        "count", "of"}], "has_normals", "normals_note", "bbox_mm": {"min",
        "max", "size", "diagonal"}, "notes"}``; ``dropped`` lists only reasons
        with a count.

    Raises
    ------
    IngestError
        When no point has finite coordinates, or fewer than ``min_points`` or
        more than ``max_points`` remain.
    ValueError
        When ``points`` or ``normals`` are not (n, 3) numeric arrays of the same length.
    """
    pts, nrm = _check_cloud(points, normals)
    read = len(pts)
    dropped: list[dict[str, Any]] = []
    pts = _scale_to_mm(pts, MM_PER_UNIT[params.units])
    pts, nrm = _drop_non_finite_points(pts, nrm, dropped)
    pts, nrm = _drop_duplicate_points(pts, nrm, dropped)
    _check_point_count(len(pts), read, dropped, min_points=min_points, max_points=max_points)
    nrm, note = _clean_normals(nrm)
    report = _report("cloud", params, {"read": read, "kept": len(pts)}, dropped, pts, notes, format,
                     has_normals=nrm is not None, normals_note=note)
    return CleanCloud(points=pts, normals=nrm, report=report)


def clean_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    params: IngestParams = IngestParams(),
    *,
    max_points: int,
    format: str | None = None,
    notes: tuple[str, ...] | list[str] = (),
) -> CleanMesh:
    """Scale a triangle mesh to mm and remove what would break reconstruction-free processing.

    In order: faces touching a non-finite vertex are dropped; bit-identical
    vertices are merged (split seams from OBJ/PLY exporters would otherwise
    leave holes); faces with a repeated vertex, zero area or a duplicate
    (same three vertices, either orientation) are dropped; unreferenced
    vertices are removed and indices compacted.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3), any real or integer dtype
        Coordinates in the file's units (``params.units``).
    faces : ndarray, shape (m, 3), integer dtype
        Indices into ``vertices``.
    params, format, notes
        As for :func:`clean_cloud`.
    max_points : int
        Bound on the vertices kept.

    Returns
    -------
    CleanMesh
        ``vertices`` float64 (k, 3) in mm, ``faces`` int64 (l, 3) into them,
        and the report of :func:`clean_cloud` with ``kind`` ``"mesh"``,
        ``counts`` adding ``faces_read`` and ``faces_kept``, ``has_normals``
        false and ``normals_note`` None.

    Raises
    ------
    IngestError
        For indices out of range (a corrupt file), no face left, or more than
        ``max_points`` vertices.
    ValueError
        When ``vertices`` is not an (n, 3) numeric array or ``faces`` not (m, 3) integers.
    """
    verts, tris = _check_mesh(vertices, faces)
    read, faces_read = len(verts), len(tris)
    dropped: list[dict[str, Any]] = []
    verts = _scale_to_mm(verts, MM_PER_UNIT[params.units])
    finite, tris = _drop_non_finite_faces(verts, tris, dropped)
    tris, merged = _merge_duplicate_vertices(verts, tris, finite, dropped)
    tris = _drop_degenerate_faces(verts, tris, dropped)
    if len(tris) == 0:
        raise IngestError(
            f"no usable face remains of {faces_read} read{_dropped_clause(dropped)}; "
            "the mesh is empty or degenerate, export it again"
        )
    # Non-finite and merged vertices are unreferenced by now but were counted under their own reason.
    already_counted = merged + int(read - finite.sum())
    verts, tris = _drop_unreferenced_vertices(verts, tris, already_counted, dropped)
    if len(verts) > max_points:
        raise IngestError(
            f"the mesh has {len(verts)} vertices, more than the limit of {max_points}; "
            "decimate it (e.g. MeshLab's Quadric Edge Collapse) and upload again; the limit is "
            "set by whoever runs the service"
        )
    counts = {"read": read, "kept": len(verts), "faces_read": faces_read, "faces_kept": len(tris)}
    report = _report("mesh", params, counts, dropped, verts, notes, format, has_normals=False, normals_note=None)
    return CleanMesh(vertices=verts, faces=tris, report=report)


# --- steps of clean_cloud --------------------------------------------------------------------------


def _check_cloud(points: np.ndarray, normals: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    pts = _rows("points", points)
    nrm = None if normals is None else _rows("normals", normals)
    if nrm is not None and len(nrm) != len(pts):
        raise ValueError(f"there are {len(nrm)} normals for {len(pts)} points; pass one per point")
    if len(pts) == 0:
        raise IngestError("the file holds no points")
    return pts, nrm


def _drop_non_finite_points(pts, nrm, dropped):
    read = len(pts)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        raise IngestError(
            f"all {read} points have non-finite coordinates (NaN or Inf); the file holds no "
            "usable geometry, check the export settings of the scanner software"
        )
    _drop(dropped, "non-finite coordinates", int(read - finite.sum()), "points")
    return pts[finite], (nrm[finite] if nrm is not None else None)


def _drop_duplicate_points(pts, nrm, dropped):
    first = first_occurrences(pts)
    _drop(dropped, "exact duplicate points", len(pts) - len(first), "points")
    return pts[first], (nrm[first] if nrm is not None else None)


def _check_point_count(kept: int, read: int, dropped, *, min_points: int, max_points: int) -> None:
    if kept < min_points:
        raise IngestError(
            f"only {kept} usable points remain of {read} read"
            f"{_dropped_clause(dropped)}; at least {min_points} are needed to rebuild a surface, "
            "upload a denser scan"
        )
    if kept > max_points:
        raise IngestError(
            f"{kept} points remain of {read} read, more than the limit of {max_points}; "
            f"subsample it below {max_points} points (e.g. CloudCompare's Subsample tool) and "
            "upload again; the limit is set by whoever runs the service"
        )


def _clean_normals(normals: np.ndarray | None) -> tuple[np.ndarray | None, str | None]:
    if normals is None:
        return None, None
    lengths = np.linalg.norm(normals, axis=1)
    bad = ~np.isfinite(normals).all(axis=1) | ~(lengths > 0) | ~np.isfinite(lengths)
    if bad.any():
        return None, (
            f"normals discarded: {int(bad.sum())} of {len(normals)} points have a missing, "
            "non-finite or zero-length normal; normals will be estimated for all points"
        )
    return normals / lengths[:, None], None


# --- steps of clean_mesh ---------------------------------------------------------------------------


def _check_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    verts = _rows("vertices", vertices)
    tris = np.asarray(faces)
    if tris.ndim != 2 or tris.shape[1] != 3 or (tris.size and tris.dtype.kind not in "iu"):
        raise ValueError(f"faces must be (m, 3) vertex indices, got shape {tris.shape} dtype {tris.dtype}")
    tris = tris.astype(np.int64)
    if len(tris) and (tris.min() < 0 or tris.max() >= len(verts)):
        raise IngestError(
            f"faces reference vertices {int(tris.min())}..{int(tris.max())} but the mesh has "
            f"{len(verts)} vertices; the file is corrupt"
        )
    return verts, tris


def _drop_non_finite_faces(verts, tris, dropped):
    """bool (n,) finite vertices, and the faces all of whose vertices are finite."""
    finite = np.isfinite(verts).all(axis=1)
    _drop(dropped, "non-finite vertex coordinates", int(len(verts) - finite.sum()), "vertices")
    keep = finite[tris].all(axis=1)
    _drop(dropped, "faces with non-finite vertices", int((~keep).sum()), "faces")
    return finite, tris[keep]


def _merge_duplicate_vertices(verts, tris, finite, dropped):
    """Faces re-indexed onto the first of each set of bit-identical finite vertices, and how many merged."""
    finite_index = np.flatnonzero(finite)
    first, group = first_occurrences(verts[finite_index], inverse=True)
    canonical = np.arange(len(verts), dtype=np.int64)
    canonical[finite_index] = finite_index[first[group]]
    # Only vertices some face uses count: an unused duplicate is counted as unreferenced later.
    merged = int(np.unique(tris).size - np.unique(canonical[tris]).size) if len(tris) else 0
    _drop(dropped, "exact duplicate vertices merged", merged, "vertices")
    return canonical[tris], merged


def _drop_degenerate_faces(verts, tris, dropped):
    repeated = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    _drop(dropped, "degenerate faces (repeated vertex)", int(repeated.sum()), "faces")
    tris = tris[~repeated]

    corners = verts[tris]
    area2 = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    flat = area2 == 0.0
    _drop(dropped, "degenerate faces (zero area)", int(flat.sum()), "faces")
    tris = tris[~flat]

    unique_rows = first_occurrences(np.sort(tris, axis=1))
    _drop(dropped, "duplicate faces", len(tris) - len(unique_rows), "faces")
    return tris[unique_rows]


def _drop_unreferenced_vertices(verts, tris, already_counted, dropped):
    """The vertices some face uses, in input order, and the faces re-indexed onto them."""
    used = np.unique(tris)
    _drop(dropped, "unreferenced vertices", len(verts) - len(used) - already_counted, "vertices")
    remap = np.full(len(verts), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return verts[used], remap[tris]


# --- shared by both --------------------------------------------------------------------------------


def _rows(name: str, array: np.ndarray) -> np.ndarray:
    values = np.asarray(array)
    if values.ndim != 2 or values.shape[1] != 3 or values.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be an (n, 3) numeric array, got shape {values.shape} dtype {values.dtype}")
    return values.astype(np.float64, copy=False)


def _scale_to_mm(values: np.ndarray, mm_per_unit: float) -> np.ndarray:
    # Scaled before the finiteness test, so that coordinates overflowing to Inf are caught by it.
    with np.errstate(over="ignore", invalid="ignore"):
        return values * mm_per_unit


def _drop(dropped: list[dict[str, Any]], reason: str, count: int, of: str) -> None:
    if count > 0:
        dropped.append({"reason": reason, "count": int(count), "of": of})


def _dropped_clause(dropped: list[dict[str, Any]]) -> str:
    if not dropped:
        return ""
    return " (dropped: " + ", ".join(f"{d['count']} {d['reason']}" for d in dropped) + ")"


def _report(kind, params, counts, dropped, points, notes, format, *, has_normals, normals_note) -> dict[str, Any]:
    report = {
        "kind": kind,
        "units": params.units,
        "scale_to_mm": MM_PER_UNIT[params.units],
        "counts": counts,
        "dropped": dropped,
        "has_normals": has_normals,
        "normals_note": normals_note,
        "bbox_mm": _bbox(points),
        "notes": [str(n) for n in notes],
    }
    # Only when given, so that a caller's own value survives a dict merge.
    if format is not None:
        report["format"] = format
    return report


def _bbox(points: np.ndarray) -> dict[str, Any]:
    low, high = points.min(axis=0), points.max(axis=0)
    size = high - low
    return {
        "min": low.tolist(),
        "max": high.tolist(),
        "size": size.tolist(),
        "diagonal": float(np.linalg.norm(size)),
    }
