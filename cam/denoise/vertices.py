"""Vertices that follow filtered face normals: the vertex update and its folded-face repair.

Vertex update (the scheme the MeshTGV paper uses, after Sun et al. 2007): iterated
    x_i <- x_i + 1/|F_i| sum_{f in F_i} n_f (n_f . (c_f - x_i)),
with F_i the faces around vertex i, n_f the filtered normals and c_f the current centroids.
That update moves vertices only along normals, so a triangle that the noise folded over (its
orientation reversed in the tangent plane, common for small faces under noise with a tangential
component) is left folded: its plane is right but its normal points the wrong way. ``repair_rounds``
rounds of a local repair follow: the vertices of every face whose normal opposes its filtered normal
are moved to the average of their neighbours within the tangent plane (normal motion is left to the
update), then a few more update iterations run. Zero rounds give the paper's update alone.

Faces the filter left out (zero area) get the normalised mean of the filtered normals around them
(:func:`fill_degenerate_normals`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from cam import CheckCancel

__all__ = ["fill_degenerate_normals", "unit_rows", "update_vertices"]

_REPAIR_UPDATE_ITERATIONS = 5  # vertex-update iterations after each flip-repair round


def update_vertices(
    x: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    iterations: int,
    repair_rounds: int,
    *,
    check_cancel: CheckCancel | None = None,
) -> tuple[np.ndarray, int, int]:
    """Move the vertices so that the faces follow the filtered normals, then repair folded faces.

    Parameters
    ----------
    x : ndarray, shape (n, 3), float64
        Vertex positions in units of the mean edge length; not modified.
    faces : ndarray, shape (m, 3), int64
        The faces the normals belong to (zero-area faces left out).
    normals : ndarray, shape (m, 3), float64
        Filtered unit face normals.
    iterations : int
        Iterations of the vertex update.
    repair_rounds : int
        Rounds of the folded-face repair (0: the paper's update alone).
    check_cancel : callable, optional
        Called before every update iteration and repair round; it stops the work by raising.

    Returns
    -------
    x : ndarray, shape (n, 3), float64
        The moved positions, mean-edge units (vertices of no face stay where they were).
    folded_before, folded_after : int
        Faces whose normal opposes the filtered one after the update and after the repair.
    """
    check_cancel = check_cancel or _no_cancel
    update = _VertexUpdate(faces, normals, len(x))
    x = x.copy()
    for _ in range(iterations):
        check_cancel()
        x = update.step(x)
    bad = _folded(x, faces, normals)
    folded_before = int(bad.sum())
    if repair_rounds > 0 and bad.any():
        x, bad = _repair_folds(x, faces, normals, update, bad, repair_rounds, check_cancel)
    return x, folded_before, int(bad.sum())


def fill_degenerate_normals(face_normals: np.ndarray, faces: np.ndarray, valid: np.ndarray, n: int) -> int:
    """Give the faces left out of the filter the mean of the filtered normals around their vertices.

    Parameters
    ----------
    face_normals : ndarray, shape (m, 3), float64
        Filtered unit normals in the rows of ``valid`` faces; the other rows are overwritten
        in place with unit vectors, or zero where no valid face shares a vertex.
    faces : ndarray, shape (m, 3), int64
        All faces.
    valid : ndarray, shape (m,), bool
        The faces that were filtered.
    n : int
        Number of vertices.

    Returns
    -------
    int
        Faces left out that got no normal (zero rows).
    """
    vf = faces[valid]
    vsum = np.zeros((n, 3))
    for k in range(3):
        np.add.at(vsum, vf[:, k], face_normals[valid])
    bad = np.flatnonzero(~valid)
    s = vsum[faces[bad]].sum(axis=1)
    face_normals[bad] = unit_rows(s)
    return int(np.sum(np.linalg.norm(s, axis=1) == 0))


def unit_rows(a: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length.

    Parameters
    ----------
    a : ndarray, shape (k, 3), float64

    Returns
    -------
    ndarray, shape (k, 3), float64
        ``a`` with each row divided by its length; rows of zero length stay zero.
    """
    nrm = np.linalg.norm(a, axis=1)
    out = np.zeros_like(a)
    ok = nrm > 0
    out[ok] = a[ok] / nrm[ok, None]
    return out


class _VertexUpdate:
    """One step of the Sun et al. update, with the sums over each vertex's faces precomputed."""

    def __init__(self, faces: np.ndarray, normals: np.ndarray, n: int) -> None:
        m = len(faces)
        self.faces, self.normals = faces, normals
        # incidence: vertex-by-face, for sums over the faces around each vertex
        self.inc = sp.csr_matrix((np.ones(3 * m), (faces.ravel(), np.repeat(np.arange(m), 3))), shape=(n, m))
        count = np.asarray(self.inc.sum(axis=1)).ravel()
        self.inv_count = np.where(count > 0, 1.0 / np.maximum(count, 1), 0.0)
        # sum_f n_f n_f^T c_f and sum_f n_f n_f^T per vertex are what the update needs:
        # x_i += 1/|F_i| (sum_f n_f n_f^T c_f - (sum_f n_f n_f^T) x_i)
        nnT = np.einsum("fi,fj->fij", normals, normals).reshape(m, 9)
        self.msum = (self.inc @ nnT).reshape(n, 3, 3)

    def step(self, x: np.ndarray) -> np.ndarray:
        c = x[self.faces].mean(axis=1)
        a = self.inc @ (self.normals * np.einsum("fi,fi->f", self.normals, c)[:, None])
        b = np.einsum("nij,nj->ni", self.msum, x)
        return x + (a - b) * self.inv_count[:, None]


def _folded(x: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """bool (m,): the face's normal opposes its filtered normal."""
    fn = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    return np.einsum("fi,fi->f", fn, normals) < 0


def _repair_folds(x, faces, normals, update: _VertexUpdate, bad, rounds: int, check_cancel: CheckCancel):
    """Tangential smoothing of folded faces' vertices, each round followed by a few update steps."""
    n = len(x)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adj = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    adj = ((adj + adj.T) > 0).astype(np.float64).tocsr()
    deg = np.asarray(adj.sum(axis=1)).ravel()
    vnormal = unit_rows(update.inc @ normals)
    for _ in range(rounds):
        if not bad.any():
            break
        check_cancel()
        verts = np.unique(faces[bad])
        lap = adj[verts] @ x / np.maximum(deg[verts], 1)[:, None] - x[verts]
        nv = vnormal[verts]
        x[verts] += lap - np.einsum("vi,vi->v", lap, nv)[:, None] * nv
        for _ in range(_REPAIR_UPDATE_ITERATIONS):
            x = update.step(x)
        bad = _folded(x, faces, normals)
    return x, bad


def _no_cancel() -> None:
    pass
