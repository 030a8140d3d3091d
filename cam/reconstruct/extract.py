"""Marching cubes on a grid fitted to the cloud's box, keeping the components that carry points."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

from cam import CheckCancel, GeometryError

__all__ = ["extract_surface", "is_watertight"]


def extract_surface(
    evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    resolution: int,
    points: np.ndarray,
    min_share: float = 0.01,
    chunk: int = 1_048_576,
    check_cancel: CheckCancel | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Zero level set of ``evaluate`` as a closed triangle mesh.

    Parameters
    ----------
    evaluate : callable
        Maps three float64 coordinate vectors (a,), (b,), (c,) to the signed
        values (negative inside) on the lattice they span, shape (a, b, c).
    lo, hi : ndarray, shape (3,), float64
        Box to sample, in the points' units; it must contain the surface with a margin.
    resolution : int
        Cells along the longest side; the cell is cubic.
    points : ndarray, shape (n, 3), float64
        The cloud; a component is kept when at least ``min_share`` of the points
        are nearest to it (the largest one is always kept).
    min_share : float
        Share of the points a component must carry to be kept.
    chunk : int
        Lattice values evaluated per call of ``evaluate`` (about).
    check_cancel : callable, optional
        Called before each slab of the lattice is evaluated; it stops the work by raising.

    Returns
    -------
    vertices : ndarray, shape (v, 3), float64
        In the box's units.
    faces : ndarray, shape (f, 3), int64
        Outward winding.
    report : dict
        ``grid`` (lattice vertices per axis), ``cell`` (the cell, box units),
        ``components``, ``components_kept``, ``watertight``.

    Raises
    ------
    GeometryError
        When the field is nowhere negative (no surface).

    Notes
    -----
    The border layer of the grid is forced outside, so a field that never
    turns positive near the border still yields closed (if spurious) shells,
    which then carry no points and are dropped.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    h = float((hi - lo).max() / resolution)
    dims = np.maximum(np.ceil((hi - lo) / h - 1e-9).astype(np.int64), 1) + 1
    axes = [lo[a] + h * np.arange(dims[a]) for a in range(3)]
    volume = np.empty(tuple(dims), dtype=np.float32)
    slabs = max(1, chunk // int(dims[1] * dims[2]))
    for start in range(0, dims[0], slabs):
        if check_cancel is not None:
            check_cancel()
        xs = axes[0][start:start + slabs]
        volume[start:start + len(xs)] = evaluate(xs, axes[1], axes[2])
    pad = float(np.abs(volume).max()) + h
    volume[[0, -1], :, :] = pad
    volume[:, [0, -1], :] = pad
    volume[:, :, [0, -1]] = pad
    report = {"grid": [int(d) for d in dims], "cell": h}
    if not (volume < 0).any():
        raise GeometryError("the trained field has no inside: no surface was found; "
                            "train longer or check the cloud's normals")
    verts, faces, _, _ = marching_cubes(volume, level=0.0, spacing=(h, h, h),
                                     gradient_direction="ascent", allow_degenerate=False)
    verts = verts.astype(np.float64) + lo
    faces = _drop_fins(faces.astype(np.int64))
    verts, faces, comp_report = _keep_components(verts, faces, points, min_share)
    report.update(comp_report)
    if _signed_volume(verts, faces) < 0:
        faces = faces[:, ::-1].copy()
    report["watertight"] = is_watertight(faces)
    return verts, faces, report


def _keep_components(verts, faces, points, min_share):
    n = len(verts)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    count, labels = connected_components(graph, directed=False)
    _, nearest = cKDTree(verts).query(points, k=1)
    carried = np.bincount(labels[nearest], minlength=count)
    keep = carried >= min_share * len(points)
    keep[np.argmax(carried)] = True
    face_keep = keep[labels[faces[:, 0]]]
    used = np.zeros(n, dtype=bool)
    used[faces[face_keep].reshape(-1)] = True
    remap = np.cumsum(used) - 1
    return verts[used], remap[faces[face_keep]], {"components": int(count), "components_kept": int(keep.sum())}


def _drop_fins(faces: np.ndarray) -> np.ndarray:
    """Remove triangles that occur twice with opposite winding.

    Marching cubes emits such a zero-volume fin where the field crosses zero almost exactly at a
    grid vertex; its edges are then shared by four triangles. Dropping both copies leaves the
    surrounding surface closed, as the fin contributes no area to the part.
    """
    key = np.sort(faces, axis=1)
    # Rows sorted lexicographically; a row equal to a neighbour occurs more than once (np.unique with
    # axis=0 does the same through a slow structured view).
    order = np.lexsort(key.T[::-1])
    ordered = key[order]
    same = np.all(ordered[1:] == ordered[:-1], axis=1)
    repeated = np.zeros(len(faces), dtype=bool)
    repeated[order[1:][same]] = True
    repeated[order[:-1][same]] = True
    return faces[~repeated]


def _signed_volume(verts: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def is_watertight(faces: np.ndarray) -> bool:
    """Whether a triangle mesh is closed and consistently wound.

    Parameters
    ----------
    faces : ndarray, shape (f, 3), integer dtype
        Triangles.

    Returns
    -------
    bool
        True when every directed edge appears once and its reverse once; False for no faces.
    """
    if len(faces) == 0:
        return False
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = directed[:, 0].astype(np.int64) * (int(faces.max()) + 1) + directed[:, 1]
    rev = directed[:, 1].astype(np.int64) * (int(faces.max()) + 1) + directed[:, 0]
    key.sort()
    if (key[1:] == key[:-1]).any():
        return False
    at = np.minimum(np.searchsorted(key, rev), len(key) - 1)
    return bool((key[at] == rev).all())
