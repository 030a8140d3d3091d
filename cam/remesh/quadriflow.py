"""Quad remeshing with QuadriFlow, checked and brought back onto the input surface.

QuadriFlow (through ``pyQuadriFlow``) runs in a child process with a timeout,
because on rare inputs it loops forever; a timeout, a crash or a result that
fails the checks is retried with the next seed, and when no attempt gives a
usable quad mesh, :class:`RemeshFailed` (a :class:`cam.GeometryError`) says why
each failed. How many of the input's creases QuadriFlow's edges follow depends
on its seed, so several results that pass are compared and the one that follows
most of them is kept (:mod:`cam.remesh.creases`). A result is
repaired where that is small and safe (:mod:`cam.remesh.check`), oriented like
the input, and its vertices are projected onto the input triangles: QuadriFlow
works in single precision, and the projection restores double precision (and
puts every vertex on the input surface). Closeness is reported as a two-sided
Hausdorff distance.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cam import CheckCancel, GeometryError, Progress
from cam.mesh.closest import MeshIndex, closest_points, mesh_index
from cam.mesh.quads import face_areas, face_normals
from cam.params import RemeshParams
from cam.remesh.check import inspect_quad_mesh, repair_quad_mesh
from cam.remesh.creases import measure_crease_following

__all__ = ["QuadriflowFailed", "RemeshFailed", "RemeshResult", "boundary_loop_count", "remesh_quads",
           "run_quadriflow"]

# How often, s, the wait on the child wakes to check the deadline and cancellation.
_CHECK_EVERY_S = 0.25
# Face-count nudges of attempt i, once a run has failed (QuadriFlow's holes and hangs depend on the exact sampling).
_TARGET_NUDGE = (0.0, -0.04, 0.04, -0.08, 0.08)


class QuadriflowFailed(RuntimeError):
    """One QuadriFlow run gave no result (timeout, crash, error); the message says which.

    :func:`remesh_quads` catches it and tries the next seed; it reaches the user only as part of a
    :class:`RemeshFailed`.
    """


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
        int64 (m, 4), counter-clockwise seen from outside like the input.
    report
        JSON-ready facts: seed used, attempts and why earlier ones failed,
        repairs, the check report, Hausdorff and mean distances (mm and as a
        fraction of the input's bounding-box diagonal), timings.
    """

    vertices: np.ndarray
    faces: np.ndarray
    report: dict


def boundary_loop_count(triangles: np.ndarray, n_vertices: int) -> int:
    """Number of boundary loops of a triangle mesh (0 for a closed surface)."""
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


def run_quadriflow(
    vertices: np.ndarray,
    triangles: np.ndarray,
    *,
    target_faces: int,
    seed: int,
    preserve_sharp: bool = True,
    preserve_boundary: bool = False,
    min_cost_flow: bool = False,
    timeout_s: float = 600.0,
    check_cancel: CheckCancel | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run QuadriFlow once in a child process.

    Parameters
    ----------
    vertices, triangles
        The input: float (n, 3) mm and int (m, 3).
    target_faces
        Quads QuadriFlow aims for (it lands within a few tens of percent).
    seed
        QuadriFlow's random seed.
    preserve_sharp, preserve_boundary, min_cost_flow
        QuadriFlow's ``-sharp``, ``-boundary`` and ``-mcf`` switches.
    timeout_s
        Wall-clock limit; the child is killed after it.
    check_cancel
        Called about four times a second while the child runs; whatever it
        raises (the caller's cancellation) kills the child and propagates.

    Returns
    -------
    The raw result: vertices float64 (n', 3) (single-precision values) and
    faces int64 (m', 4).

    Raises
    ------
    QuadriflowFailed
        On timeout, a crash, an error reported by QuadriFlow or unreadable output.
    """
    buf = io.BytesIO()
    np.savez(buf, vertices=np.asarray(vertices, dtype=np.float64), faces=np.asarray(triangles, dtype=np.int64),
             target_faces=int(target_faces), seed=int(seed), preserve_sharp=bool(preserve_sharp),
             preserve_boundary=bool(preserve_boundary), min_cost_flow=bool(min_cost_flow),
             limit_s=float(timeout_s) + 30.0)
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    proc = subprocess.Popen([sys.executable, "-m", "cam.remesh.child"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    # communicate() in a thread: polling communicate(timeout=...) cannot resume sending stdin.
    result: dict[str, bytes] = {}

    def talk() -> None:
        result["out"], result["err"] = proc.communicate(input=buf.getvalue())

    talker = threading.Thread(target=talk, daemon=True)
    talker.start()
    deadline = time.monotonic() + timeout_s
    try:
        while talker.is_alive():
            # A time limit shorter than the check interval holds too.
            talker.join(max(0.0, min(_CHECK_EVERY_S, deadline - time.monotonic())))
            if not talker.is_alive():
                break
            if time.monotonic() > deadline:
                raise QuadriflowFailed(f"timed out after {timeout_s:.0f} s")
            if check_cancel is not None:
                check_cancel()
    finally:
        if proc.poll() is None:
            proc.kill()
        talker.join()
    out, err = result.get("out", b""), result.get("err", b"")
    message = err.decode("utf-8", errors="replace").strip().splitlines()
    tail = message[-1] if message else ""
    if proc.returncode == 3:
        raise QuadriflowFailed(f"QuadriFlow reported an error: {tail}")
    if proc.returncode != 0:
        raise QuadriflowFailed(f"QuadriFlow crashed (exit status {proc.returncode}){': ' + tail if tail else ''}")
    try:
        data = np.load(io.BytesIO(out))
        return data["vertices"], data["faces"]
    except Exception as exc:
        raise QuadriflowFailed(f"unreadable output from the QuadriFlow process ({exc})") from exc


def _hausdorff(verts: np.ndarray, quads: np.ndarray, index: MeshIndex) -> tuple[float, float]:
    """Two-sided Hausdorff and mean distance (mm) between a quad mesh and a triangle mesh, on dense samples."""
    p = verts[quads]
    samples = np.vstack([verts, p.mean(axis=1), 0.5 * (p + np.roll(p, -1, axis=1)).reshape(-1, 3)])
    d_fwd = closest_points(index, samples)[1]
    tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    in_verts, in_tris = index.vertices, index.faces
    back = np.vstack([in_verts[np.unique(in_tris)], in_verts[in_tris].mean(axis=1)])
    d_back = closest_points(mesh_index(verts, tris), back)[1]
    return float(max(d_fwd.max(), d_back.max())), float(0.5 * (d_fwd.mean() + d_back.mean()))


def _orient_like(verts: np.ndarray, quads: np.ndarray, index: MeshIndex) -> tuple[np.ndarray, bool]:
    """Flip all quads when their normals disagree with the input's at the closest points (area-weighted)."""
    tri = closest_points(index, verts[quads].mean(axis=1))[2]
    c = index.vertices[index.faces[tri]]
    tn = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-300)
    agreement = float((np.einsum("ij,ij->i", face_normals(verts, quads), tn) * face_areas(verts, quads)).sum())
    if agreement < 0:
        return quads[:, ::-1].copy(), True
    return quads, False


def _accept(raw_v: np.ndarray, raw_f: np.ndarray, in_verts: np.ndarray, in_tris: np.ndarray, loops: int,
            diag: float, max_hausdorff_ratio: float, split_unpaired: bool = False
            ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Repair, orient, project and check one QuadriFlow result; ValueError says why it is not acceptable."""
    if len(raw_f) == 0:
        raise ValueError("QuadriFlow returned no faces")
    if not np.isfinite(raw_v).all():
        raise ValueError("QuadriFlow returned non-finite coordinates")
    verts, quads, repairs = repair_quad_mesh(raw_v, raw_f, expected_boundary_loops=loops,
                                             split_unpaired=split_unpaired)
    index = mesh_index(in_verts, in_tris)
    quads, flipped = _orient_like(verts, quads, index)
    if flipped:
        repairs.append("reversed the faces to match the input's orientation")
    verts, dist = closest_points(index, verts)[:2]
    check = inspect_quad_mesh(verts, quads, expected_boundary_loops=loops)
    if check.problems:
        raise ValueError("; ".join(check.problems))
    hausdorff, mean = _hausdorff(verts, quads, index)
    if hausdorff > max_hausdorff_ratio * diag:
        raise ValueError(f"the quad mesh is {hausdorff:.3g} mm from the input at worst "
                         f"({hausdorff / diag:.1%} of the part's diagonal, limit {max_hausdorff_ratio:.1%}); "
                         "details smaller than the quads are lost: raise remesh.target_faces")
    return verts, quads, {
        "repairs": repairs, "check": check.as_dict(), "projection_max_mm": float(dist.max()),
        "hausdorff_mm": hausdorff, "hausdorff_ratio": hausdorff / diag, "mean_distance_mm": mean,
    }


def remesh_quads(
    vertices: np.ndarray,
    faces: np.ndarray,
    params: RemeshParams = RemeshParams(),
    *,
    progress: Progress | None = None,
    check_cancel: CheckCancel | None = None,
) -> RemeshResult:
    """Remesh a triangle mesh into a checked, feature-aligned quad mesh.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    faces
        int (m, 3) triangles, counter-clockwise seen from outside.
    params
        The remesh group:

        - ``target_faces``: quads to aim for.
        - ``seed``: seed of the first attempt; attempt ``i`` uses ``seed + i``. Once a run
          has failed, later ones also take a face count a few percent off the
          target (QuadriFlow's rare hangs and holes depend on the exact sampling);
          until then every run is at the target, so the layouts compared are of
          one density.
        - ``attempts``: most QuadriFlow runs. When none passed and some failed on
          triangular holes that cannot be paired, one more run at a quarter of the
          faces fills them and splits every face into four quads
          (:func:`cam.remesh.check.split_into_quads`); the report says ``"split": true``.
        - ``candidates``: runs that pass the checks to compare: attempts stop once this many
          passed, and of those the one whose edges follow the most crease length
          of the input is kept (the nearer one, by Hausdorff distance, on a tie).
          The report lists them under ``"candidates"`` (seed, QuadriFlow's target, faces,
          missed crease length, Hausdorff distance).
        - ``timeout_s``: limit of one run, seconds.
        - ``preserve_sharp``: align quads with sharp features (QuadriFlow's ``-sharp``).
        - ``min_cost_flow``: QuadriFlow's ``-mcf`` (slower, sometimes fewer singularities).
        - ``max_hausdorff_ratio``: largest accepted two-sided Hausdorff distance as a
          fraction of the input's bounding-box diagonal.
    progress
        ``progress(fraction, message)`` before each run and before its checks.
    check_cancel
        Called about four times a second while QuadriFlow runs (see :func:`run_quadriflow`);
        what it raises kills the child and propagates.

    Raises
    ------
    ValueError
        For malformed arrays or parameters out of range, naming what was seen.
    GeometryError
        When the mesh has zero extent.
    RemeshFailed
        When every attempt failed: the message lists each attempt's seed and reason.
    """
    target_faces, seed, attempts, candidates = params.target_faces, params.seed, params.attempts, params.candidates
    timeout_s = params.timeout_s
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(faces)
    if verts.ndim != 2 or verts.shape[1] != 3 or not np.isfinite(verts).all():
        raise ValueError(f"vertices must be a finite (n, 3) array, got shape {verts.shape}")
    if tris.ndim != 2 or tris.shape[1] != 3 or len(tris) == 0 or tris.dtype.kind not in "iu":
        raise ValueError(f"triangles must be a non-empty (m, 3) integer array, got shape {tris.shape} dtype {tris.dtype}")
    tris = tris.astype(np.int64)
    if tris.min() < 0 or tris.max() >= len(verts):
        raise ValueError(f"triangles index vertices {tris.min()}..{tris.max()} but there are {len(verts)}")
    # The group validates these; a group made without validation (model_construct) must not loop or divide by zero.
    if target_faces < 1 or attempts < 1 or candidates < 1 or timeout_s <= 0:
        raise ValueError(f"need target_faces ≥ 1, attempts ≥ 1, candidates ≥ 1, timeout_s > 0; got {target_faces}, "
                         f"{attempts}, {candidates}, {timeout_s}")
    diag = float(np.linalg.norm(np.ptp(verts[np.unique(tris)], axis=0)))
    if diag <= 0:
        raise GeometryError("the mesh has zero extent")
    loops = boundary_loop_count(tris, len(verts))
    failures: list[str] = []
    accepted: list[RemeshResult] = []
    runs = 0
    # After the plain attempts, one more at a quarter of the faces may split every face into quads to close
    # triangular holes that cannot be paired (QuadriFlow leaves them on some marching-cubes meshes).
    for attempt in range(attempts + 1):
        split = attempt == attempts
        if split and (accepted or not any("triangular holes" in f for f in failures)):
            break
        runs = attempt + 1
        run_seed, run_target = seed + attempt, int(target_faces)
        if failures:
            run_target = max(1, round(target_faces * (1.0 + _TARGET_NUDGE[attempt % len(_TARGET_NUDGE)])))
        if split:
            run_seed, run_target = seed, max(1, round(target_faces / 4))
        if progress is not None:
            progress(attempt / (attempts + 1), f"QuadriFlow, seed {run_seed}")
        started = time.monotonic()
        try:
            raw_v, raw_f = run_quadriflow(verts, tris, target_faces=run_target, seed=run_seed,
                                          preserve_sharp=params.preserve_sharp, preserve_boundary=loops > 0,
                                          min_cost_flow=params.min_cost_flow, timeout_s=timeout_s,
                                          check_cancel=check_cancel)
            quadriflow_s = time.monotonic() - started
            if progress is not None:
                progress((attempt + 0.8) / (attempts + 1), "checking the quads")
            out_v, out_f, facts = _accept(raw_v, raw_f, verts, tris, loops, diag, params.max_hausdorff_ratio,
                                          split_unpaired=split)
        except (QuadriflowFailed, ValueError) as exc:
            failures.append(f"seed {run_seed}, {run_target} faces: {exc}")
            continue
        creases = measure_crease_following(out_v, out_f, verts, tris)
        report = {
            "seed": run_seed, "attempts": attempt + 1, "quadriflow_target_faces": run_target,
            "split": any("split every face" in r for r in facts["repairs"]),
            "target_faces": int(target_faces), "faces": len(out_f), "vertices": len(out_v),
            "input_triangles": len(tris), "input_boundary_loops": loops, "quadriflow_s": quadriflow_s,
            "total_s": time.monotonic() - started, **facts, **creases.as_dict(),
        }
        accepted.append(RemeshResult(vertices=out_v, faces=out_f, report=report))
        if len(accepted) >= candidates:
            break
    if accepted:
        # The layout whose edges follow most of the input's creases; the closer one on a tie.
        best = min(accepted, key=lambda r: (r.report["missed_crease_mm"], r.report["hausdorff_mm"]))
        best.report["attempts"] = runs  # failed runs after the last that passed count too
        best.report["failed_attempts"] = failures
        keys = ("seed", "quadriflow_target_faces", "faces", "missed_crease_mm", "hausdorff_mm")
        best.report["candidates"] = [{key: r.report[key] for key in keys} for r in accepted]
        return best
    raise RemeshFailed(f"QuadriFlow gave no usable quad mesh in {len(failures)} attempt(s): " + "; ".join(failures)
                       + ". Try another remesh.target_faces or remesh.seed")
