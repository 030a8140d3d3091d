"""Bring one QuadriFlow result onto the input surface and decide whether it is usable.

A raw result is repaired where that is small and safe (:mod:`cam.remesh.repair`),
oriented like the input, and its vertices are projected onto the input
triangles: QuadriFlow works in single precision, and the projection restores
double precision (and puts every vertex on the input surface). It is usable
when :func:`cam.remesh.check.inspect_quad_mesh` finds no problem and its
two-sided Hausdorff distance to the input is within the limit.
"""

from __future__ import annotations

import numpy as np

from cam.mesh.closest import MeshIndex, closest_points, mesh_index
from cam.mesh.quads import face_areas, face_normals
from cam.remesh.check import inspect_quad_mesh
from cam.remesh.repair import repair_quad_mesh

__all__ = ["accept_quads", "hausdorff_to_mesh"]


def accept_quads(raw_vertices: np.ndarray, raw_faces: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, *,
                 boundary_loops: int, diagonal_mm: float, max_hausdorff_ratio: float,
                 split_unpaired: bool = False) -> tuple[np.ndarray, np.ndarray, dict]:
    """Repair, orient, project and check one QuadriFlow result.

    Parameters
    ----------
    raw_vertices
        float64 (n, 3), mm: QuadriFlow's vertices.
    raw_faces
        int64 (m, 4) vertex indices: QuadriFlow's quads.
    vertices
        float64 (p, 3), mm: the input triangle mesh's vertices.
    triangles
        int64 (q, 3) vertex indices: its triangles, counter-clockwise seen from outside.
    boundary_loops
        Boundary loops of the input (more in the result are holes).
    diagonal_mm
        The input's bounding-box diagonal, mm (> 0).
    max_hausdorff_ratio
        Largest accepted two-sided Hausdorff distance, as a fraction of ``diagonal_mm``.
    split_unpaired
        Passed to :func:`cam.remesh.repair.repair_quad_mesh`.

    Returns
    -------
    vertices : ndarray
        float64 (n', 3), mm, each on the input surface.
    faces : ndarray
        int64 (m', 4) vertex indices, oriented like the input.
    facts : dict
        JSON-ready: ``repairs``, ``check`` (the inspection report), ``projection_max_mm``,
        ``hausdorff_mm``, ``hausdorff_ratio``, ``mean_distance_mm``.

    Raises
    ------
    ValueError
        Saying why the result is not usable (no faces, non-finite coordinates, a repair that failed,
        a problem the inspection found, too far from the input).
    """
    if len(raw_faces) == 0:
        raise ValueError("QuadriFlow returned no faces")
    if not np.isfinite(raw_vertices).all():
        raise ValueError("QuadriFlow returned non-finite coordinates")
    verts, quads, repairs = repair_quad_mesh(raw_vertices, raw_faces, expected_boundary_loops=boundary_loops,
                                             split_unpaired=split_unpaired)
    index = mesh_index(vertices, triangles)
    quads, flipped = _orient_like(verts, quads, index)
    if flipped:
        repairs.append("reversed the faces to match the input's orientation")
    verts, dist = closest_points(index, verts)[:2]
    check = inspect_quad_mesh(verts, quads, expected_boundary_loops=boundary_loops)
    if check.problems:
        raise ValueError("; ".join(check.problems))
    hausdorff, mean = hausdorff_to_mesh(verts, quads, index)
    if hausdorff > max_hausdorff_ratio * diagonal_mm:
        raise ValueError(f"the quad mesh is {hausdorff:.3g} mm from the input at worst "
                         f"({hausdorff / diagonal_mm:.1%} of the part's diagonal, limit {max_hausdorff_ratio:.1%}); "
                         "details smaller than the quads are lost: raise remesh.target_faces")
    return verts, quads, {
        "repairs": repairs, "check": check.as_dict(), "projection_max_mm": float(dist.max()),
        "hausdorff_mm": hausdorff, "hausdorff_ratio": hausdorff / diagonal_mm, "mean_distance_mm": mean,
    }


def hausdorff_to_mesh(verts: np.ndarray, quads: np.ndarray, index: MeshIndex) -> tuple[float, float]:
    """Two-sided Hausdorff and mean distance (mm) between a quad mesh (vertices (n, 3) mm, quads (m, 4)) and the
    triangle mesh of `index`, on dense samples."""
    p = verts[quads]
    samples = np.vstack([verts, p.mean(axis=1), 0.5 * (p + np.roll(p, -1, axis=1)).reshape(-1, 3)])
    d_fwd = closest_points(index, samples)[1]
    tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    in_verts, in_tris = index.vertices, index.faces
    back = np.vstack([in_verts[np.unique(in_tris)], in_verts[in_tris].mean(axis=1)])
    d_back = closest_points(mesh_index(verts, tris), back)[1]
    return float(max(d_fwd.max(), d_back.max())), float(0.5 * (d_fwd.mean() + d_back.mean()))


def _orient_like(verts: np.ndarray, quads: np.ndarray, index: MeshIndex) -> tuple[np.ndarray, bool]:
    """Flip all quads when their normals disagree with the input's at the closest points (area-weighted)."""
    tri = closest_points(index, verts[quads].mean(axis=1))[2]
    c = index.vertices[index.faces[tri]]
    tn = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-300)
    agreement = float((np.einsum("ij,ij->i", face_normals(verts, quads), tn) * face_areas(verts, quads)).sum())
    if agreement < 0:
        return quads[:, ::-1].copy(), True
    return quads, False
