"""Mesh denoising for the ``denoise`` stage: MeshTGV normal filtering, then the vertex update.

``denoise_mesh`` is the public entry. The normal filtering lives in :mod:`cam.denoise.tgv`, the
vertex update in :mod:`cam.denoise.vertices`; this module checks the input arrays, makes the mesh
scale and translation free (lengths in units of the mean edge length), measures the noise
(:mod:`cam.denoise.noise`) and, for the weights the user left unset, chooses them from it
(:mod:`cam.denoise.weights`), runs the filter and the update, and maps the result back to the input's
units.

Bad input: non-finite coordinates, wrong shapes, out-of-range indices -> ValueError (a caller's bug:
the pipeline's readers rule them out; the parameters are those of a `DenoiseParams`, validated when
it was made); no face of non-zero area -> :class:`~cam.GeometryError` (the user's mesh is
degenerate). Zero-area faces (repeated vertex indices or an area below 1e-12 mean-edge-lengths
squared) are handled: they are left out of the filtering and of the vertex update, and their
reported normal is the normalised mean of the filtered normals of the faces sharing a vertex with
them (zero when they have none). Edges with more than two faces (non-manifold) are handled by not
coupling the faces across them (they act like boundary edges); neighbours with inconsistent
orientation are compared with a sign flip. All counts are in the report.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from cam import CheckCancel, GeometryError, Progress
from cam.denoise.noise import estimate_noise
from cam.denoise.tgv import FaceTopology, TGVResult, face_topology, tgv_filter_normals
from cam.denoise.vertices import fill_degenerate_normals, unit_rows, update_vertices
from cam.denoise.weights import Weights, weights_for_noise
from cam.mesh.rows import unique_pairs
from cam.params import DenoiseParams

__all__ = ["DenoiseResult", "denoise_mesh"]


@dataclass(frozen=True)
class DenoiseResult:
    """A denoised mesh: same faces, moved vertices."""

    vertices: np.ndarray  # (n, 3) float64, input units
    face_normals: np.ndarray  # (m, 3) float64, filtered unit normals
    iterations: int  # outer iterations of the normal filter
    report: dict = field(default_factory=dict)  # plain JSON types only


_DEGENERATE_REL_AREA = 1e-12  # faces with area below this (in mean edge lengths squared) are degenerate


def denoise_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    params: DenoiseParams = DenoiseParams(),
    *,
    progress: Progress | None = None,
    check_cancel: CheckCancel | None = None,
    processes: int = 1,
) -> DenoiseResult:
    """Denoise a triangle mesh with MeshTGV normal filtering and the iterative vertex update.

    Every parameter of ``params`` is dimensionless: the mesh is first expressed in units of its
    mean edge length, so the result does not depend on the input's scale, position or
    orientation. ``params.enabled`` is not read here (the stage skips a disabled denoise).

    Parameters
    ----------
    vertices : ndarray, shape (n >= 3, 3), real dtype
        Finite coordinates, any unit.
    faces : ndarray, shape (m >= 1, 3), integer dtype
        Triangles, indices into ``vertices``.
    params : DenoiseParams
        alpha0: weight of the second-order TGV term (jumps of the auxiliary gradient field across
        edges, gradients per mean edge length, each jump weighted by its edge length in mean edge
        lengths). Larger: the auxiliary field is dearer and the filter behaves more like plain TV
        (crisper creases, curved parts drift towards facets); smaller: ramps replace creases.
        None (default): chosen from the measured noise, as alpha1.
        alpha1: weight of the first-order TGV term (jump of the normal across each edge, minus the
        jump the auxiliary field predicts, weighted by edge length in mean edge lengths), relative to
        the area-weighted fidelity (areas in mean edge lengths squared). Larger: stronger denoising.
        None (default): chosen by :func:`cam.denoise.weights.weights_for_noise` from the noise
        :func:`cam.denoise.noise.estimate_noise` measures on the input (its level and how correlated
        it is from vertex to vertex). A weight given by hand is used as given.
        penalty0, penalty1: augmented-Lagrangian penalties of the two split variables (same units
        as alpha0, alpha1). They fix the linear systems, which are factored once.
        vertex_iterations: iterations of the vertex update. None (default): chosen with the weights
        (:func:`cam.denoise.weights.weights_for_noise`: 20 for white noise, up to 300 for correlated).
        flip_repair_rounds: rounds of the folded-face repair after the update (0: paper's update only).
        max_iterations: cap on the outer iterations of the normal filter.
        tolerance: stop when |N_k - N_{k-1}| / |N_{k-1}| (Frobenius norms) falls below it.
        noise_reference_deg: only for weights set by hand, the earlier noise adaptation: each is
        multiplied by min(1, median dihedral angle of the input / noise_reference_deg). 0
        (default): used as given. Jobs stored before the automatic choice carry alpha0=0.15,
        alpha1=0.4, noise_reference_deg=15 and get the results they got then.
    progress : callable, optional
        ``progress(fraction, message)``, called once per outer iteration (fractions rise through
        [0, 0.9)) and once at the end with 1.0.
    check_cancel : callable, optional
        Called once before the filter, once per outer iteration and once per vertex iteration; it
        stops the work by raising (the exception passes through untouched).
    processes : int
        Processors the filter may use (`cam.denoise.tgv.tgv_filter_normals`); the result is the same
        with any number.

    Returns
    -------
    DenoiseResult
        ``vertices`` float64 (n, 3) in the input's units and frame, ``face_normals`` float64
        (m, 3) filtered unit normals, the filter's ``iterations`` and a JSON-ready ``report``
        (iterations, timings in s, parameters, scaling, mesh counts, folded faces, warnings).

    Raises
    ------
    GeometryError
        When no face has a non-zero area.
    ValueError
        For arrays of the wrong shape or dtype, non-finite coordinates or indices out of range.
    """
    t0 = time.perf_counter()
    check_cancel = check_cancel or _no_cancel
    v_in, f_in = _check_mesh(vertices, faces)
    check_cancel()
    frame = _normalise(v_in, f_in)
    topo = face_topology(frame.faces, len(v_in))
    median_dihedral = _median_dihedral_deg(frame.x, frame.faces, topo)
    weight_scale = _noise_weight_scale(median_dihedral, params.noise_reference_deg)
    t_noise = time.perf_counter()
    noise = estimate_noise(frame.x, frame.faces)
    t_noise = time.perf_counter() - t_noise
    check_cancel()
    auto = weights_for_noise(noise)
    alpha0, alpha1 = _weights_used(params, auto, weight_scale)
    tgv = _filter_normals(frame, topo, params, alpha0, alpha1, progress=progress, check_cancel=check_cancel,
                          processes=processes)
    t_vu = time.perf_counter()
    iterations = _vertex_iterations_used(params, auto)
    x_new, flips_before, flips_after = update_vertices(frame.x, frame.faces, tgv.normals, iterations,
                                                       params.flip_repair_rounds, check_cancel=check_cancel)
    t_vu_end = time.perf_counter()
    face_normals, no_normal = _all_face_normals(tgv.normals, f_in, frame)
    out = _to_input_frame(x_new, v_in, frame)
    sliver = _sliver_fraction(frame.x, frame.faces)
    warnings = _warnings(tgv, params, sliver, flips_after)
    if progress is not None:
        progress(1.0, "denoising done")
    timings = _timings(tgv, noise_estimate=t_noise, vertex_update=t_vu_end - t_vu, total=time.perf_counter() - t0)
    report = {
        "iterations": int(tgv.iterations),
        "converged": bool(tgv.converged),
        "final_relative_change": float(tgv.relative_change),
        "time_s": timings,
        "parameters": {k: (None if v is None else int(v) if isinstance(v, (int, np.integer)) else float(v))
                       for k, v in params.model_dump(exclude={"enabled"}).items()},
        "noise": noise.as_report(),
        "weights": _weights_report(params, auto, alpha0, alpha1),
        "scaling": _scaling_report(frame, alpha0, alpha1, median_dihedral, weight_scale),
        "mesh": _mesh_report(frame, topo, tgv, no_normal),
        "folded_faces": {"after_update": int(flips_before), "after_repair": int(flips_after)},
        "sliver_face_fraction": float(sliver),
        "warnings": warnings,
    }
    return DenoiseResult(vertices=out, face_normals=face_normals, iterations=int(tgv.iterations),
                         report=report)


@dataclass(frozen=True)
class _Frame:
    """The valid faces and the scale- and translation-free positions the filter works on."""

    valid: np.ndarray  # (m,) bool, faces of non-zero area
    faces: np.ndarray  # (k, 3) int64, the valid faces
    x: np.ndarray  # (n, 3) float64, (vertices - center) / ell
    ell: float  # mean edge length of the valid faces, input units
    center: np.ndarray  # (3,) mean of the vertices of valid faces, input units


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


def _normalise(v_in: np.ndarray, f_in: np.ndarray) -> _Frame:
    # A first length unit from the faces with three distinct vertices decides which faces have
    # zero area; the unit and the centre used from then on come from the valid faces alone, so
    # adding or removing degenerate faces does not change the result on the others.
    m = len(f_in)
    repeated = (f_in[:, 0] == f_in[:, 1]) | (f_in[:, 1] == f_in[:, 2]) | (f_in[:, 2] == f_in[:, 0])
    ell0 = _mean_edge_length(v_in, f_in[~repeated])
    if not np.isfinite(ell0) or ell0 <= 0.0:
        raise GeometryError(f"all {m} faces are degenerate (no face has an edge of non-zero length)")
    cross = np.cross(v_in[f_in[:, 1]] - v_in[f_in[:, 0]], v_in[f_in[:, 2]] - v_in[f_in[:, 0]])
    area0 = 0.5 * np.linalg.norm(cross, axis=1) / (ell0 * ell0)
    valid = ~repeated & (area0 > _DEGENERATE_REL_AREA)
    if not valid.any():
        raise GeometryError(f"all {m} faces are degenerate (zero area)")
    vf = f_in[valid]
    ell = _mean_edge_length(v_in, vf)
    center = v_in[np.unique(vf)].mean(axis=0)
    return _Frame(valid=valid, faces=vf, x=(v_in - center) / ell, ell=ell, center=center)


def _weights_used(params: DenoiseParams, auto: Weights, hand_scale: float) -> tuple[float, float]:
    # A weight the user set is theirs (scaled only by the noise_reference_deg they may have set);
    # an unset one is the automatic choice.
    alpha0 = auto.alpha0 if params.alpha0 is None else params.alpha0 * hand_scale
    alpha1 = auto.alpha1 if params.alpha1 is None else params.alpha1 * hand_scale
    return float(alpha0), float(alpha1)


def _vertex_iterations_used(params: DenoiseParams, auto: Weights) -> int:
    """The user's count where set, else the one chosen for the noise."""
    return auto.vertex_iterations if params.vertex_iterations is None else int(params.vertex_iterations)


def _weights_report(params: DenoiseParams, auto: Weights, alpha0: float, alpha1: float) -> dict:
    return {
        "alpha0": alpha0,
        "alpha1": alpha1,
        "alpha0_from": "noise" if params.alpha0 is None else "parameter",
        "alpha1_from": "noise" if params.alpha1 is None else "parameter",
        "vertex_iterations": _vertex_iterations_used(params, auto),
        "vertex_iterations_from": "noise" if params.vertex_iterations is None else "parameter",
        "for_the_noise": auto.as_report(),
    }


def _noise_weight_scale(median_dihedral_deg: float, noise_reference_deg: float) -> float:
    if noise_reference_deg > 0:
        return min(1.0, median_dihedral_deg / noise_reference_deg)
    return 1.0


def _filter_normals(frame: _Frame, topo: FaceTopology, params: DenoiseParams, alpha0: float, alpha1: float, *,
                    progress: Progress | None, check_cancel: CheckCancel, processes: int) -> TGVResult:
    def on_iteration(k: int, rel: float) -> None:
        if progress is not None:
            progress(0.9 * k / (params.max_iterations + 1),
                     f"normal filtering: iteration {k}, relative change {rel:.3g}")

    return tgv_filter_normals(
        frame.x, frame.faces, topo,
        alpha0=alpha0, alpha1=alpha1,
        r0=params.penalty0, r1=params.penalty1,
        max_iterations=params.max_iterations, tolerance=params.tolerance,
        on_iteration=on_iteration, check_cancel=check_cancel, processes=processes,
    )


def _all_face_normals(normals_valid: np.ndarray, f_in: np.ndarray, frame: _Frame) -> tuple[np.ndarray, int]:
    """Normals of every input face, and how many degenerate faces got none."""
    face_normals = np.zeros((len(f_in), 3))
    face_normals[frame.valid] = normals_valid
    if frame.valid.all():
        return face_normals, 0
    return face_normals, fill_degenerate_normals(face_normals, f_in, frame.valid, frame.x.shape[0])


def _to_input_frame(x_new: np.ndarray, v_in: np.ndarray, frame: _Frame) -> np.ndarray:
    # Vertices no valid face uses keep their input position bit for bit.
    out = v_in.copy()
    moved = np.zeros(len(v_in), dtype=bool)
    moved[np.unique(frame.faces)] = True
    out[moved] = x_new[moved] * frame.ell + frame.center
    if not np.all(np.isfinite(out)):  # cannot happen for valid input; never hand back garbage
        raise ValueError("denoising produced non-finite coordinates")
    return out


def _warnings(tgv: TGVResult, params: DenoiseParams, sliver: float, flips_after: int) -> list[str]:
    warnings = []
    if not tgv.converged:
        warnings.append(f"normal filtering stopped at max_iterations={params.max_iterations} with "
                        f"relative change {tgv.relative_change:.3g} (tolerance {params.tolerance:g})")
    if sliver > 0.1:
        warnings.append(f"{100 * sliver:.0f}% of the faces are slivers (longest edge > 10x the height "
                        "on it); the filter over-smooths such meshes, remesh first or lower alpha1")
    if flips_after:
        warnings.append(f"{flips_after} faces remain folded over (normal against the filtered one)")
    return warnings


def _timings(tgv: TGVResult, *, noise_estimate: float, vertex_update: float, total: float) -> dict[str, float]:
    return {
        "noise_estimate": round(noise_estimate, 6),
        "setup": round(tgv.setup_seconds, 6),
        "factorization": round(tgv.factor_seconds, 6),
        "normal_iterations": round(tgv.iterate_seconds, 6),
        "vertex_update": round(vertex_update, 6),
        "total": round(total, 6),
    }


def _scaling_report(frame: _Frame, alpha0_used: float, alpha1_used: float, median_dihedral: float,
                    weight_scale: float) -> dict:
    return {
        "length_unit": "mean edge length",
        "mean_edge_length": float(frame.ell),
        "center": [float(c) for c in frame.center],
        "median_dihedral_deg": float(median_dihedral),
        "noise_weight_scale": float(weight_scale),  # applies to hand-set weights only
        "alpha0_used": float(alpha0_used),
        "alpha1_used": float(alpha1_used),
        # the same energy written in the input's units (areas and lengths not rescaled)
        "alpha1_used_input_units": float(alpha1_used * frame.ell),
        "alpha0_used_input_units": float(alpha0_used * frame.ell * frame.ell),
    }


def _mesh_report(frame: _Frame, topo: FaceTopology, tgv: TGVResult, no_normal: int) -> dict:
    m = len(frame.valid)
    return {
        "vertices": len(frame.x),
        "faces": int(m),
        "degenerate_faces": int(m - frame.valid.sum()),
        "degenerate_faces_without_normal": int(no_normal),
        "interior_edges": int(tgv.n_edges),
        "boundary_edges": int(topo.n_boundary_edges),
        "nonmanifold_edges": int(topo.n_nonmanifold_edges),
        "inconsistently_oriented_edges": int(topo.n_flipped_edges),
    }


def _mean_edge_length(v: np.ndarray, f: np.ndarray) -> float:
    if len(f) == 0:
        return 0.0
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = unique_pairs(np.sort(e, axis=1))
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    length = length[length > 0]
    return float(length.mean()) if len(length) else 0.0


def _median_dihedral_deg(x: np.ndarray, f: np.ndarray, topo: FaceTopology) -> float:
    """Median angle between the normals of the two faces on each interior edge, in degrees."""
    if len(topo.edge_faces) == 0:
        return 0.0
    n = unit_rows(np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]))
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


def _no_cancel() -> None:
    pass
