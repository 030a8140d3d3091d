"""One surface fitted to mesh samples by squared-distance minimisation (the paper's iteration).

Each step projects the samples onto the current surface (foot points, `cam.fit.foot`), replaces
the squared distance of every sample by its local quadratic approximation and solves the
resulting linear least-squares problem for the free control points (`cam.fit.system`, which
describes the terms). Fixed control points (a shared border) stay exactly as given. The iteration
keeps the best step seen, retakes a step that folds the net more from the best one, damped, and
stops when the steps stop improving.

Squared-distance steps leave tangential motion free, so the parameterisation is
held by anchors: the quad grid's vertices, moved onto the mesh, keep the grid
parameters (i, j) they have by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam import CheckCancel, Progress
from cam.fit.foot import FootFrame, foot_frames, project_points
from cam.fit.measure import measure_lattice
from cam.fit.param import Anchors
from cam.fit.system import (
    NormalEquations,
    anchor_rows,
    dot_rows,
    kink_rows,
    normal_rows,
    sdm_weights,
    tangent_plane,
)
from cam.mesh.closest import MeshIndex
from cam.spline.basis import surface_rows
from cam.spline.folds import find_folds
from cam.spline.surface import make_bspline_surface

__all__ = ["SurfaceFit", "fit_surface"]


@dataclass(frozen=True, eq=False)
class SurfaceFit:
    """A fitted control net and where the n samples fell on it.

    Attributes
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The knot vectors, parameter units (grid-index units in the fit).
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    u, v : ndarray, shape (n,), float64
        The samples' foot parameters.
    distance : ndarray, shape (n,), float64
        Distance from each sample to its foot point, mm.
    clamped : ndarray, shape (n,), bool
        Foot on the border with the sample beyond it.
    counted : ndarray, shape (n,), bool
        The samples the fit answers for (all, or those inside a fixed border).
    iterations : int
        The step this fit came from.
    folded : float
        Share of the surface that folds over itself (`cam.spline.surface.find_folds`).
    surface_u, surface_v : ndarray, shape (m,), float64
        Points of the surface (a lattice of parameters, `cam.fit.measure.measure_lattice`), when
        the fit was given the mesh; else empty.
    surface_distance : ndarray, shape (m,), float64
        Their distance to the mesh, mm.
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


@dataclass(frozen=True, eq=False)
class _Feet:
    """What a step's terms are built from besides its fit: the frames at the feet (n), each sample's
    offset along the normal (n,) mm and within the tangent plane (n, 3) mm, and the lattice on the
    mesh (`measure_lattice`'s six arrays; None without a mesh)."""

    frame: FootFrame
    along: np.ndarray
    off: np.ndarray
    lattice: tuple | None


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
                degree: tuple[int, int] = (3, 3), check_cancel: CheckCancel | None = None,
                progress: Progress | None = None) -> SurfaceFit:
    """Fit a B-spline surface with the given knots to samples, keeping `fixed` control points.

    Stops when the largest distance is within tolerance and no longer improving, when it stops
    improving, or after `iterations` steps; returns the best step seen: the least folded, and of
    those the closest (`SurfaceFit.improves_on`). A step that folds the net more is taken again
    from the best one, damped (Levenberg-Marquardt).

    Parameters
    ----------
    points : ndarray, shape (n, 3), float64
        The mesh samples, mm.
    normals : ndarray, shape (n, 3), float64
        The mesh's unit normals at them.
    u, v : ndarray, shape (n,), float64
        Starting parameters, in the knots' units.
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's clamped knot vectors, parameter units (grid-index units in the fit).
    control_points : ndarray, shape (nu, nv, 3), float64, or None
        The start, mm (required when `fixed` is given); None: the first step fits each sample's
        tangent plane at (u, v).
    fixed : ndarray, shape (nu, nv), bool, or None
        Control points kept as given.
    anchors : Anchors or None
        The quad grid's vertices on the mesh (`cam.fit.param.grid_anchors`), parameters fixed.
    lengths_mm : tuple of float
        mm per parameter unit along u and v (scales the thin-plate energy to the part).
    tolerance_mm : float
        The distance the fit aims to stay within, mm.
    smoothing_mm2, smoothing_decay, smoothing_floor : float
        The smoothing weight (mm²) starts at `smoothing_mm2` and shrinks by `smoothing_decay` per
        step down to `smoothing_floor` times it, so early steps are stiff and the converged surface
        is not biased by it.
    normal_weight_mm : float
        Weight of the normal term: an angle error of ε rad costs as much as a distance of
        ε · normal_weight_mm.
    kink_weight_mm : float
        The same for the two sides of a C0 knot line (a border that turns a corner) against their
        shared normal, so the line is a kink of the parameters only, not a crease of the surface.
    anchor_weight : float
        Weight in all of the anchors' offsets across the patch border, against the mean squared
        distance (they hold the patch's extent).
    param_weight : float
        Weight in all of the anchors' other tangential offsets (they keep the parameterisation from
        sliding without forcing the grid's irregularities on it).
    pull_weight : float
        Weight of the samples beyond a pulled border (see `clamped_samples`).
    pull_sides : tuple of 4 bool
        The sides pulled: u = u0, u = u1, v = v0, v = v1 (a patch fitted on its own, not across a
        crease, where samples beyond belong to the other face).
    clamped_samples : {"pull", "drop"}
        "pull" draws the border out towards samples beyond it; "drop" ignores them (a border that
        is a shared curve).
    iterations : int
        Steps at most.
    warm : bool
        A start that already fits (e.g. after knot insertion): the smoothing starts at the floor.
    mesh : MeshIndex or None
        The triangle mesh the samples come from. With it, every step also measures the surface
        itself on a lattice of parameters `mesh_spacing` apart (`cam.fit.measure.measure_lattice`)
        against the mesh, and draws those points onto the mesh (their closest points, along the mesh
        normal there, `mesh_weight` in all against the samples' 1): samples alone leave a span with
        few of them free to bulge between them.
    mesh_weight, mesh_spacing : float
        See `mesh`; mesh_spacing in parameter units.
    mesh_edges : bool
        Draw the points whose closest mesh point is off to the side (on an edge: past a crease, or
        past the mesh's own border) towards it as well, along the distance's own direction (for a
        surface inside fixed borders, where the surface has no business past the mesh).
    mesh_points : tuple of two ndarray, each shape (k,), float64, or None
        Parameters (u, v) measured and drawn onto the mesh besides the lattice (the peaks a search
        found between its points: a refit after knot insertion for them must see them, or a start
        within tolerance on the lattice is the best step it finds, and it gives back the same surface).
    degree : tuple of int
        (p, q), the surface's degrees.
    check_cancel : callable or None
        Called before every step; it raises to stop the fit.
    progress : callable or None
        progress(fraction, message) before every step: the share of the `iterations` + 1 steps taken (the
        iteration may stop before the last).

    Returns
    -------
    SurfaceFit
        The best step's control net, the samples' feet and distances, and the lattice's distances.

    Raises
    ------
    ValueError
        For shapes that do not match, an unknown `clamped_samples`, or `fixed` without `control_points`.
    """
    P, Nm, ku, kv, fixed = _check_surface_inputs(points, normals, knots_u, knots_v, control_points, fixed,
                                                 clamped_samples=clamped_samples, degree=degree)
    system = NormalEquations(ku, kv, fixed, lengths_mm=lengths_mm, degree=degree)
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    n = max(len(P), 1)
    cp = _start_net(system, P, Nm, u, v, ku, kv, control_points, anchors=anchors, anchor_weight=anchor_weight,
                    param_weight=param_weight, smoothing_mm2=smoothing_mm2, degree=degree)
    best = best_feet = None
    gram, gram_of = None, None  # the last step's Gram blocks, and the fit they were built from
    stalls, damping = 0, 0.0
    # A pulled border settles like a contact problem (samples come in and out of reach), so it gets
    # more patience before the iteration is called stuck.
    patience = 4 if clamped_samples == "pull" else 2
    for it in range(iterations + 1):
        if check_cancel is not None:
            check_cancel()
        if progress is not None:
            progress(it / (iterations + 1), f"step {it + 1} of {iterations + 1} at most")
        folded = find_folds(make_bspline_surface(cp, ku, kv, degree=degree))[0]
        if best is not None and folded > best.folded:
            # Judged on the net alone: a step that folds more is taken again from the best fit, so
            # measuring it (four in ten steps on a 50k-point Fandisk cloud) would change nothing.
            verdict, stalls, damping = "folded", *_damp_fold(stalls, damping)
        else:
            fit, feet = _measure_step(P, ku, kv, cp, u, v, it, folded, clamped_samples=clamped_samples, mesh=mesh,
                                      mesh_spacing=mesh_spacing, mesh_edges=mesh_edges, mesh_points=mesh_points,
                                      degree=degree)
            verdict, stalls, damping = _judge_step(fit, best, stalls, damping, tolerance_mm)
        if verdict == "better":
            best, best_feet = fit, feet
        if it == iterations or (best.max_error <= tolerance_mm and stalls >= 1) or stalls >= patience:
            break
        base, base_feet = (best, best_feet) if verdict == "folded" else (fit, feet)
        lam = smoothing_mm2 * (smoothing_floor if warm else max(smoothing_decay ** (it + 1), smoothing_floor))
        if gram_of is not base:
            # A step taken again from the same fit (after a fold) has the same terms: only lam and
            # the damping differ, so its Gram blocks are the last step's.
            gram, gram_of = system.gram(_step_rows(
                P, Nm, base, base_feet, n=n, clamped_samples=clamped_samples, pull_weight=pull_weight,
                pull_sides=pull_sides, mesh_weight=mesh_weight, normal_weight_mm=normal_weight_mm,
                kink_weight_mm=kink_weight_mm, lengths_mm=lengths_mm, anchors=anchors, anchor_weight=anchor_weight,
                param_weight=param_weight, degree=degree)), base
        cp = system.solve_gram(gram, lam, base.control_points, damping)
        u, v = base.u, base.v
    return best


def _check_surface_inputs(points, normals, knots_u, knots_v, control_points, fixed, *, clamped_samples: str,
                          degree: tuple[int, int]):
    """The samples (n, 3), normals (n, 3), knots and fixed mask (nu, nv) as arrays; ValueError where they
    do not fit together."""
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
    return P, Nm, ku, kv, fixed


def _start_net(system: NormalEquations, P, Nm, u, v, ku, kv, control_points, *, anchors: Anchors | None,
               anchor_weight: float, param_weight: float, smoothing_mm2: float, degree: tuple[int, int]
               ) -> np.ndarray:
    """The control net (nu, nv, 3) mm the iteration starts from: a copy of the one given, else the first step.

    The first step fits each sample's tangent plane (its mesh normal), the anchors on the mesh and on
    the border. Point distances at the seed parameters would drag the parameterisation along with the
    seed's errors, and undoing tangential distortion is what foot-point steps do worst.
    """
    nu, nv = ku.size - degree[0] - 1, kv.size - degree[1] - 1
    if control_points is not None:
        cp = np.asarray(control_points, dtype=np.float64).copy()
        if cp.shape != (nu, nv, 3):
            raise ValueError(f"control_points must have shape {(nu, nv, 3)}, got {cp.shape}")
        return cp
    n = max(len(P), 1)
    rows = [(surface_rows(ku, kv, u, v, degree=degree), [(Nm, np.full(len(P), 1.0 / n), dot_rows(Nm, P))])]
    if anchors is not None:
        t1, t2 = tangent_plane(anchors.normals)
        rows.append(anchor_rows(anchors, ku, kv, t1, t2, degree=degree, border_weight=anchor_weight,
                                param_weight=param_weight,
                                extra=((anchors.normals, anchor_weight / len(anchors.points)),)))
    return system.solve(rows, smoothing_mm2, np.zeros((nu, nv, 3)))


def _measure_step(P, ku, kv, cp, u, v, it: int, folded: float, *, clamped_samples: str, mesh: MeshIndex | None,
                  mesh_spacing: float, mesh_edges: bool, mesh_points, degree: tuple[int, int]
                  ) -> tuple[SurfaceFit, _Feet]:
    """Project the samples P (n, 3) onto the net cp from (u, v) (n,), and measure the lattice on the mesh;
    `folded` is the net's fold share (`find_folds`)."""
    u, v, dist = project_points(ku, kv, cp, P, u, v, degree=degree)
    frame = foot_frames(ku, kv, cp, u, v, degree=degree)
    r = P - frame.point
    along = dot_rows(r, frame.normal)
    off = r - along[:, None] * frame.normal
    clamped = np.linalg.norm(off, axis=1) > 1e-6 + 1e-3 * np.abs(along)
    counted = ~clamped if clamped_samples == "drop" else np.ones(len(P), dtype=bool)
    lattice = measure_lattice(ku, kv, cp, mesh, spacing=mesh_spacing, degree=degree, edges=mesh_edges,
                              points=mesh_points) if mesh is not None else None
    extra = {} if lattice is None else dict(surface_u=lattice[0], surface_v=lattice[1], surface_distance=lattice[2])
    fit = SurfaceFit(ku, kv, cp, u, v, dist, clamped, counted, it, folded, **extra)
    return fit, _Feet(frame, along, off, lattice)


def _judge_step(fit: SurfaceFit, best: SurfaceFit | None, stalls: int, damping: float, tolerance_mm: float
                ) -> tuple[str, int, float]:
    """Whether a step that folds the net no more than the best so far is "better" or "stalled"; with the
    stall count and the damping that follow."""
    if best is None or fit.folded < best.folded or fit.improves_on(best, tolerance_mm):
        clearly = best is None or fit.folded < best.folded or fit.improves_on(best, tolerance_mm, by=0.05)
        return "better", 0 if clearly else stalls + 1, 0.0 if damping <= 1e-3 else damping / 10.0
    return "stalled", stalls + 1, damping


def _damp_fold(stalls: int, damping: float) -> tuple[int, float]:
    """The stall count and damping after a step that folds the net more than the best fit does."""
    # Squared-distance steps leave tangential motion almost free, and as the smoothing decays
    # a net can fold while it hugs the data ever closer: a step that folds more is no progress.
    # Take the step again from the best fit, shorter (Levenberg-Marquardt). A refit after knot
    # insertion, whose new control points little data holds, folds at its first full step;
    # without this it never moves. A fold that no damping prevents is a stall.
    damping = 1.0 if damping == 0.0 else 10.0 * damping
    return stalls + (damping > 100.0), damping


def _step_rows(P, Nm, fit: SurfaceFit, feet: _Feet, *, n: int, clamped_samples: str, pull_weight: float,
               pull_sides, mesh_weight: float, normal_weight_mm: float, kink_weight_mm: float, lengths_mm,
               anchors: Anchors | None, anchor_weight: float, param_weight: float, degree: tuple[int, int]) -> list:
    """The row sets of the step from `fit` (`cam.fit.system`): the samples' squared distances, the
    lattice drawn onto the mesh, the normal term, G1 across C0 knot lines and the anchors."""
    ku, kv, cp, u, v, clamped = fit.knots_u, fit.knots_v, fit.control_points, fit.u, fit.v, fit.clamped
    frame, along, off = feet.frame, feet.along, feet.off
    keep = (~clamped).astype(np.float64) / n
    terms = [(frame.normal, keep, dot_rows(frame.normal, P)),
             (frame.t1, sdm_weights(along, frame.k1) * keep, dot_rows(frame.t1, P)),
             (frame.t2, sdm_weights(along, frame.k2) * keep, dot_rows(frame.t2, P))]
    if clamped_samples == "pull":
        # Beyond the border, pull within the tangent plane only: the offset along the normal
        # there is the surface's curvature, not a fitting error.
        out = off / np.maximum(np.linalg.norm(off, axis=1, keepdims=True), 1e-300)
        (u0, u1), (v0, v1) = (ku[degree[0]], ku[-degree[0] - 1]), (kv[degree[1]], kv[-degree[1] - 1])
        on_side = np.stack([u <= u0, u >= u1, v <= v0, v >= v1], axis=1)
        pull = clamped & (on_side & np.asarray(pull_sides, dtype=bool)).any(axis=1)
        terms.append((out, pull_weight * pull / n, dot_rows(out, P)))
    rows = [(surface_rows(ku, kv, u, v, degree=degree), terms)]
    if feet.lattice is not None:
        gu, gv, _, near, mesh_normal, ok = feet.lattice
        w = mesh_weight * ok / max(int(ok.sum()), 1)
        rows.append((surface_rows(ku, kv, gu, gv, degree=degree), [(mesh_normal, w, dot_rows(mesh_normal, near))]))
    if normal_weight_mm > 0:
        rows += normal_rows(ku, kv, u, v, Nm, frame.su, frame.sv, keep, degree=degree, weight_mm=normal_weight_mm,
                            lengths_mm=lengths_mm)
    if kink_weight_mm > 0:
        rows += kink_rows(ku, kv, cp, degree=degree, weight_mm=kink_weight_mm, lengths_mm=lengths_mm)
    if anchors is not None:
        af = foot_frames(ku, kv, cp, anchors.u, anchors.v, degree=degree)
        rows.append(anchor_rows(anchors, ku, kv, af.t1, af.t2, degree=degree, border_weight=anchor_weight,
                                param_weight=param_weight))
    return rows
