"""Fit every patch: free fits, shared boundary curves, border-constrained fits, refinement, report.

The order follows the paper with C0 made exact:
1. each patch is fitted on its own (squared-distance iteration, its quad grid holding
   the parameterisation and the extent), and samples that fell beyond a border move to
   the neighbour that is closer;
2. each boundary curve is fitted once, through the junction points where patches meet:
   along a sharp edge to the mesh's own crease, elsewhere to where the patches' own fits
   put their borders;
3. each patch is fitted again with its border rows taken from the curves (knots
   merged, curves refined into them by exact knot insertion) and held fixed;
4. spans still beyond the tolerance are halved and refitted; what remains beyond it
   is reported per patch, never hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam import CheckCancel, GeometryError, Progress
from cam.fit.boundary import SIDES, Layout, boundary_layout, side_params, side_vertices
from cam.fit.crease import edge_keys, snap_points, vertex_positions
from cam.fit.curve import CurveFit, fit_curve
from cam.fit.measure import surface_peaks
from cam.fit.param import (
    assign_samples,
    distance_to_surface,
    grid_anchors,
    mesh_samples,
)
from cam.fit.refine import Refined, fit_refined
from cam.fit.solve import SurfaceFit
from cam.mesh.closest import closest_points, mesh_index, triangle_normals
from cam.mesh.creases import closest_on_creases, mesh_creases
from cam.params import FitParams
from cam.spline.basis import evaluate_surface
from cam.spline.knots import (
    join_curves,
    lattice_knots,
    merge_knots,
    refine_knots,
    reverse_curve,
    shift_curve,
    sub_curve,
)
from cam.spline.surface import (
    FOLD_CHECK_SAMPLES,
    BSplineSurface,
    find_folds,
    make_bspline_surface,
)

__all__ = ["PatchFit", "FitResult", "fit_patches"]


@dataclass(frozen=True, eq=False)
class PatchFit:
    """One patch's surface (parameters on [0, 1]) and how well it fits.

    max_error_mm / mean_error_mm: distance from the patch's mesh samples to the fitted surfaces
    (a sample beyond the border counts against the nearest neighbour), max_error_mm also
    covers surface_to_mesh_mm: the largest distance from points of the surface to the mesh;
    boundary_error_mm: the largest distance of its boundary curves from the mesh (along a crease, from the crease);
    folded_fraction: share of the surface that folds over itself (`cam.spline.surface.find_folds` on the grid the
    planner checks, `FOLD_CHECK_SAMPLES`; 0 for a regular patch), reported because a fold can hug the mesh
    and still pass the distance test.
    worst_point_mm float64 (3,): where max_error_mm is (the mesh sample, or the point of the surface);
    worst_crease_mm: its distance to the nearest crease of the mesh (edges sharper than the fit's crease
    angle; inf without one). About the error itself or less, the surface cuts or misses a crease
    there: one the patch layout does not follow, which no surface of this patch can.
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
    """Every patch's fit (in the order of the grids given), the largest gap between neighbours
    along shared borders (mm), the number of boundary curves, and the tolerance used."""

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


def fit_patches(vertices: np.ndarray, grids: list[np.ndarray], mesh_vertices: np.ndarray, mesh_faces: np.ndarray,
                params: FitParams, *, other_quads: np.ndarray | None = None, sharp_edges: np.ndarray | None = None,
                progress: Progress | None = None, check_cancel: CheckCancel | None = None) -> FitResult:
    """Bicubic B-spline surfaces for patches of a quad mesh, fitted to a triangle mesh, C0 where they meet.

    vertices float64 (k, 3) mm: quad-mesh vertices; grids: per patch int (R + 1, C + 1) vertex ids
    (see `cam.fit.grid.patch_grid`); mesh_vertices float64 (n, 3) mm and mesh_faces int (m, 3):
    the triangle mesh to fit; other_quads int (q, 4): quads in no patch (their mesh samples are
    not fitted). sharp_edges int (e, 2): quad-mesh vertex pairs on sharp edges; patch borders
    along them are moved onto the mesh's creases (edges sharper than `params.crease_angle_deg`) found
    within `params.snap_radius_quads` quad edges.

    params: the fit's group with `tolerance_mm` resolved (`JobParams.effective("fit")`); its
    knot_spacing_quads: quads per knot span to start with; samples_per_face: mesh points taken inside
    each triangle besides its corners; max_samples_per_quad: the fit uses at most this many samples
    per patch quad on average (an evenly strided subset; a fine reconstructed mesh has ~100), None:
    all of them; the reported errors are measured on every sample either way; max_refinements,
    iterations, smoothing_mm2, normal_weight_mm: see `cam.fit.refine.fit_refined` and
    `cam.fit.solve.fit_surface`. `require_tolerance` is the caller's to act on (`FitResult.over_tolerance`).

    progress(fraction, message=None) is called between patches; check_cancel() between patches and
    inside each patch's fit (it raises to stop the fit). Raises `GeometryError` (e.g.
    `cam.fit.boundary.PatchLayoutError`) where the patches cannot be fitted as given, ValueError for
    arguments no caller should pass (shapes, ids, an unresolved tolerance).
    """
    return _fit_patches(vertices, grids, mesh_vertices, mesh_faces, params, other_quads=other_quads,
                        sharp_edges=sharp_edges, progress=progress, check_cancel=check_cancel)


def _fit_patches(vertices: np.ndarray, grids: list[np.ndarray], mesh_vertices: np.ndarray, mesh_faces: np.ndarray,
                 params: FitParams, *, other_quads: np.ndarray | None = None, sharp_edges: np.ndarray | None = None,
                 progress: Progress | None = None, check_cancel: CheckCancel | None = None,
                 smoothing_floor: float = 1e-6, param_weight: float = 0.01, anchor_weight: float = 1.0,
                 min_span_quads: float = 0.125, kink_angle_deg: float = 30.0, mesh_weight: float = 1.0) -> FitResult:
    """`fit_patches` with the fit's inner weights open to change (tests and benches; no user sets them).

    smoothing_floor, param_weight, anchor_weight: see `cam.fit.solve.fit_surface`. min_span_quads:
    refinement halves knot spans, never below this many quads. kink_angle_deg: where a patch side
    turns by more than this at a vertex (it runs round a corner of the part), its surface gets a C0
    knot line there. mesh_weight: weight of the surface's own points drawn onto the mesh, against the
    samples' 1 (`cam.fit.solve.fit_surface`; 0: samples only).
    """
    tolerance_mm = params.tolerance_mm
    knot_spacing_quads = params.knot_spacing_quads
    max_samples_per_quad = params.max_samples_per_quad
    max_refinements = params.max_refinements
    if tolerance_mm is None:
        raise ValueError("params.tolerance_mm is None: the fit needs the group with its tolerance resolved, "
                         "as JobParams.effective(\"fit\") returns it")
    if not tolerance_mm > 0:
        raise ValueError(f"tolerance_mm must be positive, got {tolerance_mm}")
    if not knot_spacing_quads > 0:
        raise ValueError(f"knot_spacing_quads must be positive, got {knot_spacing_quads}")
    if max_samples_per_quad is not None and not max_samples_per_quad > 0:
        raise ValueError(f"max_samples_per_quad must be positive or None, got {max_samples_per_quad}")
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
    report = progress or (lambda fraction, message=None: None)
    cancel = check_cancel or (lambda: None)
    crease_angle_deg = params.crease_angle_deg
    layout = boundary_layout(grids)
    index = mesh_index(mesh_vertices, mesh_faces)
    opts = dict(smoothing_mm2=params.smoothing_mm2, smoothing_floor=smoothing_floor, param_weight=param_weight,
                normal_weight_mm=params.normal_weight_mm, anchor_weight=anchor_weight, iterations=params.iterations,
                mesh=index if mesh_weight > 0 else None, mesh_weight=mesh_weight, check_cancel=cancel)
    sharp = edge_keys(sharp_edges)
    creases = mesh_creases(mesh_vertices, mesh_faces, angle_deg=crease_angle_deg) if sharp else None
    positions = vertex_positions(V, grids, index, sharp=sharp, creases=creases,
                                 snap_radius_quads=params.snap_radius_quads)
    P_all, N_all = mesh_samples(mesh_vertices, mesh_faces, per_face=params.samples_per_face)
    # Samples go to the quad nearest them once the grid vertices sit where the fit puts them:
    # the remesher's sharp edges run up to a quad beside the crease, and a sample on the far
    # face (the neighbour's, or the unfitted base's) would otherwise belong to this patch.
    placed = np.where(np.isfinite(positions), positions, V)
    asg_all = assign_samples(P_all, placed, grids, other_quads=other_quads)
    use = _thin(asg_all.patch, grids, max_samples_per_quad)
    P, N = P_all[use], N_all[use]
    owner, su, sv = asg_all.patch[use], asg_all.u[use], asg_all.v[use]
    anchors = [grid_anchors(V, g, index, knot_spacing_quads=knot_spacing_quads, positions=positions) for g in grids]
    sharp_side = {(k, name): _is_sharp(side_vertices(g, name), sharp) for k, g in enumerate(grids) for name in SIDES}
    # A side that turns a corner needs a C0 knot line there in the free fit already: a smooth
    # surface cuts the corner, and the boundary curves are fitted to where the free fits' borders lie.
    kinks = {(k, name): _kinks(positions[side_vertices(g, name)], kink_angle_deg).astype(np.float64)
             for k, g in enumerate(grids) for name in SIDES}
    lengths = [_lengths(V, g) for g in grids]
    shape = [(g.shape[0] - 1, g.shape[1] - 1) for g in grids]
    n = len(grids)

    def data(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        # The patch's mesh samples, then its grid vertices on the mesh: a patch too thin to own
        # samples still has data, and results are reported for the samples only (the first rows).
        sel = owner == k
        a = anchors[k]
        return (np.concatenate([P[sel], a.points]), np.concatenate([N[sel], a.normals]),
                np.concatenate([su[sel], a.u]), np.concatenate([sv[sel], a.v]))

    def free_fit(k: int, start: SurfaceFit | None) -> Refined:
        R, C = shape[k]
        kw = dict(knots_u=merge_knots(lattice_knots(0, R, knot_spacing_quads), np.repeat(kinks[(k, "v0")], 3),
                                      np.repeat(kinks[(k, "v1")], 3)),
                  knots_v=merge_knots(lattice_knots(0, C, knot_spacing_quads), np.repeat(kinks[(k, "u0")], 3),
                                      np.repeat(kinks[(k, "u1")], 3)))
        if start is not None:
            kw = dict(knots_u=start.knots_u, knots_v=start.knots_v, control_points=start.control_points)
        pts, nrm, u, v = data(k)
        pull = tuple(not sharp_side[(k, name)] for name in SIDES)
        return fit_refined(pts, nrm, u, v, tolerance_mm=tolerance_mm, lengths_mm=lengths[k], anchors=anchors[k],
                           max_refinements=max_refinements, min_span=min_span_quads, pull_sides=pull, **kw, **opts)

    # The free fits are refined for their borders, where the boundary curves are fitted. The
    # constrained fits start from the first free fits, before refinement (and before samples moved:
    # they refit from the top anyway): knot lines run across the whole patch, and the spans a free
    # fit split for one border would free every row and column to follow the mesh's facets (ripples
    # no tolerance sees, concave tighter than the ball). They refine themselves where they need it.
    free: list[Refined] = []
    for k in range(n):
        cancel()
        free.append(free_fit(k, None))
        report(0.35 * (k + 1) / n, f"fitted patch {k + 1} of {n} on its own")
    coarse = [f.unrefined for f in free]
    moved = _reassign(P, owner, su, sv, [f.fit for f in free], layout, tolerance_mm, check_cancel=cancel)
    for k in sorted(moved):
        cancel()
        free[k] = free_fit(k, free[k].fit)
    report(0.4, "fitting the shared boundary curves")
    curves, curve_err = _fit_curves(layout, grids, shape, [f.fit for f in free], positions, index, creases, sharp,
                                    knot_spacing_quads=knot_spacing_quads, tolerance_mm=tolerance_mm,
                                    max_refinements=max_refinements, min_span_quads=min_span_quads,
                                    kink_angle_deg=kink_angle_deg, check_cancel=cancel)
    final: list[SurfaceFit] = []
    rounds: list[int] = []
    peaks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for k in range(n):
        cancel()
        ku, kv, cp = _constrained_start(k, layout, coarse[k], curves)
        pts, nrm, u, v = data(k)
        # The final surfaces are drawn onto the mesh on a lattice an eighth of a quad apart, the free
        # fits on a quarter: between a quarter's points a refined surface still rippled past the
        # tolerance (a bump's fit, 0.03204 mm), and the free fits only place the borders.
        done = fit_refined(pts, nrm, u, v, knots_u=ku, knots_v=kv, control_points=cp, fix_border=True,
                           tolerance_mm=tolerance_mm, lengths_mm=lengths[k], anchors=anchors[k],
                           max_refinements=max_refinements, min_span=min_span_quads, mesh_spacing=0.125,
                           mesh_edges=True, **opts)
        final.append(done.fit)
        rounds.append(done.rounds)
        peaks.append(done.peaks)
        report(0.4 + 0.5 * (k + 1) / n, f"fitted patch {k + 1} of {n} to its shared borders")
    report(0.92, "measuring every mesh sample against the surfaces")
    errors = _sample_errors(P_all, asg_all.patch, final, layout, tolerance_mm, check_cancel=cancel)
    if creases is None:
        creases = mesh_creases(mesh_vertices, mesh_faces, angle_deg=crease_angle_deg)
    out = []
    for k in range(n):
        cancel()
        R, C = shape[k]
        fit = final[k]
        surf = make_bspline_surface(fit.control_points, fit.knots_u / R, fit.knots_v / C)
        mine = asg_all.patch == k
        e = errors[mine]
        # The refinement searched the final surface already, unless it was not given the mesh (mesh_weight 0).
        found = peaks[k] if peaks[k][2].size else surface_peaks(index, fit.knots_u, fit.knots_v, fit.control_points)
        s2m = float(found[2].max(initial=0.0))
        berr = max((curve_err[p.curve] for name in SIDES for p in layout.sides[(k, name)]), default=0.0)
        worst = max(float(e.max(initial=0.0)), s2m)
        if e.size and e.max() >= s2m:
            at = P_all[mine][int(np.argmax(e))]
        else:
            i = int(np.argmax(found[2]))
            at = surf.evaluate(found[0][i:i + 1] / R, found[1][i:i + 1] / C)[0]
        out.append(PatchFit(index=k, surface=surf, max_error_mm=worst, mean_error_mm=float(e.mean()) if e.size else 0.0,
                            surface_to_mesh_mm=s2m, boundary_error_mm=berr, samples=int(e.size), refinements=rounds[k],
                            within_tolerance=worst <= tolerance_mm, neighbours=layout.neighbours[k],
                            side_neighbours={s: layout.side_neighbours[(k, s)] for s in SIDES},
                            folded_fraction=find_folds(surf, samples=FOLD_CHECK_SAMPLES)[0],
                            worst_point_mm=at, worst_crease_mm=float(closest_on_creases(creases, at[None])[1][0])))
    report(1.0, "fitted")
    return FitResult(patches=out, max_gap_mm=_max_gap(out, layout, shape), curves=len(curves),
                     tolerance_mm=tolerance_mm)


def _lengths(V: np.ndarray, g: np.ndarray) -> tuple[float, float]:
    """Mean mm per grid-index unit along u and v (scales the bending energy to the part)."""
    pts = V[g]
    lu = np.linalg.norm(np.diff(pts, axis=0), axis=2).mean()
    lv = np.linalg.norm(np.diff(pts, axis=1), axis=2).mean()
    return float(max(lu, 1e-9)), float(max(lv, 1e-9))


def _reassign(P, owner, su, sv, fits, layout: Layout, tolerance_mm: float, *,
              check_cancel: CheckCancel | None = None) -> set[int]:
    """Move samples that lie beyond their patch's border to a neighbour that is closer; returns changed patches.

    P float64 (n, 3) mm; owner int (n,) patch per sample, su, sv float64 (n,) its parameters (quads):
    all three updated in place for the samples that move.
    """
    changed: set[int] = set()
    before = owner.copy()  # the fits' sample order; moves are applied to `owner` as they are found
    for k, fit in enumerate(fits):
        if check_cancel is not None:
            check_cancel()
        idx = np.flatnonzero(before == k)
        far = fit.clamped[: idx.size] & (fit.distance[: idx.size] > 0.5 * tolerance_mm)
        cand = idx[far]
        if not cand.size or not layout.neighbours[k]:
            continue
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
        if moved.any():
            changed.add(k)
            changed.update(int(x) for x in np.unique(best[moved]))
            owner[cand[moved]] = best[moved]
            su[cand[moved]], sv[cand[moved]] = best_u[moved], best_v[moved]
    return changed


def _fit_curves(layout: Layout, grids, shape, free, positions, index, creases, sharp, *, knot_spacing_quads: float,
                tolerance_mm: float, max_refinements: int, min_span_quads: float, kink_angle_deg: float,
                check_cancel: CheckCancel | None = None) -> tuple[list[CurveFit], list[float]]:
    """Fit each boundary curve once, through its junction points, to half the patches' tolerance (mm);
    knots start `knot_spacing_quads` apart and are halved down to `min_span_quads`.

    A curve is fitted piecewise and joined C0 where its vertices turn by more than
    `kink_angle_deg` (a patch side that runs round a corner of the part: one cubic cannot turn
    a corner without leaving the mesh). Along its sharp edges the data are the crease itself
    (points between the curve's vertices moved onto it); along the others, where the patches'
    own fits put their borders.
    """
    ends = {spec.vertices[0] for spec in layout.curves} | {spec.vertices[-1] for spec in layout.curves}
    samples: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in layout.curves]
    for (k, name), pieces in layout.sides.items():
        R, C = shape[k]
        f = free[k]
        for pc in pieces:
            t0, t1 = pc.side
            t = np.linspace(t0, t1, 4 * (t1 - t0) + 1)
            u, v = side_params(name, t, R, C)
            q = evaluate_surface(f.knots_u, f.knots_v, f.control_points, u, v, order=0)[(0, 0)]
            h = (pc.host[1] - (t - t0)) if pc.reversed else (pc.host[0] + (t - t0))
            samples[pc.curve].append((q, h))
    fits, errs = [], []
    for c, spec in enumerate(layout.curves):
        if check_cancel is not None:
            check_cancel()
        verts = np.asarray(spec.vertices)
        pts = positions[verts]
        cuts = [0, *_kinks(pts, kink_angle_deg).tolist(), len(verts) - 1]
        q_free = np.concatenate([s[0] for s in samples[c]])
        h_free = np.concatenate([s[1] for s in samples[c]])
        parts = []
        for a, b in zip(cuts[:-1], cuts[1:]):
            lo, hi = spec.start + a, spec.start + b
            seg = pts[a:b + 1]
            fixed = [i for i in range(b - a + 1) if i in (0, b - a) or int(verts[a + i]) in ends]
            cons = [(float(lo + i), seg[i]) for i in fixed]
            # Along a crease the curve's parameter runs with arc length between its junctions, which
            # keep theirs (the patches' sides meet there): the crease data follow the remesher's
            # vertices, one of which can sit 0.02 mm from the next between edges of 1 mm, and a
            # cubic cannot stand still for a parameter unit. The patches' own borders elsewhere are
            # parameterised smoothly already.
            on = _sharp_edges(verts[a:b + 1], sharp) if creases is not None else np.zeros(b - a, dtype=bool)
            tau = lo + _chord_params(seg, fixed, on)
            q, h, exact = _curve_data(on, seg, tau, q_free, h_free, creases, index)
            length = float(np.linalg.norm(np.diff(seg, axis=0), axis=1).sum())

            def on_mesh(t: np.ndarray, seg=seg, tau=tau) -> np.ndarray:
                # Where the border's vertices say the curve runs: their polyline, onto the mesh.
                return closest_points(index, _polyline_at(seg, np.interp(t, tau, np.arange(len(seg)))))[0]

            slide = _slide_ranges(on, tau, h, exact)
            parts.append(fit_curve(q, h, knots=lattice_knots(lo, hi, knot_spacing_quads), constraints=cons,
                                   length_mm=length, tolerance_mm=0.5 * tolerance_mm,
                                   max_refinements=max_refinements, min_span=min_span_quads,
                                   closest=lambda p: _feet_and_normals(index, p), project=on_mesh,
                                   slide=slide, exact=exact))
        knots, cp = join_curves([(f.knots, f.control_points) for f in parts])
        fits.append(CurveFit(knots=knots, control_points=cp, max_error=max(f.max_error for f in parts)))
        errs.append(fits[-1].max_error)
    return fits, errs


def _feet_and_normals(index, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest mesh points to `points` (k, 3) and the unit normals of the distance there (k, 3): towards
    the point where it is off the mesh (exact at edges and creases too), else the triangle's normal."""
    feet, dist, tri, _ = closest_points(index, points)
    off = dist > 1e-9
    normals = np.where(off[:, None], (points - feet) / np.where(off, dist, 1.0)[:, None], triangle_normals(index, tri))
    return feet, normals


def _curve_data(on: np.ndarray, pts: np.ndarray, params: np.ndarray, q_free: np.ndarray, h_free: np.ndarray,
                creases, index) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Data for the curve through vertices at `pts` (m, 3) with curve parameters `params` (m,):
    along each run of sharp edges (`on`, bool (m - 1,)) the crease, along the rest the patches' own
    borders (q_free at parameters h_free). Returns the points (n, 3), their parameters (n,) and
    which of them the curve must pass through (bool (n,)): the crease's, except next to a jump."""
    cuts = [0, *(np.flatnonzero(on[1:] != on[:-1]) + 1).tolist(), len(on)]
    qs, hs, exact = [], [], []
    for a, b in zip(cuts[:-1], cuts[1:]):
        if on[a]:
            q, h = _crease_samples(pts[a:b + 1], params[a:b + 1], creases, index)
            exact.append(~_near_jumps(q))
        else:
            inside = (h_free >= params[a]) & (h_free <= params[b])
            q, h = q_free[inside], h_free[inside]
            exact.append(np.zeros(len(q), dtype=bool))
        qs.append(q)
        hs.append(h)
    return np.concatenate(qs), np.concatenate(hs), np.concatenate(exact)


def _slide_ranges(on: np.ndarray, params: np.ndarray, h: np.ndarray, exact: np.ndarray, reach: float = 0.125
                  ) -> list[tuple[float, float]]:
    """Parameter ranges where a curve is held on the mesh: between vertices (parameters `params` (m,))
    joined by edges that are not sharp (`on`, bool (m - 1,)), and within `reach` of crease data
    (parameters h (n,)) that are not `exact` (next to a jump). Elsewhere along a crease its data are
    the crease, and the mesh beside it would let the curve slide off it onto one face; at a jump no
    curve follows the data, and on the mesh is what is left."""
    ranges = [(float(params[i]), float(params[i + 1])) for i in np.flatnonzero(~on)]
    crease = np.zeros(len(h), dtype=bool)
    for i in np.flatnonzero(on):
        crease |= (h > params[i]) & (h < params[i + 1])
    return ranges + [(float(x) - reach, float(x) + reach) for x in h[crease & ~exact]]


def _near_jumps(q: np.ndarray, factor: float = 2.0, reach: int = 2) -> np.ndarray:
    """bool (n,): crease data (n, 3), in order, within `reach` steps of a jump (a step over `factor` times
    the median step). There the data leave one crease for another (the two creases of a bevelled
    edge, a crease corner the junction is not on): no curve passes through both sides of that."""
    step = np.linalg.norm(np.diff(q, axis=0), axis=1)
    out = np.zeros(len(q), dtype=bool)
    if step.size < 2:
        return out
    for i in np.flatnonzero(step > factor * np.median(step)).tolist():
        out[max(0, i - reach + 1):i + reach + 1] = True
    return out


def _chord_params(pts: np.ndarray, fixed: list[int], along: np.ndarray) -> np.ndarray:
    """Parameters (m,) for the vertices of a polyline (m, 3): their indices, except along runs of
    edges marked in `along` (bool (m - 1,)), where between two vertices that keep their index
    (those in `fixed`, and the ends of each run) the parameter grows with arc length (evenly where
    they coincide)."""
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    out = np.arange(len(pts), dtype=np.float64)
    ends = {*fixed, *(np.flatnonzero(along[1:] != along[:-1]) + 1).tolist()}
    stops = sorted(ends | {0, len(pts) - 1})
    for a, b in zip(stops[:-1], stops[1:]):
        total = step[a:b].sum()
        if b - a > 1 and along[a] and total > 0:
            out[a + 1:b] = a + (b - a) * np.cumsum(step[a:b - 1]) / total
    return out


def _kinks(pts: np.ndarray, angle_deg: float) -> np.ndarray:
    """Interior indices of a polyline (m, 3) where its direction turns by more than `angle_deg`."""
    d = np.diff(pts, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
    cos = np.einsum("ij,ij->i", d[1:], d[:-1])
    return np.flatnonzero(cos < np.cos(np.radians(angle_deg))) + 1


def _sharp_edges(verts: np.ndarray, sharp: set) -> np.ndarray:
    """bool (m - 1,): which edges of a vertex polyline (m,) are sharp edges."""
    return np.array([(min(a, b), max(a, b)) in sharp for a, b in zip(verts[:-1].tolist(), verts[1:].tolist())],
                    dtype=bool)


def _is_sharp(verts: np.ndarray, sharp: set) -> bool:
    """Whether most edges of a vertex polyline are sharp edges."""
    if not sharp or len(verts) < 2:
        return False
    return 2 * int(_sharp_edges(verts, sharp).sum()) >= len(verts) - 1


def _polyline_at(pts: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points (n, 3) on the polyline through `pts` (m, 3) at parameters t (n,), one unit per segment."""
    i = np.clip(np.floor(t).astype(np.int64), 0, len(pts) - 2)
    s = (t - i)[:, None]
    return (1.0 - s) * pts[i] + s * pts[i + 1]


def _crease_samples(pts: np.ndarray, params: np.ndarray, creases, index, per_unit: int = 8
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Points along a polyline of vertex positions (m, 3) moved onto the nearest crease (else onto the
    mesh), `per_unit` per unit of the curve parameter (the vertices have `params`, (m,) ascending),
    with their parameters."""
    h = params[0] + np.arange(int(round((params[-1] - params[0]) * per_unit))) / per_unit
    x = np.interp(h, params, np.arange(len(pts), dtype=np.float64))
    seg = np.minimum(np.floor(x).astype(np.int64), len(pts) - 2)
    s = x - seg
    a, b = pts[seg], pts[seg + 1]
    q = a * (1 - s)[:, None] + b * s[:, None]
    # The reach shrinks to nothing at the vertices: the curve passes through them, and a vertex
    # left off the crease (no crease within its own reach) must not get data a crease away from it.
    reach = np.linalg.norm(b - a, axis=1) * np.minimum(1.0, 2.0 * np.minimum(s, 1.0 - s))
    # Only a crease along the edge: a sharp edge of the quad mesh can end on a crease running
    # across it (where segment's feature line meets a sharper one), and all of it would go there.
    snapped, moved = snap_points(creases, q, reach, directions=b - a)
    q = np.where(moved[:, None], snapped, closest_points(index, q)[0])
    return np.concatenate([q, pts[-1:]]), np.concatenate([h, params[-1:]])


def _side_curve(pieces, curves: list[CurveFit]) -> tuple[np.ndarray, np.ndarray]:
    """The curve along one side, in the side's parameter, joined from pieces of boundary curves."""
    parts = []
    for pc in pieces:
        cf = curves[pc.curve]
        k, P = sub_curve(cf.knots, cf.control_points, float(pc.host[0]), float(pc.host[1]))
        if pc.reversed:
            k, P = reverse_curve(k, P)
        parts.append(shift_curve(k, P, float(pc.side[0] - pc.host[0])))
    return join_curves(parts)


def _constrained_start(k: int, layout: Layout, free: SurfaceFit, curves):
    """Knots merged from the free fit and the four border curves; the free net refined into them, border replaced."""
    from cam.spline.knots import refine_surface

    side = {name: _side_curve(layout.sides[(k, name)], curves) for name in SIDES}
    ku = merge_knots(free.knots_u, side["v0"][0], side["v1"][0])
    kv = merge_knots(free.knots_v, side["u0"][0], side["u1"][0])
    ku, kv, cp = refine_surface(free.knots_u, free.knots_v, free.control_points, target_u=ku, target_v=kv)
    cp[:, 0] = refine_knots(*side["v0"], ku)[1]
    cp[:, -1] = refine_knots(*side["v1"], ku)[1]
    cp[0, :] = refine_knots(*side["u0"], kv)[1]
    cp[-1, :] = refine_knots(*side["u1"], kv)[1]
    return ku, kv, cp


def _sample_errors(P, owner, fits, layout: Layout, tolerance_mm: float, *,
                   check_cancel: CheckCancel | None = None) -> np.ndarray:
    """Distance (mm, float64 (n,), NaN where unassigned) of every assigned sample P (n, 3) to the fitted
    surfaces (own, or a neighbour where closer).

    Measured afresh on all samples, not taken from the fit, which may have used a subset; a
    distance over the tolerance is searched for span by span before it counts.
    """
    err = np.full(len(P), np.nan)
    for k, fit in enumerate(fits):
        if check_cancel is not None:
            check_cancel()
        idx = np.flatnonzero(owner == k)
        if not idx.size:
            continue
        d = distance_to_surface(fit.knots_u, fit.knots_v, fit.control_points, P[idx], search_above=tolerance_mm)[2]
        # Every far sample, not only those whose foot is on the border: where the quad mesh cuts
        # a corner of the part, a sample can take a strip's quad and a foot inside the strip
        # while the neighbour's surface passes through it.
        for nb in layout.neighbours[k]:
            far = np.flatnonzero(d > tolerance_mm)
            if not far.size:
                break
            f = fits[nb]
            d[far] = np.minimum(d[far], distance_to_surface(f.knots_u, f.knots_v, f.control_points, P[idx[far]],
                                                            search_above=tolerance_mm)[2])
        err[idx] = d
    return err


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


def _max_gap(patches: list[PatchFit], layout: Layout, shape, samples: int = 64) -> float:
    """Largest distance between two patches along the boundary they share, mm."""
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
