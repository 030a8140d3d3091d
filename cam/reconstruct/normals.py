"""Normals for a point cloud: PCA over the k nearest neighbours, read on each point's own sheet.

A plane fit over a point's neighbours gives the normal's line; which way out it points is settled by
:mod:`cam.reconstruct.orient`. Across a thin wall or a narrow gap (the two faces of a 2 mm web, a boss 2 mm
above a floor) the neighbourhoods of a noisy cloud reach the opposite face, whose tangent plane is parallel.
Such neighbours are told apart by their offset from the point's tangent plane, against the gap a sheet of
this noise can show (:data:`SHEET_GAP_NOISE` times the fit's residual, at least the point spacing), and each
normal is refitted on the neighbours of its own face, so a thin wall's normals and noise estimate are as
good as a thick part's (mean error 14.5 -> 11.9 degrees on 2 mm walls). The same gap keeps the orientation's
tree from crossing a wall.

On walls thinner than a neighbourhood (0.7-1 mm at a 60 mm diagonal) the plain fit's residual measured the
wall, not the noise: the noise read high, the fit was widened up to 4x and the sheet gap grew past the
wall. The noise is now read on each point's own sheet, the refit repeated until the gap settles, before the
fit is widened.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from cam import CheckCancel
from cam.reconstruct.orient import NormalsError, orient_outward

__all__ = ["NormalsError", "check_normals", "estimate_normals"]

# Noise ratio (see estimate_normals) above which the neighbourhood grows in proportion. 0.25 when the noise
# was read on the whole neighbourhood; read on the point's own sheet it comes out 12-13 % lower on thick
# parts (Fandisk, Block at 0.1-0.5 % noise), and 0.22 keeps the k those parts had.
NOISE_REFERENCE = 0.22

# Two neighbours are on one sheet while each lies within this many times the median plane-fit residual
# (about the noise's sigma) of the other's tangent plane: Gaussian noise puts two samples of one face
# sqrt(2) sigma apart along the normal, so 3 residuals keep 97 % of same-face pairs, while the two faces of a
# 2 mm wall at the bench's noise (sigma 0.2 mm) lie 10 sigma apart.
SHEET_GAP_NOISE = 3.0


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
        median RMS distance of each point's k neighbours on its own sheet from
        their plane, in units of the median point spacing (about 0 on a clean
        scan of a CAD part, 0.48-0.58 on most of the bench's 50k clouds at
        Gaussian noise of 0.25 % of the diagonal). A plane fit's angular error
        grows with that ratio and falls with the neighbours, so k grows in proportion above a ratio of
        NOISE_REFERENCE, up to 4k. A clean cloud keeps k: a wider fit would
        round its sharp edges.
    workers : int
        Threads for the k-NN query.
    check_cancel : callable, optional
        Called between phases; it stops the work by raising.

    Returns
    -------
    normals : ndarray, shape (n, 3), float64
        Unit vectors turned outward (see :func:`cam.reconstruct.orient.orient_outward`).
    report : dict
        ``k`` (the one used), ``noise_ratio``, ``sheet_gap`` (the offset from a
        neighbour's tangent plane beyond which a pair is taken for two sheets,
        the points' units), and the orientation's report: ``components``,
        ``flipped_share``, ``orientation``, ``outside_voted_share``,
        ``outside_votes_disagree`` (``outside_agreement``).

    Raises
    ------
    NormalsError
        When the normals cannot be oriented (see
        :func:`cam.reconstruct.orient.orient_outward`).
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
    # The noise is read on each point's own sheet: on a part whose walls are thinner than a neighbourhood
    # (0.7 mm walls at a 60 mm diagonal), the plain fit's residual measures the wall, not the noise, and
    # widening the fit by it made the neighbourhoods straddle more and the sheet gap exceed the wall.
    normals, residual = _fit_own_sheet(pts, idx, normals, residual, spacing)
    noise = float(np.median(residual) / spacing)
    sheet_gap = _sheet_gap(residual, spacing)
    wider = min(4 * k, int(round(k * noise / NOISE_REFERENCE)), len(pts) - 1)
    if noise_adaptive and wider > k:
        if check_cancel is not None:
            check_cancel()
        k = wider
        dist, idx = tree.query(pts, k=k + 1, workers=workers)
        dist, idx = dist[:, 1:], idx[:, 1:]
        # Where a wider neighbourhood straddles a thin wall, both faces are parallel, so the plain fit's
        # direction is right; the refit keeps the neighbours within the narrow fit's sheet gap of the point's
        # own face, which gives a normal as good as on a thick part. The gap stays the narrow fit's: a wide
        # fit's residual also measures how the face curves within it.
        normals, _ = _pca_normals(pts, idx)
        normals, _ = _pca_normals(pts, idx, _on_own_sheet(pts, idx, normals, sheet_gap))
    if check_cancel is not None:
        check_cancel()
    normals, sides = orient_outward(pts, normals, idx, dist, sheet_gap)
    if check_cancel is not None:
        check_cancel()
    return normals, {"k": k, "noise_ratio": round(noise, 4), "sheet_gap": sheet_gap, **sides}


def _sheet_gap(residual: np.ndarray, spacing: float) -> float:
    """The offset from a point's tangent plane beyond which a neighbour is on another sheet, the points' units.

    The spacing is the floor: on a clean scan the residual is ~0 while a curved face still bends away from
    its tangent plane by (spacing)^2 / (2 radius) within a neighbourhood.
    """
    return max(SHEET_GAP_NOISE * float(np.median(residual)), spacing)


def _fit_own_sheet(points: np.ndarray, idx: np.ndarray, normals: np.ndarray, residual: np.ndarray,
                   spacing: float, *, rounds: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Refit each normal (n, 3) and residual (n,) on the neighbours within the sheet gap of its own plane.

    Each round takes the gap from the last round's median residual, so a residual inflated by the far face
    of a thin wall shrinks towards the noise; two rounds settle it (a third changes the bench clouds' noise
    estimate by under 2 %).
    """
    for _ in range(rounds):
        normals, residual = _pca_normals(points, idx,
                                         _on_own_sheet(points, idx, normals, _sheet_gap(residual, spacing)))
    return normals, residual


def _on_own_sheet(points: np.ndarray, idx: np.ndarray, normals: np.ndarray, gap: float) -> np.ndarray:
    """(n, k) bool: the neighbours within ``gap`` (the points' units) of each point's tangent plane."""
    return np.abs(np.einsum("nkj,nj->nk", points[idx] - points[:, None, :], normals)) < gap


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


