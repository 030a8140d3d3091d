"""Patch parameterisation seeded from the quad grid: mesh samples, their patch and (u, v), and anchors.

The quad grid of a patch is a discrete parameterisation of it: quad (i, j) of an
R x C grid covers [i, i + 1] x [j, j + 1] in grid-index units (the fit works in
these units and divides by R and C only when it writes the surface out). Mesh samples take the
parameters of their closest point on the grid's quads (`assign_samples`); the fit then corrects them
by projecting onto the current surface (`cam.fit.foot`). The grid's own vertices, moved onto the
mesh, keep their grid parameters (`grid_anchors`): they hold the parameterisation where
squared-distance steps leave it free to slide.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.fit.foot import unit_rows
from cam.mesh.closest import MeshIndex, closest_points, mesh_index

__all__ = ["Anchors", "Assignment", "assign_samples", "grid_anchors", "mesh_samples"]

_LEVELS = {0: 1, 1: 3, 3: 4, 6: 5, 10: 6}  # samples per face -> barycentric lattice level


def mesh_samples(vertices: np.ndarray, faces: np.ndarray, *, per_face: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Points on a triangle mesh with unit normals: the vertices, plus `per_face` interior points per face.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3), float64
        The mesh's vertices, mm.
    faces : ndarray, shape (m, 3), int
        Its triangles, vertex ids.
    per_face : {0, 1, 3, 6, 10}
        Points of the barycentric lattice strictly inside each face.

    Returns
    -------
    points : ndarray, shape (k, 3), float64
        The vertices some face uses, then the faces' interior points (face by face), mm.
    normals : ndarray, shape (k, 3), float64
        Unit normals: area weighted at the vertices, the face's own inside it.
    """
    if per_face not in _LEVELS:
        raise ValueError(f"per_face must be one of {sorted(_LEVELS)}, got {per_face}")
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    tri = V[F]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = twice the area
    vn = np.zeros_like(V)
    for k in range(3):
        np.add.at(vn, F[:, k], fn)
    used = np.unique(F)
    pts, nrm = [V[used]], [unit_rows(vn[used])]
    L = _LEVELS[per_face]
    bary = np.array([(a, b, L - a - b) for a in range(1, L) for b in range(1, L - a)], dtype=np.float64) / L
    if bary.size:
        pts.append(np.einsum("bk,fkd->fbd", bary, tri).reshape(-1, 3))
        nrm.append(np.repeat(unit_rows(fn), len(bary), axis=0))
    return np.concatenate(pts), np.concatenate(nrm)


@dataclass(frozen=True, eq=False)
class Assignment:
    """Which patch each of n samples falls in, and where.

    Attributes
    ----------
    patch : ndarray, shape (n,), int64
        The patch's index in the grids given; -1: none (a quad in no patch).
    u, v : ndarray, shape (n,), float64
        Parameters in grid-index units: u in [0, R] counts quads along the patch's first axis.
    distance : ndarray, shape (n,), float64
        Distance to the quad mesh, mm.
    """

    patch: np.ndarray
    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray


def assign_samples(points: np.ndarray, vertices: np.ndarray, grids: list[np.ndarray], *,
                   other_quads: np.ndarray | None = None) -> Assignment:
    """Assign samples to the patch of their closest quad and seed their parameters from the grid.

    Parameters
    ----------
    points : ndarray, shape (n, 3), float64
        The samples, mm.
    vertices : ndarray, shape (k, 3), float64
        The quad mesh's vertices, mm.
    grids : list of ndarray, each shape (R + 1, C + 1), int
        Per patch, its vertex ids (`cam.fit.grid.patch_grid`).
    other_quads : ndarray, shape (q, 4), int, or None
        Quads in no patch (the setup base...), which take samples away from the patches
        (patch -1) instead of letting them stick to one.

    Returns
    -------
    Assignment
        Per sample its patch, (u, v) on the patch's quads and its distance to them.
    """
    V = np.asarray(vertices, dtype=np.float64)
    tris, owner, cell = [], [], []
    for k, g in enumerate(grids):
        g = np.asarray(g, dtype=np.int64)
        R, C = g.shape[0] - 1, g.shape[1] - 1
        i, j = np.meshgrid(np.arange(R), np.arange(C), indexing="ij")
        i, j = i.ravel(), j.ravel()
        a, b, c, d = g[i, j], g[i + 1, j], g[i + 1, j + 1], g[i, j + 1]
        tris += [np.stack([a, b, c], 1), np.stack([a, c, d], 1)]
        for half in (0, 1):
            owner.append(np.full(i.size, k))
            cell.append(np.stack([i, j, np.full(i.size, half), np.full(i.size, R), np.full(i.size, C)], 1))
    if other_quads is not None and len(other_quads):
        oq = np.asarray(other_quads, dtype=np.int64).reshape(-1, 4)
        tris += [oq[:, [0, 1, 2]], oq[:, [0, 2, 3]]]
        owner.append(np.full(2 * len(oq), -1))
        cell.append(np.zeros((2 * len(oq), 5), dtype=np.int64) + np.array([0, 0, 0, 1, 1]))
    T = np.concatenate(tris)
    own = np.concatenate(owner)
    cells = np.concatenate(cell)
    _, dist, tri, bary = closest_points(mesh_index(V, T), points)
    i, j, half, R, C = cells[tri].T
    # Local corner coordinates of the two halves: (0,0),(1,0),(1,1) and (0,0),(1,1),(0,1).
    lu = np.where(half == 0, bary[:, 1] + bary[:, 2], bary[:, 1])
    lv = np.where(half == 0, bary[:, 2], bary[:, 1] + bary[:, 2])
    return Assignment(patch=own[tri], u=np.clip(i + lu, 0, R), v=np.clip(j + lv, 0, C), distance=dist)


@dataclass(frozen=True, eq=False)
class Anchors:
    """Quad-grid vertices on the mesh, with the grid parameters they have by construction.

    The border lies where the patch's quads end, so the component across it is exact; where a
    vertex sits along the border or inside is only as regular as the remesher made it.

    Attributes
    ----------
    points : ndarray, shape (m, 3), float64
        The grid's m = (R + 1)(C + 1) vertices on the mesh, row-major, mm.
    normals : ndarray, shape (m, 3), float64
        Unit normals of the mesh triangles nearest them.
    u, v : ndarray, shape (m,), float64
        Their grid indices i, j.
    across_u, across_v : ndarray, shape (m, 3), float64
        At vertices on a u-border (i = 0 or R) / v-border (j = 0 or C), the unit tangent
        direction across that border; zero elsewhere.
    targets : ndarray, shape (m, 3), float64
        Where a smooth parameterisation puts the grid points, mm (see `grid_anchors`).
    """

    points: np.ndarray
    normals: np.ndarray
    u: np.ndarray
    v: np.ndarray
    across_u: np.ndarray
    across_v: np.ndarray
    targets: np.ndarray


def grid_anchors(vertices: np.ndarray, grid: np.ndarray, index: MeshIndex, *, knot_spacing_quads: float = 2.0,
                 positions: np.ndarray | None = None) -> Anchors:
    """Anchors of one patch: its grid's vertices moved onto the mesh.

    `Anchors.targets` are where a smooth parameterisation puts the grid points: a cubic spline
    with knots every `knot_spacing_quads` quads fitted to the grid vertices at their indices, so the
    remesher's vertex-to-vertex irregularity is not forced on the fit while its overall
    layout is kept (and an exact grid stays exact).

    Parameters
    ----------
    vertices : ndarray, shape (k, 3), float64
        The quad mesh's vertices, mm.
    grid : ndarray, shape (R + 1, C + 1), int
        The patch's vertex ids.
    index : MeshIndex
        The triangle mesh (`cam.mesh.closest.mesh_index`).
    knot_spacing_quads : float
        Knot spacing of the smoothing spline, quads.
    positions : ndarray, shape (k, 3), float64, or None
        Where each quad-mesh vertex goes, mm (e.g. onto a crease, see `cam.fit.crease`);
        None: the closest point of the mesh.

    Returns
    -------
    Anchors
        The grid's vertices on the mesh with their indices, normals, across-border directions
        and targets.
    """
    from cam.spline.basis import surface_matrix

    g = np.asarray(grid, dtype=np.int64)
    G = np.asarray(vertices, dtype=np.float64)[g]
    on_mesh, _, tri, _ = closest_points(index, G.reshape(-1, 3))
    if positions is not None:
        on_mesh = np.asarray(positions, dtype=np.float64)[g.ravel()]
    f = index.faces[tri]
    corner = index.vertices[f]
    n = unit_rows(np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0]))
    di = np.gradient(G, axis=0).reshape(-1, 3)
    dj = np.gradient(G, axis=1).reshape(-1, 3)
    ti = unit_rows(di - np.einsum("ij,ij->i", di, n)[:, None] * n)
    tj = unit_rows(dj - np.einsum("ij,ij->i", dj, n)[:, None] * n)
    # Across a u-border is along i, with the along-border (j) part removed; likewise for v.
    au = unit_rows(ti - np.einsum("ij,ij->i", ti, tj)[:, None] * tj)
    av = unit_rows(tj - np.einsum("ij,ij->i", tj, ti)[:, None] * ti)
    i, j = np.meshgrid(np.arange(g.shape[0]), np.arange(g.shape[1]), indexing="ij")
    on_u = ((i == 0) | (i == g.shape[0] - 1)).ravel()
    on_v = ((j == 0) | (j == g.shape[1] - 1)).ravel()
    iu, jv = i.ravel().astype(np.float64), j.ravel().astype(np.float64)
    ku = _lattice(g.shape[0] - 1, knot_spacing_quads)
    kv = _lattice(g.shape[1] - 1, knot_spacing_quads)
    B = surface_matrix(ku, kv, iu, jv).toarray()
    targets = B @ np.linalg.lstsq(B, on_mesh, rcond=None)[0]
    return Anchors(points=on_mesh, normals=n, u=iu, v=jv, across_u=au * on_u[:, None], across_v=av * on_v[:, None],
                   targets=targets)


def _lattice(count: int, spacing: float) -> np.ndarray:
    inner = np.arange(spacing, count, spacing)
    inner = inner[(inner > 0) & (inner < count)]
    return np.concatenate([[0.0] * 4, inner, [float(count)] * 4])
