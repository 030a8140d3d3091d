"""Mesh denoising for the ``denoise`` stage: MeshTGV normal filtering, then the vertex update.

``denoise_mesh`` is the public entry. The normal filtering lives in :mod:`cam.denoise.tgv`; this
module validates the input, makes it scale and translation free (lengths in units of the mean edge
length), runs the filter, moves the vertices to follow the filtered normals and maps the result back
to the input's units.

Vertex update (the scheme the MeshTGV paper uses, after Sun et al. 2007): iterated
    x_i <- x_i + 1/|F_i| sum_{f in F_i} n_f (n_f . (c_f - x_i)),
with F_i the faces around vertex i, n_f the filtered normals and c_f the current centroids.
That update moves vertices only along normals, so a triangle that the noise folded over (its
orientation reversed in the tangent plane, common for small faces under noise with a tangential
component) is left folded: its plane is right but its normal points the wrong way. ``flip_repair_rounds``
rounds of a local repair follow: the vertices of every face whose normal opposes its filtered normal
are moved to the average of their neighbours within the tangent plane (normal motion is left to the
update), then a few more update iterations run. Set it to 0 for the paper's update alone.

Bad input: non-finite coordinates, wrong shapes, out-of-range indices, parameters out of range ->
ValueError (a caller's bug: the pipeline's readers and `DenoiseParams` rule them out); no face of
non-zero area -> :class:`~cam.GeometryError` (the user's mesh is degenerate). Zero-area faces
(repeated vertex indices or an area below 1e-12 mean-edge-lengths squared) are handled: they are
left out of the filtering and of the vertex update, and their reported normal is the normalised
mean of the filtered normals of the faces sharing a vertex with them (zero when they have none).
Edges with more than two faces (non-manifold) are handled by not coupling the faces across them
(they act like boundary edges); neighbours with inconsistent orientation are compared with a sign
flip. All counts are in the report.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from cam import CheckCancel, GeometryError, Progress
from cam.denoise.tgv import face_topology, tgv_filter_normals
from cam.params import DenoiseParams

__all__ = ["PARAMETER_BOUNDS", "DenoiseResult", "denoise_mesh"]


@dataclass(frozen=True)
class DenoiseResult:
    vertices: np.ndarray  # (n, 3) float64, input units
    face_normals: np.ndarray  # (m, 3) float64, filtered unit normals
    iterations: int  # outer iterations of the normal filter
    report: dict = field(default_factory=dict)  # plain JSON types only


# name: (default, lower, upper, lower_inclusive); upper is inclusive. Same numbers as DenoiseParams
# (checked again here for a group built without validation, e.g. by model_construct).
PARAMETER_BOUNDS: dict[str, tuple[float, float, float, bool]] = {
    "alpha0": (0.15, 0.0, 100.0, False),
    "alpha1": (0.4, 0.0, 100.0, False),
    "penalty0": (2.0, 0.0, 1000.0, False),
    "penalty1": (2.0, 0.0, 1000.0, False),
    "vertex_iterations": (20, 0, 1000, True),
    "flip_repair_rounds": (5, 0, 100, True),
    "max_iterations": (100, 1, 10000, True),
    "tolerance": (1e-5, 0.0, 1.0, True),
    "noise_reference_deg": (15.0, 0.0, 180.0, True),
}

_DEGENERATE_REL_AREA = 1e-12  # faces with area below this (in mean edge lengths squared) are degenerate
_REPAIR_UPDATE_ITERATIONS = 5  # vertex-update iterations after each flip-repair round


def denoise_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    params: DenoiseParams = DenoiseParams(),
    *,
    progress: Progress | None = None,
    check_cancel: CheckCancel | None = None,
) -> DenoiseResult:
    """Denoise a triangle mesh with MeshTGV normal filtering and the iterative vertex update.

    vertices: (n, 3) real coordinates, any unit; faces: (m, 3) integer indices into them.
    Returns vertices float64 (n, 3) in the input's units and frame, and the filtered unit face
    normals float64 (m, 3).

    Every parameter of ``params`` is dimensionless: the mesh is first expressed in units of its
    mean edge length, so the result does not depend on the input's scale, position or
    orientation. ``params.enabled`` is not read here (the stage skips a disabled denoise).

    alpha0: weight of the second-order TGV term (jumps of the auxiliary gradient field across
        edges, gradients per mean edge length, each jump weighted by its edge length in mean edge
        lengths). Larger: the auxiliary field is dearer and the filter behaves more like plain TV
        (crisper creases, curved parts drift towards facets); smaller: ramps replace creases.
    alpha1: weight of the first-order TGV term (jump of the normal across each edge, minus the jump
        the auxiliary field predicts, weighted by edge length in mean edge lengths), relative to the
        area-weighted fidelity (areas in mean edge lengths squared). Larger: stronger denoising.
    penalty0, penalty1: augmented-Lagrangian penalties of the two split variables (same units as
        alpha0, alpha1). They fix the linear systems, which are factored once.
    vertex_iterations: iterations of the vertex update.
    flip_repair_rounds: rounds of the folded-face repair after the update (0: paper's update only).
    max_iterations: cap on the outer iterations of the normal filter.
    tolerance: stop when |N_k - N_{k-1}| / |N_{k-1}| (Frobenius norms) falls below it.
    noise_reference_deg: noise adaptation. The median dihedral angle over the interior edges of the
        input measures its noise (clean CAD meshes: under 1 deg; the benchmark meshes: about 20 deg).
        alpha0 and alpha1 are multiplied by min(1, median / noise_reference_deg), so noisy input gets
        the full weights and clean input is left (nearly) alone. 0 switches the adaptation off.
    progress: ``progress(fraction, message)``, called once per outer iteration (fractions rise
        through [0, 0.9)) and once at the end with 1.0.
    check_cancel: called once before the filter, once per outer iteration and once per vertex
        iteration; it stops the work by raising (the exception passes through untouched).

    Raises :class:`~cam.GeometryError` when no face has a non-zero area; ``ValueError`` for
    arrays or parameters a caller got wrong.
    """
    t0 = time.perf_counter()
    options = _check_params({name: getattr(params, name) for name in PARAMETER_BOUNDS})
    check_cancel = check_cancel or _no_cancel

    v_in, f_in = _check_mesh(vertices, faces)
    n, m = len(v_in), len(f_in)
    check_cancel()

    # --- degenerate faces and the length unit ---------------------------------------------
    # a first length unit from the faces with three distinct vertices decides which faces have
    # zero area; the unit and the centre used from then on come from the valid faces alone, so
    # adding or removing degenerate faces does not change the result on the others
    repeated = (f_in[:, 0] == f_in[:, 1]) | (f_in[:, 1] == f_in[:, 2]) | (f_in[:, 2] == f_in[:, 0])
    ell0 = _mean_edge_length(v_in, f_in[~repeated])
    if not np.isfinite(ell0) or ell0 <= 0.0:
        raise GeometryError(f"all {m} faces are degenerate (no face has an edge of non-zero length)")
    cross = np.cross(v_in[f_in[:, 1]] - v_in[f_in[:, 0]], v_in[f_in[:, 2]] - v_in[f_in[:, 0]])
    area0 = 0.5 * np.linalg.norm(cross, axis=1) / (ell0 * ell0)
    valid = ~repeated & (area0 > _DEGENERATE_REL_AREA)
    n_degenerate = int(m - valid.sum())
    if not valid.any():
        raise GeometryError(f"all {m} faces are degenerate (zero area)")
    vf = f_in[valid]
    ell = _mean_edge_length(v_in, vf)
    used = np.unique(vf)
    center = v_in[used].mean(axis=0)
    x = (v_in - center) / ell

    # --- noise adaptation -------------------------------------------------------------------------
    topo = face_topology(vf, n)
    median_dihedral = _median_dihedral_deg(x, vf, topo)
    if options["noise_reference_deg"] > 0:
        weight_scale = min(1.0, median_dihedral / options["noise_reference_deg"])
    else:
        weight_scale = 1.0
    alpha0_used = options["alpha0"] * weight_scale
    alpha1_used = options["alpha1"] * weight_scale

    # --- normal filtering ---------------------------------------------------------------------

    def on_iteration(k: int, rel: float) -> None:
        if progress is not None:
            progress(0.9 * k / (options["max_iterations"] + 1),
                     f"normal filtering: iteration {k}, relative change {rel:.3g}")

    tgv = tgv_filter_normals(
        x, vf, topo,
        alpha0=alpha0_used, alpha1=alpha1_used,
        r0=options["penalty0"], r1=options["penalty1"],
        max_iterations=options["max_iterations"], tolerance=options["tolerance"],
        on_iteration=on_iteration, check_cancel=check_cancel,
    )
    normals_valid = tgv.normals

    # --- vertex update --------------------------------------------------------------------------
    t_vu = time.perf_counter()
    x_new, flips_before, flips_after = _update_vertices(
        x, vf, normals_valid, options["vertex_iterations"], options["flip_repair_rounds"],
        check_cancel=check_cancel,
    )
    t_vu_end = time.perf_counter()

    face_normals = np.zeros((m, 3))
    face_normals[valid] = normals_valid
    no_normal = 0
    if n_degenerate:
        no_normal = _fill_degenerate_normals(face_normals, f_in, valid, n)

    out = v_in.copy()
    moved = np.zeros(n, dtype=bool)
    moved[np.unique(vf)] = True
    out[moved] = x_new[moved] * ell + center
    if not np.all(np.isfinite(out)):  # cannot happen for valid input; never hand back garbage
        raise ValueError("denoising produced non-finite coordinates")

    warnings = []
    if not tgv.converged:
        warnings.append(f"normal filtering stopped at max_iterations={options['max_iterations']} with "
                        f"relative change {tgv.relative_change:.3g} (tolerance {options['tolerance']:g})")
    sliver = _sliver_fraction(x, vf)
    if sliver > 0.1:
        warnings.append(f"{100 * sliver:.0f}% of the faces are slivers (longest edge > 10x the height "
                        "on it); the filter over-smooths such meshes, remesh first or lower alpha1")
    if flips_after:
        warnings.append(f"{flips_after} faces remain folded over (normal against the filtered one)")
    if progress is not None:
        progress(1.0, "denoising done")
    t_end = time.perf_counter()
    report = {
        "iterations": int(tgv.iterations),
        "converged": bool(tgv.converged),
        "final_relative_change": float(tgv.relative_change),
        "time_s": {
            "setup": round(tgv.setup_seconds, 6),
            "factorization": round(tgv.factor_seconds, 6),
            "normal_iterations": round(tgv.iterate_seconds, 6),
            "vertex_update": round(t_vu_end - t_vu, 6),
            "total": round(t_end - t0, 6),
        },
        "parameters": {k: (int(v) if isinstance(v, (int, np.integer)) else float(v))
                       for k, v in options.items()},
        "scaling": {
            "length_unit": "mean edge length",
            "mean_edge_length": float(ell),
            "center": [float(c) for c in center],
            "median_dihedral_deg": float(median_dihedral),
            "noise_weight_scale": float(weight_scale),
            "alpha0_used": float(alpha0_used),
            "alpha1_used": float(alpha1_used),
            # the same energy written in the input's units (areas and lengths not rescaled)
            "alpha1_used_input_units": float(alpha1_used * ell),
            "alpha0_used_input_units": float(alpha0_used * ell * ell),
        },
        "mesh": {
            "vertices": int(n),
            "faces": int(m),
            "degenerate_faces": n_degenerate,
            "degenerate_faces_without_normal": int(no_normal),
            "interior_edges": int(tgv.n_edges),
            "boundary_edges": int(topo.n_boundary_edges),
            "nonmanifold_edges": int(topo.n_nonmanifold_edges),
            "inconsistently_oriented_edges": int(topo.n_flipped_edges),
        },
        "folded_faces": {"after_update": int(flips_before), "after_repair": int(flips_after)},
        "sliver_face_fraction": float(sliver),
        "warnings": warnings,
    }
    return DenoiseResult(vertices=out, face_normals=face_normals, iterations=int(tgv.iterations),
                         report=report)


# ------------------------------------------------------------------------------------------------
def _no_cancel() -> None:
    pass


def _check_params(params: dict) -> dict:
    out = {}
    for name, value in params.items():
        default, lo, hi, lo_incl = PARAMETER_BOUNDS[name]
        integral = isinstance(default, int)
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            # ValueError, not TypeError: the stage contract is "bad input -> ValueError"
            raise ValueError(f"{name} must be a number, got {value!r}")  # noqa: TRY004
        if not np.isfinite(float(value)):
            raise ValueError(f"{name} must be finite, got {value!r}")
        if integral and float(value) != int(value):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        v = int(value) if integral else float(value)
        if v > hi or v < lo or (v == lo and not lo_incl):
            bound = f"{'[' if lo_incl else '('}{lo}, {hi}]"
            raise ValueError(f"{name}={value!r} is outside {bound}")
        out[name] = v
    return out


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise ValueError(f"vertices must have shape (n >= 3, 3), got {v.shape}")
    if not np.issubdtype(v.dtype, np.number) or np.issubdtype(v.dtype, np.complexfloating):
        raise ValueError(f"vertices must be real numbers, got dtype {v.dtype}")
    v = v.astype(np.float64, copy=True)
    bad = ~np.isfinite(v)
    if bad.any():
        rows = np.flatnonzero(bad.any(axis=1))
        raise ValueError(f"vertices contain {int(bad.sum())} non-finite values (NaN or inf), "
                         f"first at vertex {int(rows[0])}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1:
        raise ValueError(f"faces must have shape (m >= 1, 3) (triangles), got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"faces must be integer vertex indices, got dtype {f.dtype}")
    f = f.astype(np.int64, copy=True)
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"face indices must lie in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
    return v, f


def _mean_edge_length(v: np.ndarray, f: np.ndarray) -> float:
    if len(f) == 0:
        return 0.0
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    length = length[length > 0]
    return float(length.mean()) if len(length) else 0.0


def _median_dihedral_deg(x: np.ndarray, f: np.ndarray, topo) -> float:
    """Median angle between the normals of the two faces on each interior edge, in degrees."""
    if len(topo.edge_faces) == 0:
        return 0.0
    n = _unit(np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]))
    a, b = topo.edge_faces[:, 0], topo.edge_faces[:, 1]
    cosang = np.einsum("ij,ij->i", n[a], n[b]) * topo.edge_sign
    return float(np.degrees(np.arccos(np.clip(np.median(cosang), -1.0, 1.0))))


def _sliver_fraction(x: np.ndarray, f: np.ndarray) -> float:
    """Fraction of faces whose longest edge exceeds 10 times the height on it."""
    e = np.stack([x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 1]], x[f[:, 0]] - x[f[:, 2]]], axis=1)
    longest2 = np.max(np.einsum("fki,fki->fk", e, e), axis=1)
    dbl_area = np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1)
    # height on the longest edge = 2A / L; sliver when L / h = L^2 / (2A) > 10
    return float(np.mean(longest2 > 10.0 * dbl_area)) if len(f) else 0.0


def _unit(a: np.ndarray) -> np.ndarray:
    nrm = np.linalg.norm(a, axis=1)
    out = np.zeros_like(a)
    ok = nrm > 0
    out[ok] = a[ok] / nrm[ok, None]
    return out


def _update_vertices(x, f, normals, iterations, repair_rounds, *, check_cancel: CheckCancel | None = None):
    """Vertex update (Sun et al. scheme) plus the folded-face repair; mean-edge units."""
    n = len(x)
    m = len(f)
    # incidence: vertex-by-face, for sums over the faces around each vertex
    inc = sp.csr_matrix((np.ones(3 * m), (f.ravel(), np.repeat(np.arange(m), 3))), shape=(n, m))
    count = np.asarray(inc.sum(axis=1)).ravel()
    inv_count = np.where(count > 0, 1.0 / np.maximum(count, 1), 0.0)
    # sum_f n_f n_f^T c_f and sum_f n_f n_f^T per vertex are what the update needs:
    # x_i += 1/|F_i| (sum_f n_f n_f^T c_f - (sum_f n_f n_f^T) x_i)
    nnT = np.einsum("fi,fj->fij", normals, normals).reshape(m, 9)
    Msum = (inc @ nnT).reshape(n, 3, 3)

    def step(x):
        c = x[f].mean(axis=1)
        a = inc @ (normals * np.einsum("fi,fi->f", normals, c)[:, None])
        b = np.einsum("nij,nj->ni", Msum, x)
        return x + (a - b) * inv_count[:, None]

    check_cancel = check_cancel or _no_cancel
    x = x.copy()
    for _ in range(iterations):
        check_cancel()
        x = step(x)

    def folded(x):
        fn = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])
        return np.einsum("fi,fi->f", fn, normals) < 0

    bad = folded(x)
    flips_before = int(bad.sum())
    if repair_rounds > 0 and bad.any():
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        adj = sp.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        adj = ((adj + adj.T) > 0).astype(np.float64).tocsr()
        deg = np.asarray(adj.sum(axis=1)).ravel()
        vnormal = _unit(inc @ normals)
        for _ in range(repair_rounds):
            if not bad.any():
                break
            check_cancel()
            verts = np.unique(f[bad])
            lap = adj[verts] @ x / np.maximum(deg[verts], 1)[:, None] - x[verts]
            nv = vnormal[verts]
            x[verts] += lap - np.einsum("vi,vi->v", lap, nv)[:, None] * nv
            for _ in range(_REPAIR_UPDATE_ITERATIONS):
                x = step(x)
            bad = folded(x)
    return x, flips_before, int(bad.sum())


def _fill_degenerate_normals(face_normals, faces, valid, n) -> int:
    """Normals for degenerate faces: mean of the valid faces' normals around their vertices."""
    vf = faces[valid]
    vsum = np.zeros((n, 3))
    for k in range(3):
        np.add.at(vsum, vf[:, k], face_normals[valid])
    bad = np.flatnonzero(~valid)
    s = vsum[faces[bad]].sum(axis=1)
    face_normals[bad] = _unit(s)
    return int(np.sum(np.linalg.norm(s, axis=1) == 0))
