"""What the fit reports per patch, measured afresh: the records `fit_patches` returns and how they are filled.

Every mesh sample is measured against the final surfaces (`sample_errors`: its own patch's, or a
neighbour's where that passes closer), every surface against the mesh (the peaks its refinement searched
for, `cam.fit.measure.surface_peaks`), and the worst of both is reported with where it is and how far
that is from a crease of the mesh. Nothing over the tolerance is hidden: `FitResult.over_tolerance`
lists the patches, `FitResult.at_crease` those whose layout misses a crease.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam import CheckCancel, Progress, map_forked
from cam.fit.boundary import SIDES, Layout, side_params
from cam.fit.foot import distance_to_surface
from cam.fit.measure import surface_peaks
from cam.fit.refine import Refined
from cam.fit.solve import SurfaceFit
from cam.mesh.closest import MeshIndex
from cam.mesh.creases import Creases, closest_on_creases
from cam.spline.folds import FOLD_CHECK_SAMPLES, find_folds
from cam.spline.surface import BSplineSurface, make_bspline_surface

__all__ = ["FitResult", "PatchFit", "max_gap", "report_patches", "sample_errors"]


@dataclass(frozen=True, eq=False)
class PatchFit:
    """One patch's surface (parameters on [0, 1]) and how well it fits.

    Attributes
    ----------
    index : int
        The patch's index in the grids given.
    surface : BSplineSurface
        The bicubic surface, parameters on [0, 1], mm.
    max_error_mm : float
        The largest of the samples' distances and `surface_to_mesh_mm`, mm.
    mean_error_mm : float
        Mean distance from the patch's mesh samples to the fitted surfaces (a sample beyond the
        border counts against the nearest neighbour), mm; 0 without samples.
    surface_to_mesh_mm : float
        The largest distance from points of the surface to the mesh, mm.
    boundary_error_mm : float
        The largest distance of its boundary curves from the mesh (along a crease, from the crease), mm.
    samples : int
        The mesh samples the patch owns.
    refinements : int
        Rounds of knot insertion its final fit took.
    within_tolerance : bool
        max_error_mm <= the tolerance.
    neighbours : tuple of int
        The patches it shares a border with.
    side_neighbours : dict of str to tuple of int
        The same per side ("u0", "u1", "v0", "v1").
    worst_point_mm : ndarray, shape (3,), float64
        Where max_error_mm is (the mesh sample, or the point of the surface), mm.
    worst_crease_mm : float
        Its distance to the nearest crease of the mesh (edges sharper than the fit's crease angle;
        inf without one), mm. About the error itself or less, the surface cuts or misses a crease
        there: one the patch layout does not follow, which no surface of this patch can.
    folded_fraction : float
        Share of the surface that folds over itself (`cam.spline.surface.find_folds` on the grid the
        planner checks, `FOLD_CHECK_SAMPLES`; 0 for a regular patch), reported because a fold can hug
        the mesh and still pass the distance test.
    """

    index: int
    surface: BSplineSurface
    max_error_mm: float
    mean_error_mm: float
    surface_to_mesh_mm: float
    boundary_error_mm: float
    samples: int
    refinements: int
    within_tolerance: bool
    neighbours: tuple[int, ...]
    side_neighbours: dict[str, tuple[int, ...]]
    worst_point_mm: np.ndarray
    worst_crease_mm: float
    folded_fraction: float = 0.0


@dataclass(frozen=True, eq=False)
class FitResult:
    """What `cam.fit.patches.fit_patches` returns.

    Attributes
    ----------
    patches : list of PatchFit
        Every patch's fit, in the order of the grids given.
    max_gap_mm : float
        The largest gap between neighbours along shared borders, mm.
    curves : int
        The number of boundary curves.
    tolerance_mm : float
        The tolerance used, mm.
    """

    patches: list[PatchFit]
    max_gap_mm: float
    curves: int
    tolerance_mm: float

    @property
    def over_tolerance(self) -> list[int]:
        """Indices of the patches whose max_error_mm exceeds the tolerance."""
        return [p.index for p in self.patches if not p.within_tolerance]

    @property
    def at_crease(self) -> list[int]:
        """Indices of the patches over tolerance whose worst point lies within twice their error of a
        crease of the mesh: the layout misses that crease, which no refinement of the fit mends."""
        return [p.index for p in self.patches
                if not p.within_tolerance and p.worst_crease_mm <= 2.0 * p.max_error_mm]

    @property
    def folded(self) -> list[int]:
        """Indices of the patches whose surface folds over itself somewhere."""
        return [p.index for p in self.patches if p.folded_fraction > 0]


def report_patches(refined: list[Refined], *, samples: np.ndarray, owner: np.ndarray, errors: np.ndarray,
                   shape: list[tuple[int, int]], layout: Layout, index: MeshIndex, creases: Creases,
                   curve_errors: list[float], tolerance_mm: float, check_cancel: CheckCancel | None = None
                   ) -> list[PatchFit]:
    """Each patch's surface on [0, 1]² and how well it fits.

    Parameters
    ----------
    refined : list of Refined
        Per patch, its final fit (grid-index units), refinement rounds and peaks searched for.
    samples : ndarray, shape (n, 3), float64
        Every mesh sample, mm.
    owner : ndarray, shape (n,), int64
        Each sample's patch (-1: none).
    errors : ndarray, shape (n,), float64
        Each sample's distance to the surfaces, mm (`sample_errors`).
    shape : list of (int, int)
        Per patch, (R, C): its quad counts.
    layout : Layout
        The patches' sides and neighbours (`cam.fit.boundary.boundary_layout`).
    index : MeshIndex
        The triangle mesh.
    creases : Creases
        Its creases, for the worst points' distance to them.
    curve_errors : list of float
        Each boundary curve's largest deviation, mm.
    tolerance_mm : float
        The fit's tolerance, mm.
    check_cancel : callable or None
        Called before each patch; it raises to stop.

    Returns
    -------
    list of PatchFit
        One per patch, in order.
    """
    out = []
    for k, done in enumerate(refined):
        if check_cancel is not None:
            check_cancel()
        out.append(_report_patch(k, done, samples=samples, owner=owner, errors=errors, shape=shape[k],
                                 layout=layout, index=index, creases=creases, curve_errors=curve_errors,
                                 tolerance_mm=tolerance_mm))
    return out


def _report_patch(k: int, done: Refined, *, samples, owner, errors, shape, layout: Layout, index, creases,
                  curve_errors, tolerance_mm: float) -> PatchFit:
    """Patch k's report: its surface scaled to [0, 1]², its samples' errors and the surface's own, where
    the worst is and how far from a crease."""
    R, C = shape
    fit = done.fit
    surf = make_bspline_surface(fit.control_points, fit.knots_u / R, fit.knots_v / C)
    mine = owner == k
    e = errors[mine]
    # The refinement searched the final surface already, unless it was not given the mesh (mesh_weight 0).
    found = done.peaks if done.peaks[2].size else surface_peaks(index, fit.knots_u, fit.knots_v, fit.control_points)
    s2m = float(found[2].max(initial=0.0))
    berr = max((curve_errors[p.curve] for name in SIDES for p in layout.sides[(k, name)]), default=0.0)
    worst = max(float(e.max(initial=0.0)), s2m)
    if e.size and e.max() >= s2m:
        at = samples[mine][int(np.argmax(e))]
    else:
        i = int(np.argmax(found[2]))
        at = surf.evaluate(found[0][i:i + 1] / R, found[1][i:i + 1] / C)[0]
    return PatchFit(index=k, surface=surf, max_error_mm=worst, mean_error_mm=float(e.mean()) if e.size else 0.0,
                    surface_to_mesh_mm=s2m, boundary_error_mm=berr, samples=int(e.size), refinements=done.rounds,
                    within_tolerance=worst <= tolerance_mm, neighbours=layout.neighbours[k],
                    side_neighbours={s: layout.side_neighbours[(k, s)] for s in SIDES},
                    folded_fraction=find_folds(surf, samples=FOLD_CHECK_SAMPLES)[0],
                    worst_point_mm=at, worst_crease_mm=float(closest_on_creases(creases, at[None])[1][0]))


def sample_errors(P: np.ndarray, owner: np.ndarray, fits: list[SurfaceFit], layout: Layout, tolerance_mm: float, *,
                  processes: int = 1, check_cancel: CheckCancel | None = None, progress: Progress | None = None
                  ) -> np.ndarray:
    """Distance of every assigned sample to the fitted surfaces: its own patch's, or a neighbour's where closer.

    Measured afresh on all samples, not taken from the fit, which may have used a subset; a
    distance over the tolerance is searched for span by span before it counts.

    Parameters
    ----------
    P : ndarray, shape (n, 3), float64
        The mesh samples, mm.
    owner : ndarray, shape (n,), int
        Each sample's patch (-1: none).
    fits : list of SurfaceFit
        Per patch, its surface (grid-index units).
    layout : Layout
        The patches' neighbours (`cam.fit.boundary.boundary_layout`).
    tolerance_mm : float
        Distances above it are searched for and looked up on the neighbours, mm.
    processes : int
        Patches measured at once, in forked processes (`cam.map_forked`; the same distances).
    check_cancel : callable or None
        Called before each patch; it raises to stop.
    progress : callable or None
        progress(fraction, message) as the patches are measured.

    Returns
    -------
    ndarray, shape (n,), float64
        The distances, mm; NaN where the sample has no patch.
    """
    err = np.full(len(P), np.nan)
    groups = [np.flatnonzero(owner == k) for k in range(len(fits))]
    todo = [k for k in range(len(fits)) if groups[k].size]
    measured = map_forked(lambda i, cc, pr: _patch_errors(P[groups[todo[i]]], todo[i], fits, layout, tolerance_mm,
                                                          progress=pr),
                          len(todo), processes=processes, check_cancel=check_cancel, progress=progress,
                          item_progress=True)
    for k, d in zip(todo, measured):
        err[groups[k]] = d
    return err


def _patch_errors(P: np.ndarray, k: int, fits: list[SurfaceFit], layout: Layout, tolerance_mm: float, *,
                  progress: Progress) -> np.ndarray:
    """Distances (n,) mm of patch k's samples P (n, 3) to its surface, or to a neighbour's where closer."""
    fit = fits[k]
    neighbours = layout.neighbours[k]
    progress(0.0, f"patch {k + 1}: its {len(P)} samples on its own surface")
    d = distance_to_surface(fit.knots_u, fit.knots_v, fit.control_points, P, search_above=tolerance_mm)[2]
    # Every far sample, not only those whose foot is on the border: where the quad mesh cuts
    # a corner of the part, a sample can take a strip's quad and a foot inside the strip
    # while the neighbour's surface passes through it.
    for i, nb in enumerate(neighbours):
        far = np.flatnonzero(d > tolerance_mm)
        if not far.size:
            break
        progress((i + 1) / (len(neighbours) + 1), f"patch {k + 1}: {far.size} far samples on neighbour {nb + 1}")
        f = fits[nb]
        d[far] = np.minimum(d[far], distance_to_surface(f.knots_u, f.knots_v, f.control_points, P[far],
                                                        search_above=tolerance_mm)[2])
    return d


def max_gap(patches: list[PatchFit], layout: Layout, shape: list[tuple[int, int]], *, samples: int = 64) -> float:
    """Largest distance between two patches along the boundary they share.

    Parameters
    ----------
    patches : list of PatchFit
        The patches' surfaces, parameters on [0, 1].
    layout : Layout
        Their shared segments (`cam.fit.boundary.boundary_layout`).
    shape : list of (int, int)
        Per patch, (R, C): its quad counts.
    samples : int
        Points compared along each shared segment.

    Returns
    -------
    float
        The largest distance, mm (0 without shared segments).
    """
    worst = 0.0
    for seg in layout.shared:
        pts = []
        for (k, name, t0, t1), flip in ((seg.a, False), (seg.b, seg.reversed)):
            R, C = shape[k]
            t = np.linspace(t0, t1, samples)
            if flip:
                t = t[::-1]
            u, v = side_params(name, t, R, C)
            pts.append(patches[k].surface.evaluate(u / R, v / C))
        worst = max(worst, float(np.linalg.norm(pts[0] - pts[1], axis=1).max()))
    return worst
