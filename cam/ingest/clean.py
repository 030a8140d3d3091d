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
    points
        (n, 3) numeric coordinates in the file's units (``params.units``).
    normals
        (n, 3) numeric normals or None; see the module docstring for when they are kept.
    params
        ``units``: the file's unit, scaled to mm by :data:`MM_PER_UNIT`.
    min_points, max_points
        Bounds on the points that remain (the operator's settings).
    format, notes
        Copied into the report: ``format`` only when given (so a caller's own
        value survives a dict merge), ``notes`` being the reader's notes
        (:attr:`cam.io.InputData.notes`).

    Returns
    -------
    :class:`CleanCloud`. Its report: ``{"kind": "cloud", "format", "units",
    "scale_to_mm", "counts": {"read", "kept"}, "dropped": [{"reason", "count",
    "of"}], "has_normals", "normals_note", "bbox_mm": {"min", "max", "size",
    "diagonal"}, "notes"}``; ``dropped`` lists only reasons with a count.

    Raises
    ------
    IngestError
        When no point has finite coordinates, or fewer than ``min_points`` or
        more than ``max_points`` remain.
    ValueError
        When ``points`` or ``normals`` are not (n, 3) numeric arrays of the same length.
    """
    mm_per_unit = MM_PER_UNIT[params.units]
    pts = _rows("points", points)
    nrm = None if normals is None else _rows("normals", normals)
    if nrm is not None and len(nrm) != len(pts):
        raise ValueError(f"there are {len(nrm)} normals for {len(pts)} points; pass one per point")
    read = len(pts)
    if read == 0:
        raise IngestError("the file holds no points")
    dropped: list[dict[str, Any]] = []

    # Scale first so that coordinates overflowing to Inf are caught as non-finite.
    with np.errstate(over="ignore", invalid="ignore"):
        pts = pts * mm_per_unit
    finite = np.isfinite(pts).all(axis=1)
    if not finite.any():
        raise IngestError(
            f"all {read} points have non-finite coordinates (NaN or Inf); the file holds no "
            "usable geometry, check the export settings of the scanner software"
        )
    _drop(dropped, "non-finite coordinates", int(read - finite.sum()), "points")
    pts = pts[finite]
    nrm = nrm[finite] if nrm is not None else None

    first = first_occurrences(pts)
    _drop(dropped, "exact duplicate points", len(pts) - len(first), "points")
    pts = pts[first]
    nrm = nrm[first] if nrm is not None else None

    kept = len(pts)
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

    nrm, note = _clean_normals(nrm)
    report = {
        "kind": "cloud",
        "units": params.units,
        "scale_to_mm": mm_per_unit,
        "counts": {"read": read, "kept": kept},
        "dropped": dropped,
        "has_normals": nrm is not None,
        "normals_note": note,
        "bbox_mm": _bbox(pts),
        "notes": [str(n) for n in notes],
    }
    if format is not None:
        report["format"] = format
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
    vertices
        (n, 3) numeric coordinates in the file's units (``params.units``).
    faces
        (m, 3) integer indices into ``vertices``.
    params, max_points, format, notes
        As for :func:`clean_cloud`; ``max_points`` bounds the vertices kept.

    Returns
    -------
    :class:`CleanMesh`; its report is that of :func:`clean_cloud` with
    ``kind`` ``"mesh"``, ``counts`` adding ``faces_read`` and ``faces_kept``,
    ``has_normals`` false and ``normals_note`` None.

    Raises
    ------
    IngestError
        For indices out of range (a corrupt file), no face left, or more than
        ``max_points`` vertices.
    ValueError
        When ``vertices`` is not an (n, 3) numeric array or ``faces`` not (m, 3) integers.
    """
    mm_per_unit = MM_PER_UNIT[params.units]
    verts = _rows("vertices", vertices)
    tris = np.asarray(faces)
    if tris.ndim != 2 or tris.shape[1] != 3 or (tris.size and tris.dtype.kind not in "iu"):
        raise ValueError(f"faces must be (m, 3) vertex indices, got shape {tris.shape} dtype {tris.dtype}")
    tris = tris.astype(np.int64)
    read, faces_read = len(verts), len(tris)
    if faces_read and (tris.min() < 0 or tris.max() >= read):
        raise IngestError(
            f"faces reference vertices {int(tris.min())}..{int(tris.max())} but the mesh has "
            f"{read} vertices; the file is corrupt"
        )
    dropped: list[dict[str, Any]] = []
    with np.errstate(over="ignore", invalid="ignore"):
        verts = verts * mm_per_unit

    finite = np.isfinite(verts).all(axis=1)
    non_finite = int(read - finite.sum())
    _drop(dropped, "non-finite vertex coordinates", non_finite, "vertices")
    keep = finite[tris].all(axis=1)
    _drop(dropped, "faces with non-finite vertices", int((~keep).sum()), "faces")
    tris = tris[keep]

    finite_index = np.flatnonzero(finite)
    first, group = first_occurrences(verts[finite_index], inverse=True)
    canonical = np.arange(read, dtype=np.int64)
    canonical[finite_index] = finite_index[first[group]]
    merged = int(np.unique(tris).size - np.unique(canonical[tris]).size) if len(tris) else 0
    _drop(dropped, "exact duplicate vertices merged", merged, "vertices")
    tris = canonical[tris]

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
    tris = tris[unique_rows]

    if len(tris) == 0:
        raise IngestError(
            f"no usable face remains of {faces_read} read{_dropped_clause(dropped)}; "
            "the mesh is empty or degenerate, export it again"
        )
    used = np.unique(tris)
    unreferenced = read - len(used) - merged - non_finite
    _drop(dropped, "unreferenced vertices", unreferenced, "vertices")
    remap = np.full(read, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    verts = verts[used]
    tris = remap[tris]
    if len(verts) > max_points:
        raise IngestError(
            f"the mesh has {len(verts)} vertices, more than the limit of {max_points}; "
            "decimate it (e.g. MeshLab's Quadric Edge Collapse) and upload again; the limit is "
            "set by whoever runs the service"
        )
    report = {
        "kind": "mesh",
        "units": params.units,
        "scale_to_mm": mm_per_unit,
        "counts": {"read": read, "kept": len(verts), "faces_read": faces_read, "faces_kept": len(tris)},
        "dropped": dropped,
        "has_normals": False,
        "normals_note": None,
        "bbox_mm": _bbox(verts),
        "notes": [str(n) for n in notes],
    }
    if format is not None:
        report["format"] = format
    return CleanMesh(vertices=verts, faces=tris, report=report)


def _rows(name: str, array: np.ndarray) -> np.ndarray:
    values = np.asarray(array)
    if values.ndim != 2 or values.shape[1] != 3 or values.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be an (n, 3) numeric array, got shape {values.shape} dtype {values.dtype}")
    return values.astype(np.float64, copy=False)


def _drop(dropped: list[dict[str, Any]], reason: str, count: int, of: str) -> None:
    if count > 0:
        dropped.append({"reason": reason, "count": int(count), "of": of})


def _dropped_clause(dropped: list[dict[str, Any]]) -> str:
    if not dropped:
        return ""
    return " (dropped: " + ", ".join(f"{d['count']} {d['reason']}" for d in dropped) + ")"


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


def _bbox(points: np.ndarray) -> dict[str, Any]:
    low, high = points.min(axis=0), points.max(axis=0)
    size = high - low
    return {
        "min": low.tolist(),
        "max": high.tolist(),
        "size": size.tolist(),
        "diagonal": float(np.linalg.norm(size)),
    }
