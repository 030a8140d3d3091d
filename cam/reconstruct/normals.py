"""Normals for a point cloud: PCA over the k nearest neighbours, oriented by a minimum spanning tree.

Orientation follows Hoppe et al. (1992): a tree over the k-NN graph whose edge
weights are small where neighbouring tangent planes agree, walked from a seed
(the point farthest from its component's centroid). Each step copies the
parent's side. The walk is linear in the number of points
whatever the shape, so a perfectly planar sample (where all weights tie) costs
no more than a curved one. Which side is out is then settled for the whole
component by the divergence theorem: over a closed surface the outward normals'
flux of (p - centroid) is three times the enclosed volume, so positive (the
seed's own normal is no guide where the seed is a corner).

Copying the parent's side is only right between two samples of the same sheet
of the surface. Across a thin wall or a narrow gap (the two faces of a 2 mm
web, a boss 2 mm above a floor) the neighbourhoods of a noisy cloud reach the
opposite face, whose tangent plane is parallel but whose outward side is the
other one: Hoppe's weight calls such a pair a perfect match, and a tree that
takes it flips the whole face behind it (half of a 2 mm-walled bracket at
0.25 % noise came out inside out). So an edge also pays for how far its two
points lie from each other's tangent plane, measured against the gap a sheet
of this noise can show (:data:`SHEET_GAP_NOISE` times the fit's residual,
at least the point spacing): the tree then crosses to the opposite face only
where no path along the surface exists. The same gap refits each normal on the
neighbours of its own face, so a thin wall's normals and noise estimate are as
good as a thick part's (mean error 14.5 -> 11.9 degrees on 2 mm walls).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import (
    breadth_first_order,
    connected_components,
    minimum_spanning_tree,
)
from scipy.spatial import cKDTree

from cam import CheckCancel, GeometryError

__all__ = ["NormalsError", "check_normals", "estimate_normals", "orient_normals"]

# Above this share of confidently parallel neighbour pairs that still point opposite ways
# after orientation, the cloud has no consistent inside (or is too sparse for its shape).
_MAX_FLIPPED_SHARE = 0.02

# Noise ratio (see estimate_normals) above which the neighbourhood grows in proportion.
NOISE_REFERENCE = 0.25

# Two neighbours are on one sheet while each lies within this many times the median plane-fit residual
# (about the noise's sigma) of the other's tangent plane: Gaussian noise puts two samples of one face
# sqrt(2) sigma apart along the normal, so 3 residuals keep 97 % of same-face pairs, while the two faces of a
# 2 mm wall at the bench's noise (sigma 0.2 mm) lie 10 sigma apart.
SHEET_GAP_NOISE = 3.0


class NormalsError(GeometryError):
    """Given normals are broken or estimated ones cannot be oriented; the message says what to do."""


def check_normals(normals: np.ndarray, n_points: int) -> np.ndarray:
    """Validate given normals and scale them to unit length.

    Rows that are non-finite or of (near) zero length carry no direction and
    would silently bias the fit, so they are refused rather than patched.

    Parameters
    ----------
    normals : ndarray, shape (n_points, 3), real dtype
        Normals of any length.
    n_points : int
        Number of points they belong to.

    Returns
    -------
    ndarray, shape (n_points, 3), float64
        Unit vectors.

    Raises
    ------
    NormalsError
        Naming how many rows are non-finite or shorter than 1e-12.
    ValueError
        For a shape other than (n_points, 3) (the caller's bug).
    """
    nrm = np.asarray(normals, dtype=np.float64)
    if nrm.shape != (n_points, 3):
        raise ValueError(f"normals must have shape ({n_points}, 3) like the points, got {nrm.shape}")
    finite = np.isfinite(nrm).all(axis=1)
    length = np.linalg.norm(np.where(finite[:, None], nrm, 0.0), axis=1)
    bad = ~finite | (length < 1e-12)
    if bad.any():
        raise NormalsError(
            f"{int(bad.sum())} of {n_points} normals are zero length or not finite (NaN/Inf); "
            "fix the export or upload the cloud without normals so they are estimated"
        )
    return nrm / length[:, None]


def estimate_normals(
    points: np.ndarray,
    *,
    k: int = 16,
    noise_adaptive: bool = True,
    workers: int = 1,
    check_cancel: CheckCancel | None = None,
) -> tuple[np.ndarray, dict]:
    """Estimate and orient unit normals for a cloud.

    Parameters
    ----------
    points : ndarray, shape (n, 3), float64
        Positions, any unit; n > k.
    k : int
        Neighbours used for the plane fit and for the orientation graph.
    noise_adaptive : bool
        Widen the neighbourhood on a noisy cloud. The noise is read as the
        median RMS distance of each point's k neighbours from their plane, in
        units of the median point spacing (about 0 on a clean scan of a CAD part,
        0.55-0.65 at Gaussian noise of 0.25 % of the diagonal on the bench's 50k
        clouds). A plane fit's angular error grows with that ratio and falls
        with the neighbours, so k grows in proportion above a ratio of
        NOISE_REFERENCE, up to 4k. A clean cloud keeps k: a wider fit would
        round its sharp edges.
    workers : int
        Threads for the k-NN query.
    check_cancel : callable, optional
        Called between phases; it stops the work by raising.

    Returns
    -------
    normals : ndarray, shape (n, 3), float64
        Unit vectors, each component's turned outward (see :func:`orient_normals`).
    report : dict
        ``k`` (the one used), ``noise_ratio``, ``sheet_gap`` (the offset from a
        neighbour's tangent plane beyond which a pair is taken for two sheets,
        the points' units; see :func:`orient_normals`), ``components``,
        ``flipped_share``.

    Raises
    ------
    NormalsError
        When the orientation leaves more than 2 % of nearly parallel neighbour
        pairs on one sheet pointing opposite ways (a non-orientable or badly
        undersampled cloud). The two faces of a thin wall point opposite ways
        by right and are not counted.
    """
    pts = np.asarray(points, dtype=np.float64)
    k = int(min(k, len(pts) - 1))
    tree = cKDTree(pts)
    dist, idx = tree.query(pts, k=k + 1, workers=workers)
    dist, idx = dist[:, 1:], idx[:, 1:]
    if check_cancel is not None:
        check_cancel()
    normals, residual = _pca_normals(pts, idx)
    spacing = max(float(np.median(dist[:, 0])), 1e-300)
    noise = float(np.median(residual) / spacing)
    wider = min(4 * k, int(round(k * noise / NOISE_REFERENCE)), len(pts) - 1)
    if noise_adaptive and wider > k:
        if check_cancel is not None:
            check_cancel()
        k = wider
        dist, idx = tree.query(pts, k=k + 1, workers=workers)
        dist, idx = dist[:, 1:], idx[:, 1:]
        normals, residual = _pca_normals(pts, idx)
    # The spacing is the floor: on a clean scan the residual is ~0 while a curved face still bends
    # away from its tangent plane by (spacing)^2 / (2 radius) within a neighbourhood.
    sheet_gap = max(SHEET_GAP_NOISE * float(np.median(residual)), spacing)
    # Where a neighbourhood straddles a thin wall, both faces are parallel, so the first fit's direction
    # is right; the refit keeps the neighbours on the point's own face, which gives a normal as good as
    # on a thick part and a residual that measures the noise, not the wall's thickness.
    own_face = np.abs(np.einsum("nkj,nj->nk", pts[idx] - pts[:, None, :], normals)) < sheet_gap
    normals, residual = _pca_normals(pts, idx, own_face)
    sheet_gap = max(SHEET_GAP_NOISE * float(np.median(residual)), spacing)
    normals, components = orient_normals(pts, normals, idx, dist, sheet_gap=sheet_gap)
    if check_cancel is not None:
        check_cancel()
    dots = np.einsum("ij,ikj->ik", normals, normals[idx])
    same_sheet = _plane_offsets(pts, normals, idx) < sheet_gap
    parallel = (np.abs(dots) > 0.7) & same_sheet
    flipped = (dots < -0.7) & parallel
    share = float(flipped.sum() / max(parallel.sum(), 1))
    if share > _MAX_FLIPPED_SHARE:
        raise NormalsError(
            f"the estimated normals cannot be oriented consistently ({share:.0%} of neighbouring "
            "points still face opposite ways): the cloud is non-orientable, very noisy or too sparse "
            "for its thin parts; upload oriented normals or a denser scan"
        )
    return normals, {"k": k, "noise_ratio": round(noise, 4), "sheet_gap": sheet_gap,
                     "components": int(components), "flipped_share": share}


def _plane_offsets(points: np.ndarray, normals: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(n, k) mean distance of each neighbour pair from the other's tangent plane, the points' units."""
    out = np.empty(idx.shape)
    step = 200_000  # bounds the (chunk, k, 3) temporaries
    for start in range(0, len(points), step):
        sl = slice(start, start + step)
        e = points[idx[sl]] - points[sl, None, :]
        out[sl] = 0.5 * (np.abs(np.einsum("nj,nkj->nk", normals[sl], e))
                         + np.abs(np.einsum("nkj,nkj->nk", normals[idx[sl]], e)))
    return out


def _pca_normals(points: np.ndarray, idx: np.ndarray, keep: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Smallest-eigenvalue direction of each neighbourhood's covariance (n, 3), and the
    neighbours' RMS distance from that plane (n,). ``keep`` (n, k) bool: only those neighbours
    count; a neighbourhood left with fewer than a third of them keeps them all (a plane through three
    points fits them exactly in any direction: at a part's corners the face refit kept three or four
    and put planes through the corner at random, some facing inward)."""
    out = np.empty((len(points), 3))
    rms = np.empty(len(points))
    # Chunks keep the (chunk, k, 3) temporaries small for multi-million-point clouds.
    step = 200_000
    for start in range(0, len(points), step):
        sl = slice(start, start + step)
        nb = points[idx[sl]]
        w = np.ones(idx[sl].shape) if keep is None else keep[sl].astype(np.float64)
        w[w.sum(axis=1) < max(3, idx.shape[1] // 3)] = 1.0
        count = w.sum(axis=1)
        nb = nb - (np.einsum("nk,nkj->nj", w, nb) / count[:, None])[:, None, :]
        cov = np.einsum("nk,nki,nkj->nij", w, nb, nb)
        vals, vecs = np.linalg.eigh(cov)
        out[sl] = vecs[:, :, 0]
        rms[sl] = np.sqrt(np.maximum(vals[:, 0], 0.0) / count)
    return out, rms


def orient_normals(
    points: np.ndarray, normals: np.ndarray, idx: np.ndarray, dist: np.ndarray, *, sheet_gap: float = np.inf
) -> tuple[np.ndarray, int]:
    """Flip normals to one consistent side along a minimum spanning tree of the k-NN graph.

    Parameters
    ----------
    points : ndarray, shape (n, 3), float64
        Positions, any unit.
    normals : ndarray, shape (n, 3), float64
        Unit normals of either sign.
    idx : ndarray, shape (n, k), integer dtype
        Each point's k nearest neighbours, self excluded.
    dist : ndarray, shape (n, k), float64
        Their distances, the points' units.
    sheet_gap : float
        The points' units. A pair's weight grows by (offset / sheet_gap)^2, the
        offset being the mean distance of each point from the other's tangent
        plane: beyond one sheet_gap that alone outweighs the worst disagreement
        of two tangent planes (1 - |cos| <= 1), so the tree only crosses a thin
        wall or gap where no path along the surface connects the two sides.
        inf: Hoppe's weight.

    Returns
    -------
    normals : ndarray, shape (n, 3), float64
        The input normals, some negated.
    components : int
        Components of the neighbour graph (each is seeded on its own).
    """
    n, k = idx.shape
    rows = np.repeat(np.arange(n), k)
    cols = idx.reshape(-1)
    dots = np.abs(np.einsum("ij,ij->i", normals[rows], normals[cols]))
    # The distance term breaks ties on planar regions (all dots 1) and keeps every weight
    # strictly positive: scipy's sparse graphs read a zero weight as a missing edge.
    scale = float(np.median(dist[:, 0])) or 1.0
    weight = (1.0 - dots) + 1e-3 * dist.reshape(-1) / scale + 1e-9
    if np.isfinite(sheet_gap):
        weight = weight + (_plane_offsets(points, normals, idx).reshape(-1) / sheet_gap) ** 2
    graph = coo_matrix((weight, (rows, cols)), shape=(n, n)).tocsr()
    graph = graph.maximum(graph.T)
    tree = minimum_spanning_tree(graph)
    tree = tree + tree.T
    count, labels = connected_components(tree, directed=False)
    out = normals.copy()
    area = dist[:, -1] ** 2  # about each point's share of the surface (k points within that radius)
    for comp in range(count):
        members = np.flatnonzero(labels == comp)
        centre = points[members].mean(axis=0)
        # The walk starts at the point farthest from the centre; its side is settled below with the rest.
        seed = members[np.argmax(np.linalg.norm(points[members] - centre, axis=1))]
        order, pred = breadth_first_order(tree, seed, directed=False, return_predecessors=True)
        _propagate(out, order, pred)
        # The seed's own normal can mislead: the farthest point is often a corner, where the plane fit
        # blends the faces (a 40 x 40 mm prism at 0.1 % noise: every normal came out inward). Over a
        # closed surface the outward normal's flux of (p - centre) is three times the volume, so its sign,
        # summed over the component with each point's share of the area, settles which side is out.
        if np.sum(area[members] * np.einsum("ij,ij->i", out[members], points[members] - centre)) < 0:
            out[members] = -out[members]
    return out, count


def _propagate(normals: np.ndarray, order: np.ndarray, pred: np.ndarray) -> None:
    """Give every node the side of its parent, in breadth-first order (parents come first)."""
    child = order[1:]
    parent = pred[child]
    # sign relative to the parent as estimated; the absolute sign is the product along the path.
    rel = np.sign(np.einsum("ij,ij->i", normals[child], normals[parent]))
    rel[rel == 0] = 1.0
    sign = np.ones(len(normals))
    position = np.empty(len(normals), dtype=np.int64)
    position[order] = np.arange(len(order))
    parent_pos = position[parent]
    # A loop in BFS order is the simple exact form; 1e6 nodes take well under a second in
    # numpy-free Python only if kept scalar, so this runs over plain lists.
    rel_l = rel.tolist()
    ppos = parent_pos.tolist()
    signs = [1.0] * len(order)
    for i in range(1, len(order)):
        signs[i] = signs[ppos[i - 1]] * rel_l[i - 1]
    sign[order] = np.asarray(signs)
    normals[order[1:]] *= sign[order[1:], None]
