"""Fit every patch: free fits, shared boundary curves, border-constrained fits, refinement, report.

The order follows the paper with C0 made exact:
1. each patch is fitted on its own (squared-distance iteration, its quad grid holding
   the parameterisation and the extent), and samples that fell beyond a border move to
   the neighbour that is closer;
2. each boundary curve is fitted once, through the junction points where patches meet:
   along a sharp edge to the mesh's own crease, elsewhere to where the patches' own fits
   put their borders (`cam.fit.borders`);
3. each patch is fitted again with its border rows taken from the curves (knots
   merged, curves refined into them by exact knot insertion) and held fixed;
4. spans still beyond the tolerance are halved and refitted; what remains beyond it
   is reported per patch, never hidden (`cam.fit.report`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from cam import CheckCancel, GeometryError, Progress, map_forked, progress_labelled
from cam.fit.borders import find_kinks, fit_boundary_curves, seed_bordered_net
from cam.fit.boundary import SIDES, Layout, boundary_layout, side_vertices
from cam.fit.crease import edge_keys, is_sharp_polyline, vertex_positions
from cam.fit.curve import CurveFit
from cam.fit.foot import distance_to_surface
from cam.fit.param import (
    Anchors,
    Assignment,
    assign_samples,
    grid_anchors,
    mesh_samples,
)
from cam.fit.refine import Refined, fit_refined
from cam.fit.report import FitResult, PatchFit, max_gap, report_patches, sample_errors
from cam.fit.solve import SurfaceFit
from cam.mesh.closest import MeshIndex, mesh_index
from cam.mesh.creases import Creases, mesh_creases
from cam.params import FitParams
from cam.spline.knots import lattice_knots, merge_knots

__all__ = ["PatchFit", "FitResult", "fit_patches"]

# A free fit is refined for, and judged on, what lies within this many quads of its sides: only its
# borders are used (the boundary curves' data along smooth borders), and the bordered fit starts from
# the unrefined one. Refining for their insides too, the free fits' rounds took about half the time
# spent fitting surfaces on a 50k-point Fandisk cloud, and brought none of them within tolerance.
FREE_BAND_QUADS = 1.0


def fit_patches(vertices: np.ndarray, grids: list[np.ndarray], mesh_vertices: np.ndarray, mesh_faces: np.ndarray,
                params: FitParams, *, other_quads: np.ndarray | None = None, sharp_edges: np.ndarray | None = None,
                processes: int = 1, progress: Progress | None = None, check_cancel: CheckCancel | None = None
                ) -> FitResult:
    """Bicubic B-spline surfaces for patches of a quad mesh, fitted to a triangle mesh, C0 where they meet.

    Parameters
    ----------
    vertices : ndarray, shape (k, 3), float64
        The quad mesh's vertices, mm.
    grids : list of ndarray, each shape (R + 1, C + 1), int
        Per patch, its vertex ids (see `cam.fit.grid.patch_grid`).
    mesh_vertices : ndarray, shape (n, 3), float64
        The triangle mesh to fit, mm.
    mesh_faces : ndarray, shape (m, 3), int
        Its triangles.
    params : FitParams
        The fit's group with `tolerance_mm` resolved (`JobParams.effective("fit")`): its
        knot_spacing_quads: quads per knot span to start with; samples_per_face: mesh points taken
        inside each triangle besides its corners; max_samples_per_quad: the fit uses at most this many
        samples per patch quad on average (an evenly strided subset; a fine reconstructed mesh has
        ~100), None: all of them; the reported errors are measured on every sample either way;
        max_refinements, iterations, smoothing_mm2, normal_weight_mm: see
        `cam.fit.refine.fit_refined` and `cam.fit.solve.fit_surface`; crease_angle_deg and
        snap_radius_quads: see `sharp_edges`. `require_tolerance` is the caller's to act on
        (`FitResult.over_tolerance`).
    other_quads : ndarray, shape (q, 4), int, or None
        Quads in no patch (their mesh samples are not fitted).
    sharp_edges : ndarray, shape (e, 2), int, or None
        Quad-mesh vertex pairs on sharp edges; patch borders along them are moved onto the mesh's
        creases (edges sharper than `params.crease_angle_deg`) found within
        `params.snap_radius_quads` quad edges.
    processes : int
        Patches fitted at once, in forked processes (`cam.map_forked`); the surfaces are bit for bit those
        of one process.
    progress : callable or None
        progress(fraction, message=None), called between patches and between the steps of each patch's
        fit (from the forked processes too).
    check_cancel : callable or None
        Called between patches and inside each patch's fit; it raises to stop the fit.

    Returns
    -------
    FitResult
        Every patch's surface (parameters on [0, 1], mm) and errors, the largest gap between
        neighbours and the tolerance used.

    Raises
    ------
    GeometryError
        Where the patches cannot be fitted as given: none at all, or
        `cam.fit.boundary.PatchLayoutError` (an edge on more than two patch sides).
    ValueError
        For arguments no caller should pass (shapes, ids, an unresolved tolerance).
    """
    return _fit_patches(vertices, grids, mesh_vertices, mesh_faces, params, other_quads=other_quads,
                        sharp_edges=sharp_edges, processes=processes, progress=progress, check_cancel=check_cancel)


@dataclass(frozen=True, eq=False)
class _Problem:
    """What every step of the fit reads, per patch where a list.

    samples (n, 3) mm and assignment: every mesh sample and its patch, as measured at the end;
    points, normals (s, 3) and owner, u, v (s,): the samples the fits use (thinned), whose owner and
    parameters move to a neighbour when the free fits put them beyond their patch's border;
    start_knots: the free fits' first knots (C0 knot lines where a side turns a corner);
    pull: per side (`SIDES`), whether samples beyond it pull the free fit's border out.
    """

    grids: list[np.ndarray]
    shape: list[tuple[int, int]]
    layout: Layout
    index: MeshIndex
    sharp: set[tuple[int, int]]
    creases: Creases | None
    positions: np.ndarray
    samples: np.ndarray
    assignment: Assignment
    points: np.ndarray
    normals: np.ndarray
    owner: np.ndarray
    u: np.ndarray
    v: np.ndarray
    anchors: list[Anchors]
    lengths: list[tuple[float, float]]
    start_knots: list[tuple[np.ndarray, np.ndarray]]
    pull: list[tuple[bool, ...]]


def _fit_patches(vertices: np.ndarray, grids: list[np.ndarray], mesh_vertices: np.ndarray, mesh_faces: np.ndarray,
                 params: FitParams, *, other_quads: np.ndarray | None = None, sharp_edges: np.ndarray | None = None,
                 processes: int = 1, progress: Progress | None = None, check_cancel: CheckCancel | None = None,
                 smoothing_floor: float = 1e-6, param_weight: float = 0.01, anchor_weight: float = 1.0,
                 min_span_quads: float = 0.125, kink_angle_deg: float = 30.0, mesh_weight: float = 1.0) -> FitResult:
    """`fit_patches` with the fit's inner weights open to change (tests and benches; no user sets them).

    smoothing_floor, param_weight, anchor_weight: see `cam.fit.solve.fit_surface`. min_span_quads:
    refinement halves knot spans, never below this many quads. kink_angle_deg: where a patch side
    turns by more than this at a vertex (it runs round a corner of the part), its surface gets a C0
    knot line there. mesh_weight: weight of the surface's own points drawn onto the mesh, against the
    samples' 1 (`cam.fit.solve.fit_surface`; 0: samples only).
    """
    V, grids = _check_inputs(vertices, grids, params)
    # One BLAS thread for the whole fit, here and in the processes it forks: LAPACK splits the banded
    # factorisations' sums along its threads, so the surfaces would depend on the process count (the serial
    # run is the reference), and BLAS threads on top of the forked processes wait on each other (the
    # factorisations took three to five times as long, two processes of two threads each on two cores).
    with threadpool_limits(1, user_api="blas"):
        report = progress or (lambda fraction, message=None: None)
        cancel = check_cancel or (lambda: None)
        problem = _prepare(V, grids, mesh_vertices, mesh_faces, params, other_quads=other_quads,
                           sharp_edges=sharp_edges, kink_angle_deg=kink_angle_deg)
        fit_opts = dict(tolerance_mm=params.tolerance_mm, max_refinements=params.max_refinements,
                        min_span=min_span_quads, smoothing_mm2=params.smoothing_mm2, smoothing_floor=smoothing_floor,
                        param_weight=param_weight,
                        normal_weight_mm=params.normal_weight_mm, anchor_weight=anchor_weight,
                        iterations=params.iterations, mesh=problem.index if mesh_weight > 0 else None,
                        mesh_weight=mesh_weight, check_cancel=cancel)
        each = _Each(processes=processes, report=report, cancel=cancel,
                     sizes=np.bincount(problem.owner[problem.owner >= 0], minlength=len(problem.grids)))
        free = _fit_free(problem, fit_opts, each)
        # The constrained fits start from the first free fits, before refinement (and before samples
        # moved: they refit from the top anyway): knot lines run across the whole patch, and the spans a
        # free fit split for one border would free every row and column to follow the mesh's facets
        # (ripples no tolerance sees, concave tighter than the ball). They refine themselves where they
        # need it.
        coarse = [f.unrefined for f in free]
        free = _refit_moved(problem, free, fit_opts, each)
        report(0.4, "fitting the shared boundary curves")
        curves, curve_err = fit_boundary_curves(
            problem.layout, problem.shape, [f.fit for f in free], problem.positions, problem.index, problem.creases,
            problem.sharp, knot_spacing_quads=params.knot_spacing_quads, tolerance_mm=params.tolerance_mm,
            max_refinements=params.max_refinements, min_span_quads=min_span_quads, kink_angle_deg=kink_angle_deg,
            processes=processes, check_cancel=cancel)
        final = _fit_bordered(problem, coarse, curves, fit_opts, each)
        report(0.92, "measuring every mesh sample against the surfaces")
        errors = sample_errors(problem.samples, problem.assignment.patch, [f.fit for f in final], problem.layout,
                               params.tolerance_mm, processes=processes, check_cancel=cancel,
                               progress=progress_labelled(report, 0.92, 0.97,
                                                          "measuring every mesh sample against the surfaces"))
        report(0.97, "reporting each patch: its errors, folds and creases")
        creases = problem.creases
        if creases is None:
            creases = mesh_creases(mesh_vertices, mesh_faces, angle_deg=params.crease_angle_deg)
        patches = report_patches(final, samples=problem.samples, owner=problem.assignment.patch, errors=errors,
                                 shape=problem.shape, layout=problem.layout, index=problem.index, creases=creases,
                                 curve_errors=curve_err, tolerance_mm=params.tolerance_mm, check_cancel=cancel)
        report(1.0, "fitted")
        return FitResult(patches=patches, max_gap_mm=max_gap(patches, problem.layout, problem.shape),
                         curves=len(curves), tolerance_mm=params.tolerance_mm)


def _check_inputs(vertices: np.ndarray, grids: list[np.ndarray], params: FitParams
                  ) -> tuple[np.ndarray, list[np.ndarray]]:
    """The quad mesh's vertices (k, 3) mm and the grids as arrays, once the arguments are checked."""
    tolerance_mm = params.tolerance_mm
    if tolerance_mm is None:
        raise ValueError("params.tolerance_mm is None: the fit needs the group with its tolerance resolved, "
                         "as JobParams.effective(\"fit\") returns it")
    if not tolerance_mm > 0:
        raise ValueError(f"tolerance_mm must be positive, got {tolerance_mm}")
    if not params.knot_spacing_quads > 0:
        raise ValueError(f"knot_spacing_quads must be positive, got {params.knot_spacing_quads}")
    if params.max_samples_per_quad is not None and not params.max_samples_per_quad > 0:
        raise ValueError(f"max_samples_per_quad must be positive or None, got {params.max_samples_per_quad}")
    V = np.asarray(vertices, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"vertices must have shape (k, 3), got {V.shape}")
    if not len(grids):
        raise GeometryError("there is no patch to fit: every patch of the layout was left out")
    grids = [np.asarray(g, dtype=np.int64) for g in grids]
    for k, g in enumerate(grids):
        if g.ndim != 2 or min(g.shape) < 2:
            raise ValueError(f"grid {k} must be (R + 1, C + 1) with R, C >= 1, got shape {g.shape}")
        if g.min() < 0 or g.max() >= len(V):
            raise ValueError(f"grid {k} refers to vertex ids outside 0..{len(V) - 1}")
    return V, grids


def _prepare(V: np.ndarray, grids: list[np.ndarray], mesh_vertices: np.ndarray, mesh_faces: np.ndarray,
             params: FitParams, *, other_quads: np.ndarray | None, sharp_edges: np.ndarray | None,
             kink_angle_deg: float) -> _Problem:
    """The layout, the grid vertices on the mesh (on its creases along sharp edges), the samples and
    their patches, and each patch's anchors and first knots."""
    layout = boundary_layout(grids)
    index = mesh_index(mesh_vertices, mesh_faces)
    sharp = edge_keys(sharp_edges)
    creases = mesh_creases(mesh_vertices, mesh_faces, angle_deg=params.crease_angle_deg) if sharp else None
    positions = vertex_positions(V, grids, index, sharp=sharp, creases=creases,
                                 snap_radius_quads=params.snap_radius_quads)
    samples, normals = mesh_samples(mesh_vertices, mesh_faces, per_face=params.samples_per_face)
    # Samples go to the quad nearest them once the grid vertices sit where the fit puts them:
    # the remesher's sharp edges run up to a quad beside the crease, and a sample on the far
    # face (the neighbour's, or the unfitted base's) would otherwise belong to this patch.
    placed = np.where(np.isfinite(positions), positions, V)
    assignment = assign_samples(samples, placed, grids, other_quads=other_quads)
    use = _thin(assignment.patch, grids, params.max_samples_per_quad)
    return _Problem(
        grids=grids, shape=[(g.shape[0] - 1, g.shape[1] - 1) for g in grids], layout=layout, index=index,
        sharp=sharp, creases=creases, positions=positions, samples=samples, assignment=assignment,
        points=samples[use], normals=normals[use], owner=assignment.patch[use], u=assignment.u[use],
        v=assignment.v[use],
        anchors=[grid_anchors(V, g, index, knot_spacing_quads=params.knot_spacing_quads, positions=positions)
                 for g in grids],
        lengths=[_lengths(V, g) for g in grids],
        start_knots=[_start_knots(g, positions, knot_spacing_quads=params.knot_spacing_quads,
                                  kink_angle_deg=kink_angle_deg) for g in grids],
        pull=[tuple(not is_sharp_polyline(side_vertices(g, name), sharp) for name in SIDES) for g in grids])


def _start_knots(grid: np.ndarray, positions: np.ndarray, *, knot_spacing_quads: float, kink_angle_deg: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A patch's first knots: `knot_spacing_quads` apart, with a C0 knot line where a side turns a corner.

    A side that turns a corner needs that knot line in the free fit already: a smooth surface cuts
    the corner, and the boundary curves are fitted to where the free fits' borders lie.
    """
    R, C = grid.shape[0] - 1, grid.shape[1] - 1
    kinks = {name: find_kinks(positions[side_vertices(grid, name)], kink_angle_deg).astype(np.float64)
             for name in SIDES}
    return (merge_knots(lattice_knots(0, R, knot_spacing_quads), np.repeat(kinks["v0"], 3), np.repeat(kinks["v1"], 3)),
            merge_knots(lattice_knots(0, C, knot_spacing_quads), np.repeat(kinks["u0"], 3), np.repeat(kinks["u1"], 3)))


def _patch_data(problem: _Problem, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Patch k's fit data: points and normals (s, 3), parameters u, v (s,)."""
    # The patch's mesh samples, then its grid vertices on the mesh: a patch too thin to own
    # samples still has data, and results are reported for the samples only (the first rows).
    sel = problem.owner == k
    a = problem.anchors[k]
    return (np.concatenate([problem.points[sel], a.points]), np.concatenate([problem.normals[sel], a.normals]),
            np.concatenate([problem.u[sel], a.u]), np.concatenate([problem.v[sel], a.v]))


def _fit_free_patch(problem: _Problem, k: int, start: SurfaceFit | None, fit_opts: dict) -> Refined:
    """Patch k fitted on its own, from its first knots or from `start`, refined for its borders."""
    ku, kv = problem.start_knots[k]
    kw = dict(knots_u=ku, knots_v=kv)
    if start is not None:
        kw = dict(knots_u=start.knots_u, knots_v=start.knots_v, control_points=start.control_points)
    pts, nrm, u, v = _patch_data(problem, k)
    return fit_refined(pts, nrm, u, v, lengths_mm=problem.lengths[k], anchors=problem.anchors[k],
                       pull_sides=problem.pull[k], judge_band=FREE_BAND_QUADS, **kw, **fit_opts)


@dataclass(frozen=True)
class _Each:
    """How the per-patch loops run: `processes` patches at once, reporting and checking for cancel; `sizes`
    (patches,): each patch's samples, what its fit costs roughly."""

    processes: int
    report: Progress
    cancel: CheckCancel
    sizes: np.ndarray

    def map(self, fit_one, ks: list[int], start: float, end: float, label: str) -> list[Refined]:
        """[fit_one(k, check_cancel, progress) for k in ks], progress from `start` to `end`, each patch's
        own steps counted as it runs; the message is `label`, the patches done and what runs."""
        # Largest first: a large patch handed out last would leave the other processes idle while it runs.
        # Each fit is independent of the others, so the order changes no result.
        order = sorted(range(len(ks)), key=lambda i: -int(self.sizes[ks[i]]))

        def one(j: int, cc: CheckCancel, item_progress: Progress) -> Refined:
            def patch_progress(fraction: float, message: str | None = None) -> None:
                item_progress(fraction, f"patch {ks[order[j]] + 1}" + (f": {message}" if message else ""))

            return fit_one(ks[order[j]], cc, patch_progress)

        done = map_forked(one, len(ks), processes=self.processes, check_cancel=self.cancel,
                          progress=progress_labelled(self.report, start, end, label), item_progress=True)
        out: list = [None] * len(ks)
        for j, i in enumerate(order):
            out[i] = done[j]
        return out


def _fit_free(problem: _Problem, fit_opts: dict, each: _Each) -> list[Refined]:
    """Every patch fitted on its own (free fits, refined for their borders, where the curves are fitted)."""
    return each.map(lambda k, cc, pr: _fit_free_patch(problem, k, None, {**fit_opts, "check_cancel": cc,
                                                                          "progress": pr}),
                    list(range(len(problem.grids))), 0.0, 0.33, "fitting each patch on its own")


def _refit_moved(problem: _Problem, free: list[Refined], fit_opts: dict, each: _Each) -> list[Refined]:
    """The free fits, with those whose samples moved to or from a neighbour fitted again from where they were:
    solved once more on the knots their first fit refined to, without rounds of their own (the free fits
    only place the borders, and a round here refined spans that the bordered fit, which starts from the
    unrefined fits, never sees: on the 50k-point Fandisk cloud a fifth of the stage's time, for the same
    surfaces within tolerance)."""
    moved = sorted(_reassign(problem.points, problem.owner, problem.u, problem.v, [f.fit for f in free],
                             problem.layout, fit_opts["tolerance_mm"], processes=each.processes,
                             check_cancel=each.cancel,
                             progress=progress_labelled(each.report, 0.33, 0.35, "moving samples beyond a border "
                                                        "to a neighbour that is closer")))
    refits = each.map(lambda k, cc, pr: _fit_free_patch(problem, k, free[k].fit, {**fit_opts, "max_refinements": 0,
                                                                                  "check_cancel": cc, "progress": pr}),
                      moved, 0.35, 0.4, "fitting again the patches whose samples moved")
    free = list(free)
    for k, fit in zip(moved, refits):
        free[k] = fit
    return free


def _fit_bordered(problem: _Problem, coarse: list[SurfaceFit], curves: list[CurveFit], fit_opts: dict,
                  each: _Each) -> list[Refined]:
    """Every patch fitted again inside its border rows, taken from the boundary curves and held fixed."""

    def fit_one(k: int, cc: CheckCancel, pr: Progress) -> Refined:
        ku, kv, cp = seed_bordered_net(k, problem.layout, coarse[k], curves)
        pts, nrm, u, v = _patch_data(problem, k)
        # The final surfaces are drawn onto the mesh on a lattice an eighth of a quad apart, the free
        # fits on a quarter: between a quarter's points a refined surface still rippled past the
        # tolerance (a bump's fit, 0.03204 mm), and the free fits only place the borders.
        return fit_refined(pts, nrm, u, v, knots_u=ku, knots_v=kv, control_points=cp, fix_border=True,
                           lengths_mm=problem.lengths[k], anchors=problem.anchors[k], mesh_spacing=0.125,
                           mesh_edges=True, **{**fit_opts, "check_cancel": cc, "progress": pr})

    return each.map(fit_one, list(range(len(problem.grids))), 0.4, 0.9,
                    "fitting each patch inside its shared borders")


def _lengths(V: np.ndarray, g: np.ndarray) -> tuple[float, float]:
    """Mean mm per grid-index unit along u and v (scales the bending energy to the part)."""
    pts = V[g]
    lu = np.linalg.norm(np.diff(pts, axis=0), axis=2).mean()
    lv = np.linalg.norm(np.diff(pts, axis=1), axis=2).mean()
    return float(max(lu, 1e-9)), float(max(lv, 1e-9))


def _thin(owner: np.ndarray, grids: list[np.ndarray], per_quad: float | None) -> np.ndarray:
    """bool mask of the samples the fit uses: per patch at most `per_quad` x its quads, evenly strided.

    Mesh samples come in mesh order, which is spatially coherent, so a stride spreads them over the patch.
    """
    use = np.ones(len(owner), dtype=bool)
    if per_quad is None:
        return use
    for k, g in enumerate(grids):
        idx = np.flatnonzero(owner == k)
        budget = max(int(per_quad * (g.shape[0] - 1) * (g.shape[1] - 1)), 16)
        if idx.size > budget:
            keep = np.zeros(idx.size, dtype=bool)
            keep[np.round(np.linspace(0, idx.size - 1, budget)).astype(np.int64)] = True
            use[idx[~keep]] = False
    return use


def _reassign(P, owner, su, sv, fits, layout: Layout, tolerance_mm: float, *, processes: int = 1,
              check_cancel: CheckCancel | None = None, progress: Progress | None = None) -> set[int]:
    """Move samples that lie beyond their patch's border to a neighbour that is closer; returns changed patches.

    P float64 (n, 3) mm; owner int (n,) patch per sample, su, sv float64 (n,) its parameters (quads):
    all three updated in place for the samples that move. Each patch's moves are found from the samples it
    owned before any moved, so the patches are searched in `processes` forked processes and the moves
    applied in patch order, as one process would.
    """
    before = owner.copy()  # the fits' sample order

    def moves(k: int, _cancel: CheckCancel) -> tuple[np.ndarray, ...] | None:
        fit = fits[k]
        idx = np.flatnonzero(before == k)
        far = fit.clamped[: idx.size] & (fit.distance[: idx.size] > 0.5 * tolerance_mm)
        cand = idx[far]
        if not cand.size or not layout.neighbours[k]:
            return None
        best_d = fit.distance[: idx.size][far].copy()
        best = np.full(cand.size, k)
        best_u, best_v = su[cand].copy(), sv[cand].copy()
        for nb in layout.neighbours[k]:
            f = fits[nb]
            u, v, d = distance_to_surface(f.knots_u, f.knots_v, f.control_points, P[cand])
            better = d < best_d
            best_d, best = np.where(better, d, best_d), np.where(better, nb, best)
            best_u, best_v = np.where(better, u, best_u), np.where(better, v, best_v)
        moved = best != k
        return (cand[moved], best[moved], best_u[moved], best_v[moved]) if moved.any() else None

    changed: set[int] = set()
    for k, found in enumerate(map_forked(moves, len(fits), processes=processes, check_cancel=check_cancel,
                                         progress=progress)):
        if found is not None:
            rows, to, u, v = found
            changed.add(k)
            changed.update(int(x) for x in np.unique(to))
            owner[rows], su[rows], sv[rows] = to, u, v
    return changed
