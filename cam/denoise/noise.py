"""How noisy a mesh is: the spread of its vertices about local quadric fits.

Around every vertex the vertices within a few edge rings are expressed in their own principal frame
(the plane through them and its normal), a quadric height field h(u, v) is fitted to them by least
squares, and the vertex's residual along the normal is divided by sqrt(1 - leverage) (the part of the
noise the fit itself absorbs). On a smooth surface with Gaussian noise of standard deviation sigma
along the normal (or isotropic: only the normal part moves a vertex off the surface) these residuals
have standard deviation sigma; a quadric follows curvature, so a clean curved surface gives nearly
zero. Creases and corners do not fit a quadric: they give large residuals on the few vertices next to
them, which is why the estimate is a median (1.4826 x the median absolute residual is sigma for a
Gaussian), not an RMS.

Two ring radii are measured, 2 and 3. White noise gives about the same sigma at both (ratio 1.01-1.14
measured on Fandisk, Block and the Kinect cone's clean surface with Gaussian noise of 0.05-0.7 mean
edge lengths). Noise that is correlated over several edges (the real Kinect scan's, whose depth errors
move patches of vertices together) is partly absorbed by the quadric of the small neighbourhood and
grows with the radius: 1.36 on the Kinect cone. The ratio is reported as ``correlation``. A third ring
radius of 4 separates less well: the creases of a part enter most 4-ring neighbourhoods, and light
white noise on Fandisk then reads 1.42. The ratio sees correlation over about two to three edges only:
noise smoother than that is followed by the quadrics at both radii and reads as shape (a plane with
white noise smoothed by five neighbour-averaging steps reads 0.95).

All lengths are in units of the mean edge length of the mesh (the unit the denoise filter works in).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from cam.denoise._noisekernel import quadric_residuals, ring_neighbourhoods

__all__ = ["NoiseEstimate", "estimate_noise", "normal_residuals"]

#: Ring radii (in edges) of the fine and the coarse neighbourhood.
FINE_RINGS = 2
COARSE_RINGS = 3
#: Most neighbours a fit uses (the nearest ones of the rings); bounds memory on high-valence vertices.
FINE_MAX_NEIGHBOURS = 24
COARSE_MAX_NEIGHBOURS = 48
#: A fit needs more points than its six quadric coefficients to leave residuals that say anything.
_MIN_NEIGHBOURS = 10
#: 1 / Phi^-1(3/4): the median absolute value of a standard Gaussian is 1 / 1.4826.
_MAD_TO_SIGMA = 1.482602218505602


@dataclass(frozen=True)
class NoiseEstimate:
    """The noise of a mesh, in mean edge lengths.

    Attributes
    ----------
    sigma : float
        Robust standard deviation of the vertices about quadrics fitted over their ``FINE_RINGS``-ring
        neighbourhoods, in mean edge lengths (0 for a clean smooth surface).
    sigma_coarse : float
        The same over ``COARSE_RINGS`` rings.
    correlation : float
        ``sigma_coarse / sigma`` (1 when ``sigma`` is 0): about 1 for noise independent from vertex to
        vertex, larger when neighbouring vertices move together.
    vertices_measured : int
        Vertices with enough neighbours for a fit (the others do not count).
    """

    sigma: float
    sigma_coarse: float
    correlation: float
    vertices_measured: int

    def as_report(self) -> dict:
        """Plain JSON types, for ``denoise.json``."""
        return {"length_unit": "mean edge length", "sigma": float(self.sigma),
                "sigma_coarse": float(self.sigma_coarse), "correlation": float(self.correlation),
                "vertices_measured": int(self.vertices_measured),
                "fine_rings": FINE_RINGS, "coarse_rings": COARSE_RINGS}


def estimate_noise(x: np.ndarray, faces: np.ndarray) -> NoiseEstimate:
    """Robust noise level of a triangle mesh at two neighbourhood sizes.

    Parameters
    ----------
    x : ndarray, shape (n, 3), float
        Vertex positions in units of the mesh's mean edge length (the estimate is returned in the
        units ``x`` is in; pass positions divided by the mean edge length to get edge lengths).
    faces : ndarray, shape (m, 3), integer
        Triangles, indices into ``x``; degenerate faces should be left out by the caller.

    Returns
    -------
    NoiseEstimate
        Fine and coarse sigma in the units of ``x``, their ratio and how many vertices were measured.
        A mesh with no vertex that has enough neighbours gets sigma 0 and 0 vertices measured.

    Raises
    ------
    ValueError
        When ``x`` is not (n, 3) finite reals or ``faces`` is not (m, 3) integers within range.
    """
    x, faces = _check(x, faces)
    fine, n_fine = _robust_sigma(normal_residuals(x, faces, FINE_RINGS, FINE_MAX_NEIGHBOURS))
    coarse, _ = _robust_sigma(normal_residuals(x, faces, COARSE_RINGS, COARSE_MAX_NEIGHBOURS))
    correlation = coarse / fine if fine > 0 else 1.0
    return NoiseEstimate(sigma=fine, sigma_coarse=coarse, correlation=float(correlation),
                         vertices_measured=n_fine)


def normal_residuals(x: np.ndarray, faces: np.ndarray, rings: int, max_neighbours: int) -> np.ndarray:
    """Each vertex's standardised residual along the normal of a quadric fitted around it.

    Parameters
    ----------
    x : ndarray, shape (n, 3), float
        Vertex positions, any unit.
    faces : ndarray, shape (m, 3), integer
        Triangles, indices into ``x``.
    rings : int >= 1
        Neighbourhood: the vertices at most this many edges away.
    max_neighbours : int >= 10
        At most this many of them (the nearest, the vertex itself included) enter a fit.

    Returns
    -------
    ndarray, shape (n,), float
        Residual of the vertex from its fitted quadric, along the fit's normal, divided by
        sqrt(1 - leverage), in the units of ``x``; NaN where a vertex has fewer than 10 neighbours
        or its fit is degenerate (all neighbours on a line).

    Raises
    ------
    ValueError
        For bad arrays (see :func:`estimate_noise`), ``rings < 1`` or ``max_neighbours < 10``.
    """
    x, faces = _check(x, faces)
    if rings < 1:
        raise ValueError(f"rings must be at least 1, got {rings}")
    if max_neighbours < _MIN_NEIGHBOURS:
        raise ValueError(f"max_neighbours must be at least {_MIN_NEIGHBOURS}, got {max_neighbours}")
    idx, count = _ring_neighbourhoods(x, faces, rings, max_neighbours)
    return quadric_residuals(x, idx, count, min_count=_MIN_NEIGHBOURS)


def _robust_sigma(residuals: np.ndarray) -> tuple[float, int]:
    r = residuals[np.isfinite(residuals)]
    if len(r) == 0:
        return 0.0, 0
    return float(_MAD_TO_SIGMA * np.median(np.abs(r))), len(r)


def _ring_neighbourhoods(x: np.ndarray, faces: np.ndarray, rings: int,
                         max_neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, K) indices of the nearest vertices within ``rings`` edges of each vertex, the first ``count`` (n,) of
    each row (`cam.denoise._noisekernel.ring_neighbourhoods`)."""
    n = len(x)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    adj = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                        shape=(n, n))
    return ring_neighbourhoods(x, adj.indptr, adj.indices, rings=rings, max_neighbours=max_neighbours)


def _check(x, faces) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x)
    f = np.asarray(faces)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x must have shape (n, 3), got {x.shape}")
    if not np.issubdtype(x.dtype, np.number) or np.issubdtype(x.dtype, np.complexfloating):
        raise ValueError(f"x must be real numbers, got dtype {x.dtype}")
    x = x.astype(np.float64, copy=False)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"x contains {int((~np.isfinite(x)).sum())} non-finite values")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (m, 3), got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be integer vertex indices, got dtype {f.dtype}")
    if len(f) and (f.min() < 0 or f.max() >= len(x)):
        raise ValueError(f"face indices must lie in [0, {len(x) - 1}], got [{f.min()}, {f.max()}]")
    return x, f.astype(np.int64, copy=False)
