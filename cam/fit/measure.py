"""How far a fitted surface lies from the mesh: on a fixed lattice, and at its worst points, searched for.

The fit itself draws the surface onto the mesh on a lattice a quarter of a quad apart (`measure_lattice`),
the same points whatever the knots, so that fits compare on them. Between those points the surface can
still leave the mesh: a wiggle near a strip's end, a cusp where it crosses a crease of the mesh.
What the fit reports, and whether it refines, rests on the search instead (`surface_peaks`).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter

from cam.fit.foot import foot_frames
from cam.mesh.closest import MeshIndex, closest_points, triangle_normals
from cam.spline.basis import evaluate_surface, span_params
from cam.spline.knots import lattice_knots

__all__ = ["border_distance", "measure_lattice", "surface_peaks"]


def surface_peaks(index: MeshIndex, knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, *,
                  per_quad: int = 8, peaks: int = 32, rounds: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The surface's largest local distances from the mesh.

    The surface is sampled `per_quad` times per quad each way and at least 4 times per knot span;
    around each of its `peaks` worst local maxima a 9 x 9 grid spans the cells on either side, then a
    grid 4 times finer around the best point of that, `rounds` times. Four samples per knot span (half
    a quad apart on a span of two quads) reported Fandisk's strip 46 at 0.041 mm where a 513 x 513
    grid finds 0.075 mm.

    Parameters
    ----------
    index : MeshIndex
        The triangle mesh (`cam.mesh.closest.mesh_index`).
    knots_u, knots_v : ndarray, shape (nu + 4,), (nv + 4,), float64
        The bicubic surface's clamped knot vectors, grid-index units (quads).
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    per_quad : int
        Samples per quad each way, >= 1.
    peaks : int
        Local maxima searched around, >= 1.
    rounds : int
        Refinements of the search around each, >= 0.

    Returns
    -------
    u, v : ndarray, shape (k,), float64
        Parameters of the k <= `peaks` peaks found, grid-index units.
    distance : ndarray, shape (k,), float64
        Their distances from the mesh, mm; the largest distance is ``distance.max()``.

    Raises
    ------
    ValueError
        Where per_quad, peaks or rounds is out of range.
    """
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    cp = np.asarray(control_points, dtype=np.float64)
    if per_quad < 1 or peaks < 1 or rounds < 0:
        raise ValueError(f"per_quad and peaks must be >= 1 and rounds >= 0, got {per_quad}, {peaks}, {rounds}")
    grids = [np.unique(np.concatenate([_even_params(k, per_quad), span_params(k, 4)])) for k in (ku, kv)]
    uu, vv = np.meshgrid(*grids, indexing="ij")
    u, v = uu.ravel(), vv.ravel()
    d = _distance_at(index, ku, kv, cp, u, v)
    # The worst local maxima, not the worst samples: those crowd round one peak and miss the next.
    top = np.flatnonzero(d == maximum_filter(d.reshape(uu.shape), size=3, mode="nearest").ravel())
    top = top[np.argsort(d[top])[-peaks:]]
    # The peaks are often cusps (the surface crosses a crease of the mesh), 0.005 mm high within a
    # hundredth of a quad: each round searches around the best point so far on a finer grid.
    best_u, best_v, best = u[top], v[top], d[top]
    h = np.array([np.diff(g).max(initial=0.0) for g in grids])
    t = np.linspace(-1.0, 1.0, 9)
    du, dv = (x.ravel() for x in np.meshgrid(t, t, indexing="ij"))
    rows = np.arange(top.size)
    for _ in range(rounds):
        pu = np.clip(best_u[:, None] + h[0] * du, ku[0], ku[-1])
        pv = np.clip(best_v[:, None] + h[1] * dv, kv[0], kv[-1])
        dd = _distance_at(index, ku, kv, cp, pu.ravel(), pv.ravel()).reshape(pu.shape)
        k = np.argmax(dd, axis=1)
        better = dd[rows, k] > best
        best_u, best_v = np.where(better, pu[rows, k], best_u), np.where(better, pv[rows, k], best_v)
        best = np.maximum(best, dd[rows, k])
        h = h / 4.0
    return best_u, best_v, best


def border_distance(index: MeshIndex, knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, *,
                    per_quad: int = 8) -> float:
    """The largest distance (mm) from the mesh of the surface's border, at the points `surface_peaks` samples there.

    Those points are `per_quad` per quad along each side whatever the knots, and `surface_peaks` returns at
    least the largest of its samples' distances; so a surface whose border is held (fitted inside fixed
    boundary curves) has peaks at least this far from the mesh, however its knots are refined.

    Parameters
    ----------
    index : MeshIndex
        The triangle mesh (`cam.mesh.closest.mesh_index`).
    knots_u, knots_v : ndarray, shape (nu + 4,), (nv + 4,), float64
        The bicubic surface's clamped knot vectors, grid-index units (quads).
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    per_quad : int
        Samples per quad along each side, >= 1 (as `surface_peaks`).

    Returns
    -------
    float
        The distance, mm.
    """
    ku, kv = np.asarray(knots_u, dtype=np.float64), np.asarray(knots_v, dtype=np.float64)
    if per_quad < 1:
        raise ValueError(f"per_quad must be >= 1, got {per_quad}")
    gu, gv = _even_params(ku, per_quad), _even_params(kv, per_quad)
    u = np.concatenate([gu, gu, np.full(gv.size, ku[0]), np.full(gv.size, ku[-1])])
    v = np.concatenate([np.full(gu.size, kv[0]), np.full(gu.size, kv[-1]), gv, gv])
    return float(_distance_at(index, ku, kv, np.asarray(control_points, dtype=np.float64), u, v).max())


def _even_params(knots: np.ndarray, per_quad: int) -> np.ndarray:
    """`per_quad` parameters per unit along the knots' domain, both ends included (float64)."""
    lo, hi = float(knots[0]), float(knots[-1])
    return np.linspace(lo, hi, max(int(np.ceil((hi - lo) * per_quad)), 1) + 1)


def _distance_at(index: MeshIndex, ku, kv, cp, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Distance (mm) from the surface at parameters (u, v) to the mesh."""
    S = evaluate_surface(ku, kv, cp, u, v, order=0)[(0, 0)]
    return closest_points(index, S)[1]


def measure_lattice(knots_u: np.ndarray, knots_v: np.ndarray, control_points: np.ndarray, mesh: MeshIndex, *,
                    spacing: float, degree: tuple[int, int] = (3, 3), edges: bool = False,
                    points: tuple[np.ndarray, np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points of the surface on a lattice of parameters, and the mesh near them.

    The lattice is the same for any knots whose spans are all at least twice `spacing` wide, so fits
    with different knots compare on it (see `_lattice_values`).

    Parameters
    ----------
    knots_u, knots_v : ndarray, shape (nu + p + 1,), (nv + q + 1,), float64
        The surface's clamped knot vectors, grid-index units.
    control_points : ndarray, shape (nu, nv, 3), float64
        The control net, mm.
    mesh : MeshIndex
        The triangle mesh (`cam.mesh.closest.mesh_index`).
    spacing : float
        Lattice spacing, parameter units.
    degree : tuple of int
        (p, q), the surface's degrees.
    edges : bool
        Whether points whose closest mesh point is off to the side (on an edge) are ok too, with the
        direction from that point for their normal.
    points : tuple of two ndarray, each shape (k,), float64, or None
        Parameters (u, v) measured besides the lattice (clipped into the domain).

    Returns
    -------
    u, v : ndarray, shape (m,), float64
        The lattice's parameters (every pair of its values each way, row-major), then `points`'.
    distance : ndarray, shape (m,), float64
        Distance from the surface point to the mesh, mm.
    near : ndarray, shape (m, 3), float64
        The closest mesh points, mm.
    normals : ndarray, shape (m, 3), float64
        Unit normals of their triangles (with `edges`, of the distance where off to the side).
    ok : ndarray, shape (m,), bool
        The mesh lies along its triangle's normal from the point (within 27°) and the triangle faces
        the way the surface does (within 60°): the points to draw onto the mesh.
    """
    ku, kv, cp = knots_u, knots_v, control_points
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
    along = np.einsum("ij,ij->i", r, fn)
    square = np.linalg.norm(r - along[:, None] * fn, axis=1) <= 1e-6 + 0.5 * np.abs(along)
    ok = square & (np.abs(np.einsum("ij,ij->i", fn, frame.normal)) > 0.5)
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

