"""The shared boundary curves, fitted once from the free fits and the mesh's creases, and the border rows they give.

Each boundary curve (`cam.fit.boundary`) is fitted once (`cam.fit.curve.fit_curve`) through the
junction points where patches meet, piecewise and joined C0 where its vertices turn a corner
(`find_kinks`): along a sharp edge its data are the mesh's own crease, elsewhere where the patches'
own free fits put their borders. A patch fitted to its borders then starts from a net whose outer
rows are those curves, refined into its knots by exact knot insertion (`seed_bordered_net`), so both
patches along a shared border take the same curve: C0 by construction.
"""

from __future__ import annotations

import numpy as np

from cam import CheckCancel, map_forked
from cam.fit.boundary import SIDES, CurveSpec, Layout, Piece, side_params
from cam.fit.crease import sharp_edge_mask, snap_points
from cam.fit.curve import CurveFit, fit_curve
from cam.fit.solve import SurfaceFit
from cam.mesh.closest import MeshIndex, closest_points, triangle_normals
from cam.mesh.creases import Creases
from cam.spline.basis import evaluate_surface
from cam.spline.knots import (
    join_curves,
    lattice_knots,
    merge_knots,
    refine_knots,
    refine_surface,
    reverse_curve,
    shift_curve,
    sub_curve,
)

__all__ = ["find_kinks", "fit_boundary_curves", "junction_vertices", "seed_bordered_net"]


def fit_boundary_curves(layout: Layout, shape: list[tuple[int, int]], free: list[SurfaceFit], positions: np.ndarray,
                        index: MeshIndex, creases: Creases | None, sharp: set[tuple[int, int]], *,
                        knot_spacing_quads: float, tolerance_mm: float, max_refinements: int, min_span_quads: float,
                        kink_angle_deg: float, processes: int = 1, check_cancel: CheckCancel | None = None
                        ) -> tuple[list[CurveFit], list[float]]:
    """Fit each boundary curve once, through its junction points, to half the patches' tolerance.

    A curve is fitted piecewise and joined C0 where its vertices turn by more than
    `kink_angle_deg` (a patch side that runs round a corner of the part: one cubic cannot turn
    a corner without leaving the mesh). Along its sharp edges the data are the crease itself
    (points between the curve's vertices moved onto it); along the others, where the patches'
    own fits put their borders.

    Parameters
    ----------
    layout : Layout
        The patches' boundary curves and sides (`cam.fit.boundary.boundary_layout`).
    shape : list of (int, int)
        Per patch, (R, C): its quad counts.
    free : list of SurfaceFit
        Per patch, its free fit (grid-index units).
    positions : ndarray, shape (k, 3), float64
        Where each quad-mesh vertex sits on the mesh, mm (`cam.fit.crease.vertex_positions`).
    index : MeshIndex
        The triangle mesh.
    creases : Creases or None
        Its creases; None: no curve follows one.
    sharp : set of tuple of int
        The quad mesh's sharp edges (`cam.fit.crease.edge_keys`).
    knot_spacing_quads : float
        Knots start this many quads apart...
    tolerance_mm : float
        The patches' tolerance, mm; the curves are fitted to half of it.
    max_refinements : int
        ...and are halved at most this many rounds...
    min_span_quads : float
        ...down to this many quads.
    kink_angle_deg : float
        Turns sharper than this, degrees, are C0 joins.
    processes : int
        Curves fitted at once, in forked processes (`cam.map_forked`); the curves are bit for bit those
        of one process.
    check_cancel : callable or None
        Called before each curve (while the processes work, every half second); it raises to stop the fit.

    Returns
    -------
    curves : list of CurveFit
        One per `layout.curves`, in its own parameter (the host side's grid index).
    errors : list of float
        Each curve's largest deviation found, mm.
    """
    ends = junction_vertices(layout)
    samples = _border_samples(layout, shape, free)

    def fit_one(c: int, _cancel: CheckCancel) -> CurveFit:
        return _fit_boundary_curve(layout.curves[c], samples[c], ends, positions, index, creases, sharp,
                                   knot_spacing_quads=knot_spacing_quads, tolerance_mm=tolerance_mm,
                                   max_refinements=max_refinements, min_span_quads=min_span_quads,
                                   kink_angle_deg=kink_angle_deg)

    # Each curve is fitted on its own data: in `processes` forked processes, the same curves as one after another.
    fits = map_forked(fit_one, len(layout.curves), processes=processes, check_cancel=check_cancel)
    return fits, [f.max_error for f in fits]


def junction_vertices(layout: Layout) -> set[int]:
    """The vertices where a piece of a side begins or ends: every patch corner and every point where a side's
    neighbour changes. A curve passes through each exactly, so that two curves meeting there (a patch's two
    sides at its corner, each perhaps a piece of a longer curve) meet at one point and the patch's corner is
    both (a curve's own ends alone leave out a corner inside two other patches' sides)."""
    out: set[int] = set()
    for pieces in layout.sides.values():
        for pc in pieces:
            spec = layout.curves[pc.curve]
            out.update(int(spec.vertices[h - spec.start]) for h in pc.host)
    return out


def _border_samples(layout: Layout, shape, free: list[SurfaceFit]) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """Per curve, where the free fits put their borders along it: points (s, 3) mm, four per quad, with
    the curve's parameters (s,) there, one pair per piece of a side."""
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
    return samples


def _fit_boundary_curve(spec: CurveSpec, samples, ends: set[int], positions, index, creases, sharp, *,
                        knot_spacing_quads: float, tolerance_mm: float, max_refinements: int,
                        min_span_quads: float, kink_angle_deg: float) -> CurveFit:
    """One boundary curve: its pieces between kinks fitted one by one (`_fit_curve_piece`), joined C0."""
    verts = np.asarray(spec.vertices)
    pts = positions[verts]
    cuts = [0, *find_kinks(pts, kink_angle_deg).tolist(), len(verts) - 1]
    q_free = np.concatenate([s[0] for s in samples])
    h_free = np.concatenate([s[1] for s in samples])
    parts = [_fit_curve_piece(spec.start + a, verts[a:b + 1], pts[a:b + 1], ends, q_free, h_free, index, creases,
                              sharp, knot_spacing_quads=knot_spacing_quads, tolerance_mm=tolerance_mm,
                              max_refinements=max_refinements, min_span_quads=min_span_quads)
             for a, b in zip(cuts[:-1], cuts[1:])]
    knots, cp = join_curves([(f.knots, f.control_points) for f in parts])
    return CurveFit(knots=knots, control_points=cp, max_error=max(f.max_error for f in parts))


def _fit_curve_piece(lo: int, verts: np.ndarray, seg: np.ndarray, ends: set[int], q_free: np.ndarray,
                     h_free: np.ndarray, index, creases, sharp, *, knot_spacing_quads: float, tolerance_mm: float,
                     max_refinements: int, min_span_quads: float) -> CurveFit:
    """The piece of a curve through vertices `verts` (m,) at `seg` (m, 3) mm, parameters lo..lo + m - 1:
    exact at its ends and at the junctions on it (each a knot), on the crease along sharp edges, else on the
    free fits' borders (q_free (s, 3) mm at curve parameters h_free (s,))."""
    hi = lo + len(verts) - 1
    fixed = [i for i in range(len(verts)) if i in (0, len(verts) - 1) or int(verts[i]) in ends]
    cons = [(float(lo + i), seg[i]) for i in fixed]
    # Along a crease the curve's parameter runs with arc length between its junctions, which
    # keep theirs (the patches' sides meet there): the crease data follow the remesher's
    # vertices, one of which can sit 0.02 mm from the next between edges of 1 mm, and a
    # cubic cannot stand still for a parameter unit. The patches' own borders elsewhere are
    # parameterised smoothly already.
    on = sharp_edge_mask(verts, sharp) if creases is not None else np.zeros(len(verts) - 1, dtype=bool)
    tau = lo + _chord_params(seg, fixed, on)
    q, h, exact = _curve_data(on, seg, tau, q_free, h_free, creases, index)
    length = float(np.linalg.norm(np.diff(seg, axis=0), axis=1).sum())

    def on_mesh(t: np.ndarray) -> np.ndarray:
        # Where the border's vertices say the curve runs: their polyline, onto the mesh.
        return closest_points(index, _polyline_at(seg, np.interp(t, tau, np.arange(len(seg)))))[0]

    slide = _slide_ranges(on, tau, h, exact)
    # a knot at each junction inside the piece: the curve has the freedom to pass through all of them exactly
    # (a side cut at every quad by its neighbours has a junction at every vertex, more than the lattice's knots
    # can take), and the patches that meet there start or end at a knot
    knots = merge_knots(lattice_knots(lo, hi, knot_spacing_quads), [lo + i for i in fixed[1:-1]])
    return fit_curve(q, h, knots=knots, constraints=cons,
                     length_mm=length, tolerance_mm=0.5 * tolerance_mm,
                     max_refinements=max_refinements, min_span=min_span_quads,
                     closest=lambda p: _feet_and_normals(index, p), project=on_mesh,
                     slide=slide, exact=exact)


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


def find_kinks(pts: np.ndarray, angle_deg: float) -> np.ndarray:
    """Interior vertices of a polyline where its direction turns by more than `angle_deg`.

    Parameters
    ----------
    pts : ndarray, shape (m, 3), float64
        The polyline's vertices, mm.
    angle_deg : float
        The turn, degrees.

    Returns
    -------
    ndarray, shape (k,), int64
        Indices in 1..m - 2, ascending.
    """
    d = np.diff(pts, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
    cos = np.einsum("ij,ij->i", d[1:], d[:-1])
    return np.flatnonzero(cos < np.cos(np.radians(angle_deg))) + 1


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


def _side_curve(pieces: list[Piece], curves: list[CurveFit]) -> tuple[np.ndarray, np.ndarray]:
    """The curve along one side, in the side's parameter, joined from pieces of boundary curves."""
    parts = []
    for pc in pieces:
        cf = curves[pc.curve]
        k, P = sub_curve(cf.knots, cf.control_points, float(pc.host[0]), float(pc.host[1]))
        if pc.reversed:
            k, P = reverse_curve(k, P)
        parts.append(shift_curve(k, P, float(pc.side[0] - pc.host[0])))
    return join_curves(parts)


def seed_bordered_net(k: int, layout: Layout, free: SurfaceFit, curves: list[CurveFit]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The net a patch's fit to its borders starts from: the free net with the boundary curves for its border.

    Knots are merged from the free fit and the four border curves, the free net is refined into them
    (exact knot insertion) and its outer rows and columns are replaced by the curves, refined alike.

    Parameters
    ----------
    k : int
        The patch.
    layout : Layout
        The patches' sides as pieces of boundary curves (`cam.fit.boundary.boundary_layout`).
    free : SurfaceFit
        The patch's free fit, grid-index units.
    curves : list of CurveFit
        The boundary curves (`fit_boundary_curves`).

    Returns
    -------
    knots_u, knots_v : ndarray, float64
        The merged knot vectors, grid-index units.
    control_points : ndarray, shape (nu, nv, 3), float64
        The net, mm; its outer ring is the four border curves.
    """
    side = {name: _side_curve(layout.sides[(k, name)], curves) for name in SIDES}
    ku = merge_knots(free.knots_u, side["v0"][0], side["v1"][0])
    kv = merge_knots(free.knots_v, side["u0"][0], side["u1"][0])
    ku, kv, cp = refine_surface(free.knots_u, free.knots_v, free.control_points, target_u=ku, target_v=kv)
    cp[:, 0] = refine_knots(*side["v0"], ku)[1]
    cp[:, -1] = refine_knots(*side["v1"], ku)[1]
    cp[0, :] = refine_knots(*side["u0"], kv)[1]
    cp[-1, :] = refine_knots(*side["u1"], kv)[1]
    return ku, kv, cp
