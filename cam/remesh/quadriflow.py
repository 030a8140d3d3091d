"""The remesh stage's entry point, `remesh_quads`: the crease-first layout (`cam.remesh.layout`), or QuadriFlow
where that cannot be made or is not asked for: several runs, each checked, and the one that follows the creases best.

QuadriFlow runs in a child process with a timeout (:mod:`cam.remesh.process`),
because on rare inputs it loops forever; a timeout, a crash or a result that
fails the checks (:mod:`cam.remesh.accept`) is retried with the next seed, and
when no attempt gives a usable quad mesh, :class:`RemeshFailed` (a
:class:`cam.GeometryError`) says why each failed. How many of the input's
creases QuadriFlow's edges follow depends on its seed, so several results that
pass are compared and the one that follows most of them is kept
(:mod:`cam.remesh.creases`). Closeness is reported as a two-sided Hausdorff
distance.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cam import CheckCancel, GeometryError, Progress, progress_between
from cam.mesh.closest import MeshIndex, mesh_index
from cam.mesh.rows import unique_pairs
from cam.params import RemeshParams, SegmentParams
from cam.remesh.accept import accept_quads, hausdorff_to_mesh
from cam.remesh.check import inspect_quad_mesh
from cam.remesh.creases import measure_crease_conformity, measure_crease_following
from cam.remesh.layout import crease_first_layout
from cam.remesh.process import QuadriflowFailed, QuadriflowRuns
from cam.remesh.snap import snap_to_creases

__all__ = ["RemeshFailed", "RemeshResult", "boundary_loop_count", "remesh_quads"]

# Face-count nudges of attempt i, once a run has failed (QuadriFlow's holes and hangs depend on the exact sampling).
_TARGET_NUDGE = (0.0, -0.04, 0.04, -0.08, 0.08)
# Creases of the report's recall and straddling quads: segment's default θ, since its sharp edges are what
# patch borders must follow.
_SHARP_ANGLE_DEG = SegmentParams.model_fields["sharp_angle_deg"].default


class RemeshFailed(GeometryError):
    """No attempt gave a usable quad mesh; the message lists each attempt's seed, face count and reason,
    and names the parameters to change."""


@dataclass(frozen=True, eq=False)
class RemeshResult:
    """A checked quad mesh on the input surface.

    Attributes
    ----------
    vertices
        float64 (n, 3), mm, each on the input surface.
    faces
        int64 (m, 4) vertex indices, counter-clockwise seen from outside like the input.
    report
        JSON-ready facts: seed used, attempts and why earlier ones failed,
        repairs, the check report, Hausdorff and mean distances (mm and as a
        fraction of the input's bounding-box diagonal), timings (s).
    """

    vertices: np.ndarray
    faces: np.ndarray
    report: dict


class _Input(NamedTuple):
    """The checked triangle mesh and what every attempt compares against."""

    vertices: np.ndarray  # float64 (n, 3), mm
    triangles: np.ndarray  # int64 (m, 3)
    boundary_loops: int
    diagonal_mm: float
    index: MeshIndex | None = None  # its closest-point index, built once when layouts are snapped or made crease-first


def boundary_loop_count(triangles: np.ndarray, n_vertices: int) -> int:
    """Number of boundary loops of a triangle mesh.

    Parameters
    ----------
    triangles
        int (m, 3) vertex indices.
    n_vertices
        Number of vertices the indices refer to.

    Returns
    -------
    int
        Connected chains of edges that have one triangle only (0 for a closed surface).
    """
    tris = np.asarray(triangles, dtype=np.int64)
    e = np.sort(np.stack([tris, np.roll(tris, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    keys, counts = np.unique(e[:, 0] * n_vertices + e[:, 1], return_counts=True)
    boundary = keys[counts == 1]
    if not len(boundary):
        return 0
    a, b = boundary // n_vertices, boundary % n_vertices
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return len(np.unique(labels[np.r_[a, b]]))


def remesh_quads(
    vertices: np.ndarray,
    faces: np.ndarray,
    params: RemeshParams = RemeshParams(),
    *,
    progress: Progress | None = None,
    check_cancel: CheckCancel | None = None,
    crease_angle_deg: float = _SHARP_ANGLE_DEG,
    processes: int = 1,
) -> RemeshResult:
    """Remesh a triangle mesh into a checked, feature-aligned quad mesh.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    faces
        int (m, 3) vertex indices of triangles, counter-clockwise seen from outside.
    params
        The remesh group:

        - ``layout``: ``"creases"`` makes the crease-first layout (:func:`cam.remesh.layout.crease_first_layout`,
          its coarse edges ``coarse_quads`` quads long), checked like a QuadriFlow run; where the mesh has
          boundary loops, or the layout fails its checks (also with coarse edges a half and a third as long),
          QuadriFlow makes the layout as below and the report's
          ``layout_fallback`` says why. ``"quadriflow"``: QuadriFlow only. The report's ``layout`` says which.
        - ``target_faces``: quads to aim for.
        - ``seed``: seed of the first attempt; attempt ``i`` uses ``seed + i``. Once a run
          has failed, later ones also take a face count a few percent off the
          target (QuadriFlow's rare hangs and holes depend on the exact sampling);
          until then every run is at the target, so the layouts compared are of
          one density.
        - ``attempts``: most QuadriFlow runs. When none passed and some failed on
          odd holes that cannot be paired, one more run at a quarter of the
          faces fills them and splits every face into four quads
          (:func:`cam.remesh.holes.split_into_quads`); the report says ``"split": true``.
        - ``candidates``: runs that pass the checks to compare: attempts stop once this many
          passed, and of those the one whose edges follow the most crease length
          of the input is kept (the nearer one, by Hausdorff distance, on a tie).
          The report lists them under ``"candidates"`` (seed, QuadriFlow's target, faces,
          missed crease length, Hausdorff distance).
        - ``timeout_s``: limit of one run, seconds; once a run has given a mesh in t seconds, later runs that
          take over max(15 s, 4 t) are taken to hang and stopped; until one has, once every run going has run
          60 s, the run that would follow a failure starts beside them, so that two runs hanging side by side
          do not wait out the limit (see `cam.remesh.process.QuadriflowRuns`).
        - ``preserve_sharp``: align quads with sharp features (QuadriFlow's ``-sharp``).
        - ``min_cost_flow``: QuadriFlow's ``-mcf`` (slower, sometimes fewer singularities).
        - ``max_hausdorff_ratio``: largest accepted two-sided Hausdorff distance as a
          fraction of the input's bounding-box diagonal.
        - ``snap_creases``: move each passing layout's vertices so that its edges run along the creases
          (:func:`cam.remesh.snap.snap_to_creases`), collapsing the quads a crease crosses from corner to
          corner, before the candidates are compared; the report's ``snap`` says what was snapped, what not
          and why, the quads collapsed, and the recall and straddling quads before. The distances, check and
          crease measures in the report are the snapped layout's.
    progress
        ``progress(fraction, message)`` before each run and before its checks.
    check_cancel
        Called about four times a second while QuadriFlow runs (see :class:`cam.remesh.process.QuadriflowRuns`);
        what it raises kills the child and propagates.
    crease_angle_deg
        Creases (normals over this many degrees apart) of the kept layout's report: ``crease_recall`` (the
        share of their length that quad edges follow within 0.2 % of the bounding-box diagonal) and
        ``straddling_quads`` (see :func:`cam.remesh.creases.measure_crease_conformity`). Measured, not used
        to choose: the choice above stays on ``missed_crease_mm``. Default: ``segment.sharp_angle_deg``'s.
    processes
        QuadriFlow runs at once: the runs that would follow if the current one passed start beside it
        (each in its own child process), and are killed when they are not wanted after all. The runs made
        and the layout kept are those of one run at a time.

    Returns
    -------
    RemeshResult
        ``vertices`` float64 (n', 3) mm on the input surface, ``faces`` int64 (m', 4) vertex indices
        oriented like the input, and the ``report``.

    Raises
    ------
    ValueError
        For malformed arrays (shape, dtype, index range, non-finite coordinates), naming what was seen.
    GeometryError
        When the mesh has zero extent.
    RemeshFailed
        When every attempt failed: the message lists each attempt's seed and reason.
    """
    mesh = _prepare_input(vertices, faces)
    fallback = None
    if params.layout == "creases":
        if mesh.boundary_loops:
            fallback = (f"the mesh has {mesh.boundary_loops} boundary loop(s) and the crease-first layout needs a "
                        "closed part")
        else:
            try:
                return _crease_first(mesh, params, progress=progress, check_cancel=check_cancel,
                                     crease_angle_deg=crease_angle_deg)
            except ValueError as exc:  # GeometryError too: the reason is reported, QuadriFlow makes the layout
                fallback = f"the crease-first layout failed: {exc}"
        if progress is not None:
            progress(0.0, "QuadriFlow, since " + fallback)
    if params.snap_creases:
        mesh = mesh._replace(index=mesh_index(mesh.vertices, mesh.triangles))
    accepted, failures, runs = _run_attempts(mesh, params, processes=processes, progress=progress,
                                             check_cancel=check_cancel, crease_angle_deg=crease_angle_deg)
    if not accepted:
        raise RemeshFailed(f"QuadriFlow gave no usable quad mesh in {len(failures)} attempt(s): "
                           + "; ".join(failures) + ". Try another remesh.target_faces or remesh.seed")
    best = _keep_best(accepted, failures, runs)
    started = time.monotonic()
    conformity = measure_crease_conformity(best.vertices, best.faces, mesh.vertices, mesh.triangles,
                                           crease_angle_deg=crease_angle_deg)
    best.report.update(conformity.as_dict(), conformity_s=time.monotonic() - started, layout="quadriflow")
    if fallback is not None:
        best.report["layout_fallback"] = fallback
    return best


def _crease_first(mesh: _Input, params: RemeshParams, *, progress: Progress | None,
                  check_cancel: CheckCancel | None, crease_angle_deg: float) -> RemeshResult:
    """The crease-first layout (`cam.remesh.layout`), checked like a QuadriFlow run, with its report; where it
    fails its checks, again with coarse edges a half and then a third as long (finer coarse faces follow bends
    the longer ones cut across); ValueError saying why each was not usable."""
    failures = []
    if mesh.index is None:  # built once for every try
        mesh = mesh._replace(index=mesh_index(mesh.vertices, mesh.triangles))
    for coarse_quads in (params.coarse_quads, params.coarse_quads / 2, params.coarse_quads / 3):
        try:
            result = _checked_layout(mesh, params, coarse_quads, progress=progress, check_cancel=check_cancel,
                                     crease_angle_deg=crease_angle_deg)
        except ValueError as exc:
            failures.append(f"with coarse edges of {coarse_quads:g} quads, {exc}")
            continue
        result.report["failed_attempts"] = failures
        return result
    raise ValueError("; ".join(failures))


def _checked_layout(mesh: _Input, params: RemeshParams, coarse_quads: float, *, progress: Progress | None,
                    check_cancel: CheckCancel | None, crease_angle_deg: float) -> RemeshResult:
    """One crease-first layout with coarse edges ``coarse_quads`` quads long and its report; ValueError naming what
    its checks found (a defect, or too far from the input)."""
    started = time.monotonic()
    layout, facts = crease_first_layout(mesh.vertices, mesh.triangles, target_faces=params.target_faces,
                                        crease_angle_deg=crease_angle_deg, coarse_quads=coarse_quads,
                                        progress=progress_between(progress, 0.0, 0.9), check_cancel=check_cancel)
    check = inspect_quad_mesh(layout.vertices, layout.quads, expected_boundary_loops=0)
    if check.problems:
        raise ValueError("; ".join(check.problems))
    if progress is not None:
        progress(0.9, "measuring the layout")
    hausdorff, mean = hausdorff_to_mesh(layout.vertices, layout.quads, mesh.index)
    if hausdorff > params.max_hausdorff_ratio * mesh.diagonal_mm:
        raise ValueError(f"it lies {hausdorff:.3g} mm from the input at worst ({hausdorff / mesh.diagonal_mm:.1%} "
                         f"of the diagonal, limit {params.max_hausdorff_ratio:.1%})")
    following = measure_crease_following(layout.vertices, layout.quads, mesh.vertices, mesh.triangles)
    conformity = measure_crease_conformity(layout.vertices, layout.quads, mesh.vertices, mesh.triangles,
                                           crease_angle_deg=crease_angle_deg)
    report = {**facts, "target_faces": int(params.target_faces), "faces": len(layout.quads),
              "vertices": len(layout.vertices), "input_triangles": len(mesh.triangles), "input_boundary_loops": 0,
              "check": check.as_dict(), "hausdorff_mm": hausdorff, "hausdorff_ratio": hausdorff / mesh.diagonal_mm,
              "mean_distance_mm": mean, **following.as_dict(), **conformity.as_dict(),
              "total_s": time.monotonic() - started}
    return RemeshResult(vertices=layout.vertices, faces=layout.quads, report=report)


def _snap(vertices: np.ndarray, faces: np.ndarray, mesh: _Input, facts: dict, crease_angle_deg: float
          ) -> tuple[np.ndarray, np.ndarray, dict]:
    """A layout with its edges on the creases (`cam.remesh.snap`: vertices, and quads less those it collapsed),
    and its facts with the distances and the check anew and ``snap`` (what was snapped and what not, the
    recall, straddling quads and extraordinary vertices before)."""
    started = time.monotonic()
    before = measure_crease_conformity(vertices, faces, mesh.vertices, mesh.triangles,
                                       crease_angle_deg=crease_angle_deg)
    snapped = snap_to_creases(vertices, faces, mesh.vertices, mesh.triangles, crease_angle_deg=crease_angle_deg,
                              index=mesh.index)
    hausdorff, mean = hausdorff_to_mesh(snapped.vertices, snapped.quads, mesh.index)
    check = inspect_quad_mesh(snapped.vertices, snapped.quads, expected_boundary_loops=mesh.boundary_loops)
    return snapped.vertices, snapped.quads, {
        **facts, "check": check.as_dict(), "hausdorff_mm": hausdorff, "hausdorff_ratio": hausdorff / mesh.diagonal_mm,
        "mean_distance_mm": mean, "snap_s": time.monotonic() - started,
        "snap": {**snapped.report, "crease_recall_before": before.recall,
                 "straddling_quads_before": len(before.straddling),
                 "extraordinary_vertices_before": facts["check"]["extraordinary_vertices"]}}


def _prepare_input(vertices: np.ndarray, faces: np.ndarray) -> _Input:
    """Check the arrays and measure what every attempt needs; ValueError or GeometryError as remesh_quads says."""
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(faces)
    if verts.ndim != 2 or verts.shape[1] != 3 or not np.isfinite(verts).all():
        raise ValueError(f"vertices must be a finite (n, 3) array, got shape {verts.shape}")
    if tris.ndim != 2 or tris.shape[1] != 3 or len(tris) == 0 or tris.dtype.kind not in "iu":
        raise ValueError(f"triangles must be a non-empty (m, 3) integer array, got shape {tris.shape} dtype {tris.dtype}")
    tris = tris.astype(np.int64)
    if tris.min() < 0 or tris.max() >= len(verts):
        raise ValueError(f"triangles index vertices {tris.min()}..{tris.max()} but there are {len(verts)}")
    diag = float(np.linalg.norm(np.ptp(verts[np.unique(tris)], axis=0)))
    if diag <= 0:
        raise GeometryError("the mesh has zero extent")
    _check_manifold(tris)
    return _Input(verts, tris, boundary_loop_count(tris, len(verts)), diag)


def _check_manifold(tris: np.ndarray) -> None:
    """GeometryError naming the edges that no quad layout can follow: an edge of more than two triangles, or
    one that two triangles run the same way (their orientations disagree). QuadriFlow takes such a mesh
    without complaint and makes a layout of the wrong surface."""
    directed = np.stack([tris, np.roll(tris, -1, axis=1)], axis=2).reshape(-1, 2)
    _, shared = unique_pairs(np.sort(directed, axis=1), return_counts=True)
    _, same_way = unique_pairs(directed, return_counts=True)
    crowded, flipped = int((shared > 2).sum()), int((same_way > 1).sum())
    if crowded or flipped:
        raise GeometryError(f"the mesh is not a manifold surface: {crowded} edge(s) shared by more than two "
                            f"triangles, {flipped} edge(s) that two triangles run the same way (inconsistent "
                            "orientation); repair the mesh (or upload the cloud) and try again")


def _run_attempts(mesh: _Input, params: RemeshParams, *, processes: int, progress: Progress | None,
                  check_cancel: CheckCancel | None, crease_angle_deg: float
                  ) -> tuple[list[RemeshResult], list[str], int]:
    """Run QuadriFlow until ``params.candidates`` results passed or the attempts are spent.

    With ``processes`` > 1 the runs that would follow if this one passed run beside it (`QuadriflowRuns`);
    which runs are made, and their results, are those of one run at a time (unless a run's time falls
    between the hang limits the two measure: see `QuadriflowRuns`).

    Returns the results that passed, a sentence per failed run, and how many runs were made.
    """
    failures: list[str] = []
    accepted: list[RemeshResult] = []
    runs = 0
    pool = QuadriflowRuns(mesh.vertices, mesh.triangles, preserve_sharp=params.preserve_sharp,
                          preserve_boundary=mesh.boundary_loops > 0, min_cost_flow=params.min_cost_flow,
                          timeout_s=params.timeout_s, processes=processes)

    def upcoming(first: int, wanted: int) -> list[tuple[int, int]]:
        # (target, seed) of the plain attempts from `first` on, while `wanted` more may pass, as now predicted.
        last = min(params.attempts, first + max(wanted, 0))
        return [_seed_and_target(params, a, after_failure=bool(failures), split=False)[::-1]
                for a in range(first, last)]

    try:
        # After the plain attempts, one more at a quarter of the faces may split every face into quads to close
        # odd holes that cannot be paired (QuadriFlow leaves them on some marching-cubes meshes).
        for attempt in range(params.attempts + 1):
            split = attempt == params.attempts
            if split and (accepted or not any("odd holes" in f for f in failures)):
                break
            runs = attempt + 1
            seed, target = _seed_and_target(params, attempt, after_failure=bool(failures), split=split)
            if progress is not None:
                progress(attempt / (params.attempts + 1), f"QuadriFlow, seed {seed}")
            following = [] if split else upcoming(attempt + 1, params.candidates - len(accepted) - 1)
            # should this run fail (hang), the next one takes a nudged count
            spare = (None if split or attempt + 1 >= params.attempts
                     else _seed_and_target(params, attempt + 1, after_failure=True, split=False)[::-1])
            try:
                raw_v, raw_f, quadriflow_s, started = _quadriflow(pool, (target, seed), following, spare,
                                                                  check_cancel)
                if progress is not None:
                    progress((attempt + 0.8) / (params.attempts + 1), "checking the quads")
                out_v, out_f, facts = accept_quads(raw_v, raw_f, mesh.vertices, mesh.triangles,
                                                   boundary_loops=mesh.boundary_loops, diagonal_mm=mesh.diagonal_mm,
                                                   max_hausdorff_ratio=params.max_hausdorff_ratio,
                                                   split_unpaired=split)
            except (QuadriflowFailed, ValueError) as exc:
                failures.append(f"seed {seed}, {target} faces: {exc}")
                continue
            accepted.append(_measure_candidate(mesh, params, out_v, out_f, facts, seed=seed, runs=attempt + 1,
                                               target=target, quadriflow_s=quadriflow_s, started=started,
                                               crease_angle_deg=crease_angle_deg))
            if len(accepted) >= params.candidates:
                break
    finally:
        pool.close()
    return accepted, failures, runs


def _quadriflow(pool: QuadriflowRuns, key: tuple[int, int], following: list[tuple[int, int]],
                spare: tuple[int, int] | None, check_cancel: CheckCancel | None
                ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The run of key (target, seed): vertices, faces, seconds and start on `time.monotonic`; the `following`
    runs (those wanted should this one pass) run beside it while the pool has room, and the `spare` (the one
    wanted should it fail) once the runs stall (`QuadriflowRuns`). QuadriflowFailed as raised."""
    pool.plan([key, *following], spare)
    result = pool.result(key, check_cancel=check_cancel)
    pool.plan(following, spare)  # while this result is checked
    return result


def _seed_and_target(params: RemeshParams, attempt: int, *, after_failure: bool, split: bool) -> tuple[int, int]:
    """QuadriFlow's seed and face target for attempt ``attempt`` (see remesh_quads' ``seed`` and ``attempts``)."""
    if split:
        return params.seed, max(1, round(params.target_faces / 4))
    if after_failure:
        nudge = _TARGET_NUDGE[attempt % len(_TARGET_NUDGE)]
        return params.seed + attempt, max(1, round(params.target_faces * (1.0 + nudge)))
    return params.seed + attempt, int(params.target_faces)


def _measure_candidate(mesh: _Input, params: RemeshParams, out_v: np.ndarray, out_f: np.ndarray, facts: dict, *,
                       seed: int, runs: int, target: int, quadriflow_s: float, started: float,
                       crease_angle_deg: float) -> RemeshResult:
    """A result that passed, snapped onto the creases when ``params.snap_creases``, with its report: the run's
    facts, the checks' and how much crease it follows (snapped: the candidates are compared as they would be
    kept).

    ``runs`` counts the runs so far, this one included; ``started`` is the run's start on ``time.monotonic``.
    """
    if params.snap_creases:
        out_v, out_f, facts = _snap(out_v, out_f, mesh, facts, crease_angle_deg)
    creases = measure_crease_following(out_v, out_f, mesh.vertices, mesh.triangles)
    report = {
        "seed": seed, "attempts": runs, "quadriflow_target_faces": target,
        "split": any("split every face" in r for r in facts["repairs"]),
        "target_faces": int(params.target_faces), "faces": len(out_f), "vertices": len(out_v),
        "input_triangles": len(mesh.triangles), "input_boundary_loops": mesh.boundary_loops,
        "quadriflow_s": quadriflow_s, "total_s": time.monotonic() - started, **facts, **creases.as_dict(),
    }
    return RemeshResult(vertices=out_v, faces=out_f, report=report)


def _keep_best(accepted: list[RemeshResult], failures: list[str], runs: int) -> RemeshResult:
    """The layout whose edges follow most of the input's creases (the closer one on a tie), its report
    completed with every run made, the failed ones and the candidates compared."""
    best = min(accepted, key=lambda r: (r.report["missed_crease_mm"], r.report["hausdorff_mm"]))
    best.report["attempts"] = runs  # failed runs after the last that passed count too
    best.report["failed_attempts"] = failures
    keys = ("seed", "quadriflow_target_faces", "faces", "missed_crease_mm", "hausdorff_mm")
    best.report["candidates"] = [{key: r.report[key] for key in keys} for r in accepted]
    return best
