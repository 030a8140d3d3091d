"""One surface fitted to mesh samples by squared-distance minimisation (the paper's iteration).

Each step projects the samples onto the current surface (foot points), replaces
the squared distance of every sample by its local quadratic approximation
(Wang, Pottmann and Liu 2006: full weight along the normal, d/(d - ρ) along each
principal direction, ρ the signed radius of curvature, negative weights dropped),
adds the feature-sensitive normal term (the surface's tangents should be
orthogonal to the mesh normal, which is linear in the control points) and a
thin-plate energy, and solves the resulting sparse linear least-squares problem
for the free control points. Fixed control points (a shared border) stay exactly
as given.

Squared-distance steps leave tangential motion free, so the parameterisation is
held by anchors: the quad grid's vertices, moved onto the mesh, keep the grid
parameters (i, j) they have by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu, spsolve

from cam import CheckCancel
from cam.fit.param import Anchors, foot_frames, project_points
from cam.mesh.closest import MeshIndex, closest_points, triangle_normals
from cam.spline.basis import (
    evaluate_surface,
    span_params,
    surface_rows,
    thin_plate_matrix,
    weighted_grams,
    weighted_rhs,
)
from cam.spline.knots import lattice_knots
from cam.spline.surface import c0_knots, find_folds, make_bspline_surface

__all__ = ["SurfaceFit", "fit_surface", "sdm_weights"]


@dataclass(frozen=True, eq=False)
class SurfaceFit:
    """A fitted control net and where the samples fell on it.

    knots_u, knots_v float64; control_points float64 (nu, nv, 3) mm; u, v float64 (n,) foot
    parameters; distance float64 (n,) mm from each sample to its foot point; clamped bool (n,):
    foot on the border with the sample beyond it; counted bool (n,): the samples the fit answers
    for (all, or those inside a fixed border); iterations: the step this fit came from.
    surface_u, surface_v, surface_distance float64 (m,): points of the surface (a grid of
    parameters) and their distance (mm) to the mesh, when the fit was given the mesh (else empty).
    """

    knots_u: np.ndarray
    knots_v: np.ndarray
    control_points: np.ndarray
    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray
    clamped: np.ndarray
    counted: np.ndarray
    iterations: int
    folded: float = 0.0
    surface_u: np.ndarray = field(default_factory=lambda: np.zeros(0))
    surface_v: np.ndarray = field(default_factory=lambda: np.zeros(0))
    surface_distance: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def max_error(self) -> float:
        """Largest distance over the counted samples and the surface's own points, mm."""
        inside = self.distance[self.counted]
        return max(float(inside.max(initial=0.0)), float(self.surface_distance.max(initial=0.0)))

    def excess(self, tolerance_mm: float) -> float:
        """Mean squared distance beyond the tolerance (mm²) of the counted samples, plus that of the
        surface points.

        It tells two fits apart where the largest distance does not: one held by a fixed border
        (its boundary curve's error) is the same for both while the rest differ.
        """
        out = 0.0
        for d in (self.distance[self.counted], self.surface_distance):
            if d.size:
                out += float(np.mean(np.maximum(d - tolerance_mm, 0.0) ** 2))
        return out

    def improves_on(self, other: SurfaceFit, tolerance_mm: float, *, by: float = 1e-9) -> bool:
        """Whether this fit is closer than `other` by at least the fraction `by`: less excess beyond the
        tolerance, or, where neither has any, a smaller largest distance."""
        mine, theirs = self.excess(tolerance_mm), other.excess(tolerance_mm)
        if mine > 0.0 or theirs > 0.0:
            return mine < theirs * (1.0 - by)
        return self.max_error < other.max_error * (1.0 - by)


def sdm_weights(signed_distance: np.ndarray, curvature: np.ndarray, *, cap: float = 100.0) -> np.ndarray:
    """Tangential weight d/(d - ρ) = dκ/(dκ - 1) of the SD error term, dropped where negative, capped."""
    dk = signed_distance * curvature
    with np.errstate(divide="ignore", invalid="ignore"):
        w = dk / (dk - 1.0)
    return np.clip(np.nan_to_num(w, nan=0.0, posinf=cap, neginf=0.0), 0.0, cap)


def fit_surface(points: np.ndarray, normals: np.ndarray, u: np.ndarray, v: np.ndarray, *,
                knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray | None = None,
                fixed: np.ndarray | None = None, anchors: Anchors | None = None,
                lengths_mm: tuple[float, float] = (1.0, 1.0), tolerance_mm: float = 0.032,
                smoothing_mm2: float = 1e-4, smoothing_decay: float = 0.1, smoothing_floor: float = 1e-6,
                normal_weight_mm: float = 0.02, kink_weight_mm: float = 1.0, anchor_weight: float = 1.0,
                param_weight: float = 0.01,
                pull_weight: float = 0.3, pull_sides: tuple[bool, bool, bool, bool] = (True, True, True, True),
                clamped_samples: str = "pull", iterations: int = 8, warm: bool = False,
                mesh: MeshIndex | None = None, mesh_weight: float = 1.0, mesh_spacing: float = 0.25,
                mesh_edges: bool = False, mesh_points: tuple[np.ndarray, np.ndarray] | None = None,
                degree: tuple[int, int] = (3, 3), check_cancel: CheckCancel | None = None) -> SurfaceFit:
    """Fit a B-spline surface with the given knots to samples, keeping `fixed` control points.

    points, normals float64 (n, 3) (mm, unit mesh normals); u, v float64 (n,) starting parameters
    in the knots' units; control_points float64 (nu, nv, 3): the start (required when `fixed` is
    given), else the first step fits each sample's tangent plane at (u, v); fixed bool (nu, nv).
    anchors: the quad grid's vertices on the mesh (`cam.fit.param.grid_anchors`), parameters fixed:
    their offsets across the patch border weigh `anchor_weight` in all against the mean squared
    distance (they hold the patch's extent), their other tangential offsets `param_weight`
    (they keep the parameterisation from sliding without forcing the grid's irregularities on it).
    lengths_mm: mm per parameter unit along u and v (scales the thin-plate energy to the part).
    The smoothing weight (mm²) starts at `smoothing_mm2` and shrinks by `smoothing_decay` per step
    down to `smoothing_floor` times it, so early steps are stiff and the converged surface is not
    biased by it; `warm` (a start that already fits, e.g. after knot insertion) starts at the floor.
    normal_weight_mm: weight of the normal term (an angle error of ε rad costs as much as a
    distance of ε · normal_weight_mm). kink_weight_mm: the same for the two sides of a C0 knot
    line (a border that turns a corner) against their shared normal, so the line is a kink of the
    parameters only, not a crease of the surface. clamped_samples: "pull" draws the border out
    towards samples beyond it, with weight `pull_weight`, across the sides flagged in `pull_sides` (u = u0,
    u = u1, v = v0, v = v1; a patch fitted on its own, not across a crease, where samples beyond
    belong to the other face); "drop" ignores them (a border that is a shared curve).
    mesh: the triangle mesh the samples come from. With it, every step also measures the surface
    itself on a grid of parameters `mesh_spacing` apart (the same points for any knots whose spans are
    all at least twice that wide, so fits with different knots compare on them; shorter spans add their
    quarter points) against the mesh, and draws those points
    onto the mesh (their closest points, along the mesh normal there, `mesh_weight` in all against
    the samples' 1): samples alone leave a span with few of them free to bulge between them.
    mesh_edges: draw the points whose closest mesh point is off to the side (on an edge: past a
    crease, or past the mesh's own border) towards it as well, along the distance's own direction
    (for a surface inside fixed borders, where the surface has no business past the mesh).
    mesh_points: parameters (u (k,), v (k,)) measured and drawn onto the mesh besides the grid (the
    peaks a search found between its points: a refit after knot insertion for them must see them, or
    a start within tolerance on the grid is the best step it finds, and it gives back the same surface).
    Stops when the largest distance is within tolerance and no longer improving, when it stops
    improving, or after `iterations` steps; returns the best step seen: the least folded, and of
    those the closest (`SurfaceFit.improves_on`). A step that folds the net more is taken again
    from the best one, damped (Levenberg-Marquardt). check_cancel() is called before every step (it
    raises to stop the fit).
    """
    P = np.asarray(points, dtype=np.float64)
    Nm = np.asarray(normals, dtype=np.float64)
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    nu, nv = ku.size - degree[0] - 1, kv.size - degree[1] - 1
    if P.ndim != 2 or P.shape[1] != 3 or Nm.shape != P.shape:
        raise ValueError(f"points and normals must both have shape (n, 3), got {P.shape} and {Nm.shape}")
    if clamped_samples not in ("pull", "drop"):
        raise ValueError(f"clamped_samples must be 'pull' or 'drop', got {clamped_samples!r}")
    fixed = np.zeros((nu, nv), dtype=bool) if fixed is None else np.asarray(fixed, dtype=bool)
    if fixed.shape != (nu, nv):
        raise ValueError(f"fixed must have shape {(nu, nv)}, got {fixed.shape}")
    if control_points is None and fixed.any():
        raise ValueError("fixed control points need control_points to take their values from")
    system = _System(ku, kv, fixed, lengths_mm, degree)
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    n = max(len(P), 1)
    if control_points is None:
        # First step: each sample's tangent plane (its mesh normal), the anchors on the mesh and on
        # the border. Point distances at the seed parameters would drag the parameterisation along
        # with the seed's errors, and undoing tangential distortion is what foot-point steps do worst.
        rows = [(surface_rows(ku, kv, u, v, degree=degree), [(Nm, np.full(len(P), 1.0 / n), _dot(Nm, P))])]
        if anchors is not None:
            t1, t2 = _plane(anchors.normals)
            rows.append(_anchor_rows(anchors, ku, kv, degree, anchor_weight, param_weight, t1, t2,
                                     [(anchors.normals, anchor_weight / len(anchors.points))]))
        cp = system.solve(rows, smoothing_mm2, np.zeros((nu, nv, 3)))
    else:
        cp = np.asarray(control_points, dtype=np.float64).copy()
        if cp.shape != (nu, nv, 3):
            raise ValueError(f"control_points must have shape {(nu, nv, 3)}, got {cp.shape}")
    best: SurfaceFit | None = None
    stalls = 0
    # A pulled border settles like a contact problem (samples come in and out of reach), so it gets
    # more patience before the iteration is called stuck.
    patience = 4 if clamped_samples == "pull" else 2
    damping = 0.0
    for it in range(iterations + 1):
        if check_cancel is not None:
            check_cancel()
        u, v, dist = project_points(ku, kv, cp, P, u, v, degree=degree)
        frame = foot_frames(ku, kv, cp, u, v, degree=degree)
        r = P - frame.point
        along = _dot(r, frame.normal)
        off = r - along[:, None] * frame.normal
        clamped = np.linalg.norm(off, axis=1) > 1e-6 + 1e-3 * np.abs(along)
        counted = ~clamped if clamped_samples == "drop" else np.ones(len(P), dtype=bool)
        grid = _surface_grid(ku, kv, cp, mesh, mesh_spacing, degree, mesh_edges, mesh_points) \
            if mesh is not None else None
        extra = {} if grid is None else dict(surface_u=grid[0], surface_v=grid[1], surface_distance=grid[2])
        fit = SurfaceFit(ku, kv, cp, u, v, dist, clamped, counted, it,
                         find_folds(make_bspline_surface(cp, ku, kv, degree=degree))[0], **extra)
        # Squared-distance steps leave tangential motion almost free, and as the smoothing decays
        # a net can fold while it hugs the data ever closer: a step that folds more is no progress.
        folds_more = best is not None and fit.folded > best.folded
        if best is None or fit.folded < best.folded or not folds_more and fit.improves_on(best, tolerance_mm):
            stalls = 0 if best is None or fit.folded < best.folded or fit.improves_on(best, tolerance_mm, by=0.05) \
                else stalls + 1
            best, state = fit, (frame, along, off, grid)
            damping = 0.0 if damping <= 1e-3 else damping / 10.0
        elif folds_more:
            # Take the step again from the best fit, shorter (Levenberg-Marquardt). A refit after knot
            # insertion, whose new control points little data holds, folds at its first full step;
            # without this it never moves. A fold that no damping prevents is a stall.
            damping = 1.0 if damping == 0.0 else 10.0 * damping
            stalls += damping > 100.0
        else:
            stalls += 1
        if it == iterations or (best.max_error <= tolerance_mm and stalls >= 1) or stalls >= patience:
            break
        if folds_more:
            cp, u, v, clamped = best.control_points, best.u, best.v, best.clamped
            frame, along, off, grid = state
        lam = smoothing_mm2 * (smoothing_floor if warm else max(smoothing_decay ** (it + 1), smoothing_floor))
        keep = (~clamped).astype(np.float64) / n
        terms = [(frame.normal, keep, _dot(frame.normal, P)),
                 (frame.t1, sdm_weights(along, frame.k1) * keep, _dot(frame.t1, P)),
                 (frame.t2, sdm_weights(along, frame.k2) * keep, _dot(frame.t2, P))]
        if clamped_samples == "pull":
            # Beyond the border, pull within the tangent plane only: the offset along the normal
            # there is the surface's curvature, not a fitting error.
            out = off / np.maximum(np.linalg.norm(off, axis=1, keepdims=True), 1e-300)
            (u0, u1), (v0, v1) = (ku[degree[0]], ku[-degree[0] - 1]), (kv[degree[1]], kv[-degree[1] - 1])
            on_side = np.stack([u <= u0, u >= u1, v <= v0, v >= v1], axis=1)
            pull = clamped & (on_side & np.asarray(pull_sides, dtype=bool)).any(axis=1)
            terms.append((out, pull_weight * pull / n, _dot(out, P)))
        rows = [(surface_rows(ku, kv, u, v, degree=degree), terms)]
        if grid is not None:
            gu, gv, _, near, mesh_normal, ok = grid
            w = mesh_weight * ok / max(int(ok.sum()), 1)
            rows.append((surface_rows(ku, kv, gu, gv, degree=degree), [(mesh_normal, w, _dot(mesh_normal, near))]))
        if normal_weight_mm > 0:
            # S_u · n = 0 and S_v · n = 0, scaled by |S_u|, |S_v|: the sine of the normal error.
            for du, dv, tangent, length in ((1, 0, frame.su, lengths_mm[0]), (0, 1, frame.sv, lengths_mm[1])):
                w = normal_weight_mm**2 * keep / _speed2(tangent, length)
                rows.append((surface_rows(ku, kv, u, v, degree=degree, du=du, dv=dv), [(Nm, w, np.zeros(len(P)))]))
        if kink_weight_mm > 0:
            rows += _kink_rows(ku, kv, cp, degree, kink_weight_mm, lengths_mm)
        if anchors is not None:
            af = foot_frames(ku, kv, cp, anchors.u, anchors.v, degree=degree)
            rows.append(_anchor_rows(anchors, ku, kv, degree, anchor_weight, param_weight, af.t1, af.t2, []))
        cp = system.solve(rows, lam, cp, damping)
    return best


def _surface_grid(ku, kv, cp, mesh: MeshIndex, spacing: float, degree, edges: bool = False, points=None):
    """Points of the surface on a grid of parameters `spacing` apart (and the far ends, and the parameters
    `points` (u (k,), v (k,)) where given), and the mesh near them.

    Returns u, v (m,), distance (m,) mm to the mesh, the closest mesh points (m, 3), the normals of
    their triangles (m, 3), and ok bool (m,): the mesh lies along its triangle's normal from the
    point (within 27°) and the triangle faces the way the surface does (within 60°). With `edges`,
    the other points off the mesh are ok too, their normal the direction from the closest point.
    """
    uu, vv = np.meshgrid(*(_lattice_values(k, spacing) for k in (ku, kv)), indexing="ij")
    u, v = uu.ravel(), vv.ravel()
    if points is not None:
        u = np.concatenate([u, np.clip(points[0], ku[0], ku[-1])])
        v = np.concatenate([v, np.clip(points[1], kv[0], kv[-1])])
    frame = foot_frames(ku, kv, cp, u, v, degree=degree)
    near, dist, tri, _ = closest_points(mesh, frame.point)
    fn = triangle_normals(mesh, tri)
    # Drawn onto the mesh only where the mesh lies along the normal from the point: past the edge of
    # an open mesh, or across a crease, the closest point is on an edge off to the side, and the
    # plane of its triangle would bend the surface towards where the mesh is not.
    r = frame.point - near
    along = _dot(r, fn)
    square = np.linalg.norm(r - along[:, None] * fn, axis=1) <= 1e-6 + 0.5 * np.abs(along)
    ok = square & (np.abs(_dot(fn, frame.normal)) > 0.5)
    if edges:
        side = ~ok & (dist > 1e-9)
        fn[side] = r[side] / dist[side, None]
        ok |= side
    return u, v, dist, near, fn, ok


def _lattice_values(knots: np.ndarray, spacing: float) -> np.ndarray:
    """The lattice's values along one direction: the multiples of `spacing` inside the domain, its ends,
    and the quarter points of every knot span shorter than twice `spacing`.

    In a span no wider than the spacing the multiples fall on its knots only, and a refit after knot
    insertion met the mesh there and bulged between them, unmeasured and undrawn (a bump one quad wide
    behind fixed borders: 0.0014 mm on the lattice, 0.66 mm between its points).
    """
    values = lattice_knots(knots[0], knots[-1], spacing)
    k = np.unique(knots)
    lo, hi = k[:-1], k[1:]
    short = (hi - lo) < 2 * spacing
    quarters = (lo[short, None] + np.array([0.25, 0.5, 0.75]) * (hi - lo)[short, None]).ravel()
    return np.unique(np.concatenate([values, quarters]))


def _speed2(tangent: np.ndarray, length_mm: float) -> np.ndarray:
    """|S_u|² of tangents (n, 3), floored at a tenth of the mean grid step `length_mm` squared.

    Dividing S_u · n by |S_u| makes it the sine of an angle, but where S_u nearly vanishes (a
    collapsed corner, a short piece of a border) the angle is undefined, and the unfloored weight
    reached 1e9 times the data's: the normal equations lost every digit and the step was garbage.
    """
    return np.maximum(np.einsum("ij,ij->i", tangent, tangent), (0.1 * length_mm) ** 2)


def _kink_rows(ku, kv, cp, degree, weight_mm: float, lengths_mm: tuple[float, float] = (1.0, 1.0),
               per_span: int = 4) -> list:
    """Rows that hold both sides of every C0 knot line tangent to one plane (G1 across it).

    Along a line u = c, S_u just before and at c (the two pieces' own derivatives) should be
    orthogonal to the mean of the two pieces' normals there; likewise across v = c. Weighted so
    that an angle error of ε costs as much as a distance of ε · weight_mm over all the samples.
    """
    out = []
    for axis, (knots, deg) in enumerate(((ku, degree[0]), (kv, degree[1]))):
        lines = c0_knots(knots, deg)
        if not lines.size:
            continue
        other = span_params(kv if axis == 0 else ku, per_span)
        c = np.repeat(lines, other.size)
        t = np.tile(other, lines.size)
        before = np.nextafter(c, -np.inf)
        sides = [(before, t), (c, t)] if axis == 0 else [(t, before), (t, c)]
        ders = [evaluate_surface(ku, kv, cp, a, b, degree=degree, order=1) for a, b in sides]
        normals = [np.cross(d[(1, 0)], d[(0, 1)]) for d in ders]
        n = sum(x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-300) for x in normals)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        key, du, dv = ((1, 0), 1, 0) if axis == 0 else ((0, 1), 0, 1)
        for (a, b), d in zip(sides, ders):
            w = weight_mm**2 / (2 * c.size) / _speed2(d[key], lengths_mm[axis])
            out.append((surface_rows(ku, kv, a, b, degree=degree, du=du, dv=dv), [(n, w, np.zeros(c.size))]))
    return out


def _solve_spd(M: sp.csc_matrix, r: np.ndarray) -> np.ndarray:
    """Solve M x = r for symmetric positive definite M (every weight here is >= 0 and the thin plate
    and the weak-point terms make it definite): an LU with a symmetric fill-reducing order and no
    pivoting, about 4 times faster here than the general default. Falls back to that default if the
    factor breaks down (a pivot of zero)."""
    try:
        return splu(M, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}).solve(r)
    except RuntimeError:
        return spsolve(M, r)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _plane(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents spanning the plane orthogonal to each normal."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(normals, helper)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-300)
    return t1, np.cross(normals, t1)


def _anchor_rows(anchors: Anchors, ku, kv, degree, border_weight: float, param_weight: float, t1, t2, extra):
    """Anchor terms: across the border (exact, `border_weight` in all) and tangential (`param_weight`)."""
    ap = anchors.points
    m = len(ap)
    on_border = sum(int((np.linalg.norm(a, axis=1) > 0).sum()) for a in (anchors.across_u, anchors.across_v))
    wb = border_weight / max(int(on_border), 1)
    wp = np.full(m, param_weight / m)
    terms = [(t1, wp, _dot(t1, anchors.targets)), (t2, wp, _dot(t2, anchors.targets))]
    for across in (anchors.across_u, anchors.across_v):
        mask = np.linalg.norm(across, axis=1) > 0
        terms.append((across, wb * mask, _dot(across, anchors.targets)))
    terms += [(e, np.broadcast_to(w, (m,)), _dot(e, ap)) for e, w in extra]
    return surface_rows(ku, kv, anchors.u, anchors.v, degree=degree), terms


class _System:
    """Normal equations of one knot layout: thin-plate matrix and free/fixed split built once."""

    def __init__(self, ku: np.ndarray, kv: np.ndarray, fixed: np.ndarray, lengths_mm: tuple[float, float],
                 degree: tuple[int, int]) -> None:
        self.ncp = fixed.size
        H = thin_plate_matrix(ku, kv, degree=degree, length_u=lengths_mm[0], length_v=lengths_mm[1])
        self.H3 = sp.block_diag([H, H, H]).tocsr()
        free = np.flatnonzero(~fixed.ravel())
        self.free3 = np.concatenate([free + k * self.ncp for k in range(3)])
        self.fixed3 = np.concatenate([np.flatnonzero(fixed.ravel()) + k * self.ncp for k in range(3)])

    def solve(self, rows: list, lam: float, cp_current: np.ndarray, damping: float = 0.0) -> np.ndarray:
        """Minimise Σ w (e · S(u) - target)² over the row sets plus lam · thin-plate, free points only.

        rows: [((cols, vals), [(e (n, 3), w (n,), target (n,)), ...]), ...] — each term is a
        weighted projection of the surface point (or derivative) the row set evaluates.
        """
        size = self.ncp
        blocks = [[None] * 3 for _ in range(3)]
        rhs = np.zeros(3 * size)
        pairs = [(i, j) for i in range(3) for j in range(i, 3)]
        for (cols, vals), terms in rows:
            for i in range(3):
                ri = sum(w * e[:, i] * t for e, w, t in terms)
                rhs[i * size:(i + 1) * size] += weighted_rhs(cols, vals, ri, size)
            grams = weighted_grams(cols, vals, [sum(w * e[:, i] * e[:, j] for e, w, _ in terms) for i, j in pairs],
                                   size)
            for (i, j), g in zip(pairs, grams):
                blocks[i][j] = g if blocks[i][j] is None else blocks[i][j] + g
        for i in range(3):
            for j in range(i):
                blocks[i][j] = blocks[j][i].T
        M = (sp.bmat(blocks, format="csr") + lam * self.H3).tocsr()
        c_all = cp_current.reshape(-1, 3).T.ravel()  # [x..., y..., z...]
        M_ff = M[self.free3][:, self.free3]
        r = rhs[self.free3]
        if self.fixed3.size:
            r = r - M[self.free3][:, self.fixed3] @ c_all[self.fixed3]
        # A vanishing diagonal is a control point nothing reaches (no sample, no bending): keep it.
        diag = M_ff.diagonal()
        scale = max(float(diag.max(initial=0.0)), 1e-300)
        weak = diag < 1e-14 * scale
        if weak.any():
            M_ff = M_ff + sp.diags(np.where(weak, scale * 1e-10, 0.0))
            r = r + np.where(weak, scale * 1e-10, 0.0) * c_all[self.free3]
        if damping > 0:
            # Levenberg-Marquardt: moving a control point from cp_current costs damping times the
            # problem's curvature along it, floored so that points little data reaches are held too.
            d = damping * np.maximum(diag, 1e-3 * float(diag.mean()))
            M_ff = M_ff + sp.diags(d)
            r = r + d * c_all[self.free3]
        c_all = c_all.copy()
        c_all[self.free3] = _solve_spd(M_ff.tocsc(), r)
        return c_all.reshape(3, -1).T.reshape(cp_current.shape)
