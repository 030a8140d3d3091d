"""Point cloud to watertight triangle mesh with IGR (Gropp et al. 2020): the public entry point.

The cloud is centred and scaled into the unit ball, normals are checked or
estimated, a signed distance f is trained with the IGR loss, and its zero
level set is extracted with marching cubes and mapped back to the input's
frame and units.

The mesh is then measured against its own cloud (:mod:`cam.reconstruct.fidelity`): a surface that
strays from the scanned points, or leaves a cluster of them out, by more than 8 point spacings plus 4
times the cloud's noise is a wrong part, not a rough one, and is refused.

What the user can change (too few or only duplicate points, a collinear or flat cloud, normals that
cannot be oriented, a diverging run, a field with no inside, a mesh that strays from its cloud) raises a
:class:`~cam.GeometryError` (:class:`~cam.reconstruct.normals.NormalsError`,
:class:`~cam.reconstruct.train.DivergedError` and :class:`~cam.reconstruct.fidelity.FidelityError` are ones); arrays of the wrong shape, non-finite coordinates and an unknown device are a caller's
bug and raise ``ValueError``. The options come from a `ReconstructParams`, validated when it was made.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

from cam import CheckCancel, GeometryError, Progress, progress_between
from cam.params import ReconstructParams
from cam.reconstruct.extract import extract_surface, is_watertight
from cam.reconstruct.fidelity import check_fidelity, measure_fidelity
from cam.reconstruct.fields import GridField, IGRNetwork
from cam.reconstruct.normals import check_normals, estimate_normals
from cam.reconstruct.presets import resolve_options
from cam.reconstruct.prior import band_vertices, plane_distance
from cam.reconstruct.sharpen import sharpen_creases
from cam.reconstruct.train import TrainSettings, train_igr

__all__ = ["MIN_POINTS", "Reconstruction", "reconstruct_surface"]

MIN_POINTS = 100


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """A reconstructed surface.

    vertices: float64 (v, 3), the input's units and frame.
    faces: int64 (f, 3), outward (counter-clockwise seen from outside).
    report: JSON-ready dict (see :func:`reconstruct_surface`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    report: dict[str, Any]


def reconstruct_surface(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    params: ReconstructParams = ReconstructParams(),
    *,
    threads: int | None = None,
    workers: int | None = None,
    device: str = "auto",
    progress: Progress | None = None,
    check_cancel: CheckCancel | None = None,
    self_check: bool = True,
) -> Reconstruction:
    """Reconstruct a closed surface from a point cloud.

    Parameters
    ----------
    points : ndarray, shape (n, 3), real dtype
        Finite coordinates, any unit (mm in the pipeline); n >= 100 distinct.
    normals : ndarray, shape (n, 3), real dtype, or None
        Outward normals (any non-zero length), or None to estimate them.
    params : ReconstructParams
        ``preset``: ``"fast"`` (grid pyramid started from the oriented-plane
        distance; the default, about a minute for 50k points on 2 CPU cores),
        ``"mlp"`` (the paper's network at 4x256, sphere start) or ``"paper"``
        (8x512, the paper's sampling and schedule; meant for a GPU); see
        :mod:`cam.reconstruct.presets`.
        ``iterations``, ``batch_size``, ``grid_cells``, ``width``, ``depth``,
        ``resolution``, ``learning_rate`` override the preset when not None:
        Adam steps, cloud points per step, finest grid cells along the longest
        side (fast), MLP width and depth (mlp, paper), marching-cubes cells
        along the longest side, initial learning rate (mlp: Adam's step; fast:
        the step as a fraction of each grid level's cell), decaying to 1/100 of it.
        ``eikonal_weight``, ``normal_weight``: lambda and tau of the IGR loss
        (paper: 0.1 and 1).
        ``normals_k``: neighbours for normal estimation.
        ``max_faces``: cap on the mesh's triangles: when marching cubes at
        ``resolution`` gives more, the surface is extracted again on a coarser
        lattice sized to fit (a closed mesh either way; the later stages' cost
        grows with the faces). None: no cap.
        ``sharpen``: restore the sharp edges that marching cubes bevels over
        about one cell (:func:`~cam.reconstruct.sharpen.sharpen_creases`):
        bevel vertices move onto the two face planes and the edges between
        them are split at the crease. The field is what IGR trained either way;
        this only changes how its zero set is meshed. False: plain marching cubes.
        ``seed``: the same seed gives the same mesh on CPU.
    threads : int, optional
        Torch threads (and k-NN threads unless ``workers`` is given); None keeps torch's setting.
    workers : int, optional
        Threads of the k-nearest-neighbour queries (each query's answer is the same with any number);
        None: ``threads``.
    device : {"auto", "cpu", "cuda"}
        ``"auto"``: CUDA when available.
    progress : callable, optional
        ``progress(fraction, message)``, called at least once per iteration.
    check_cancel : callable, optional
        Called every iteration and between phases; it stops the work by raising
        (the exception passes through untouched).
    self_check : bool
        Refuse a mesh that strays from its cloud (see ``fidelity`` below and
        :func:`~cam.reconstruct.fidelity.check_fidelity`). False: measure and
        report only (for benches that study a failing case).

    Returns
    -------
    Reconstruction
        ``vertices`` float64 (v, 3) in the input's units and frame, ``faces``
        int64 (f, 3) wound outward, and the report: ``points``, ``normals``
        (``"given"`` or ``"estimated"`` and the estimate's details), ``preset``,
        the effective ``options`` (``prior_creases``: whether the grid's start combined faces at
        creases; see :mod:`cam.reconstruct.prior`), ``device``, ``threads``, ``normalisation``
        (``centre`` in input units, ``scale``), ``training`` (``iterations``,
        final loss terms), ``mesh`` (vertex and face counts, ``watertight``,
        components, ``cell_units``), ``fidelity`` (the mesh against its own
        cloud, input units: ``tolerance`` = 8 x ``spacing`` + 4 x ``noise``,
        ``mesh_to_cloud`` and ``cloud_to_mesh`` (largest distances; isolated
        outliers left out and counted under ``outliers``), the same as shares of
        the cloud's ``diagonal``, ``ok``; see
        :class:`~cam.reconstruct.fidelity.Fidelity`) and ``timings_s`` (seconds).

    Raises
    ------
    GeometryError
        With a message naming the problem: too few or only duplicate points,
        a collinear or flat cloud, zero-length or non-finite normals or normals
        that cannot be oriented (:class:`~cam.reconstruct.normals.NormalsError`),
        a diverging training run (:class:`~cam.reconstruct.train.DivergedError`),
        a field in which no surface was found, or (``self_check``) a mesh that
        strays from its cloud or leaves a cluster of it out
        (:class:`~cam.reconstruct.fidelity.FidelityError`, naming the distances,
        where, and what to do).
    ValueError
        For arrays of the wrong shape, non-finite coordinates, or an unknown ``device``.
    """
    started = time.perf_counter()
    timings: dict[str, float] = {}
    check_cancel = check_cancel or _no_cancel
    opts = resolve_options(params)
    dev = _torch_device(device)
    pts = _check_points(points)
    nrm = check_normals(normals, len(pts)) if normals is not None else None
    workers = workers or threads or 1
    centre, scale, unit = _normalise(pts)

    with _timed(timings, "normals"):
        tree, spacing, sigma = _sample_spacing(unit, sigma_k=opts["sigma_k"], workers=workers)
        nrm, normals_report = _oriented_normals(unit, nrm, k=params.normals_k, workers=workers,
                                                check_cancel=check_cancel)
    check_cancel()

    lo, hi = _sampling_box(unit)
    creases = _normals_hold_at_creases(normals_report, params)
    with _torch_threads(threads):
        with _timed(timings, "init"):
            field, groups = _make_field(opts, lo, hi, unit, nrm, spacing, tree, workers, params.seed, dev,
                                        check_cancel, creases=creases)
        with _timed(timings, "train"):
            training = _train(field, groups, unit, nrm, sigma, lo, hi, opts, params, dev, progress, check_cancel)
        with _timed(timings, "extract"):
            if progress is not None:
                progress(0.92, "extracting the surface")
            verts, faces, mesh_report = _extract_within_cap(
                _lattice_evaluator(field, dev), lo, hi, unit, resolution=opts["resolution"], params=params,
                field_cell=field.cell[-1] if isinstance(field, GridField) else 0.0, workers=workers,
                progress=progress, check_cancel=check_cancel)

    verts = verts * scale + centre
    # The surface cannot be held finer than the field's finest cell nor the marching-cubes lattice.
    finest = max(mesh_report["cell"], field.cell[-1] if isinstance(field, GridField) else 0.0) * scale
    mesh_report.update({"vertices": int(len(verts)), "faces": int(len(faces)),
                        "cell_units": mesh_report.pop("cell") * scale})
    check_cancel()
    with _timed(timings, "check"):
        fidelity = measure_fidelity(verts, faces, pts, resolution=finest, workers=workers)
    timings["total"] = time.perf_counter() - started
    report = {
        "points": int(len(pts)),
        "normals": normals_report,
        "preset": params.preset,
        "options": {**opts, "eikonal_weight": params.eikonal_weight, "normal_weight": params.normal_weight,
                    "normals_k": params.normals_k, "max_faces": params.max_faces, "sharpen": params.sharpen,
                    "seed": params.seed, "prior_creases": creases},
        "device": str(dev),
        "threads": torch.get_num_threads() if threads is None else threads,
        "normalisation": {"centre": centre.tolist(), "scale": scale},
        "training": training,
        "mesh": mesh_report,
        "fidelity": fidelity.report(),
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    if self_check:
        check_fidelity(fidelity)
    return Reconstruction(vertices=verts, faces=faces, report=report)


def _torch_device(device: str) -> torch.device:
    if device not in ("auto", "cpu", "cuda"):
        raise ValueError(f"device must be auto, cpu or cuda, got {device!r}")
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def _check_points(points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be an (n, 3) array, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        bad = int((~np.isfinite(pts).all(axis=1)).sum())
        raise ValueError(f"{bad} of {len(pts)} points have non-finite coordinates (NaN/Inf); drop them first")
    if len(pts) < MIN_POINTS:
        raise GeometryError(f"the cloud has {len(pts)} points; at least {MIN_POINTS} are needed to rebuild a "
                            "surface")
    distinct = len(np.unique(pts, axis=0))
    if distinct < MIN_POINTS:
        raise GeometryError(f"the cloud has only {distinct} distinct points among {len(pts)} (the rest are "
                            f"duplicates); at least {MIN_POINTS} distinct points are needed")
    centred = pts - pts.mean(axis=0)
    spread = np.linalg.svd(centred[:: max(1, len(pts) // 200_000)], compute_uv=False)
    if spread[1] <= 1e-6 * spread[0]:
        raise GeometryError("the points are collinear (they lie on one line); a surface needs a scan of the "
                            "part's faces, not a single line")
    if spread[2] <= 1e-3 * spread[0]:
        raise GeometryError("the points are coplanar (they lie in one plane, thinner than 0.1 % of their "
                            "size); a flat sheet of points encloses no volume, scan the part from all sides")
    return pts


def _normalise(pts: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre of the box and the scale that puts the farthest point at radius 1, and the points so mapped."""
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
    scale = float(np.linalg.norm(pts - centre, axis=1).max())
    return centre, scale, (pts - centre) / scale


def _sample_spacing(unit: np.ndarray, *, sigma_k: int, workers: int) -> tuple[cKDTree, float, np.ndarray]:
    """The cloud's k-d tree, its median spacing, and each point's eikonal sigma (its sigma_k-th neighbour)."""
    tree = cKDTree(unit)
    kk = min(sigma_k, len(unit) - 1)
    dist, _ = tree.query(unit, k=[2, kk + 1], workers=workers)
    return tree, float(np.median(dist[:, 0])), dist[:, 1]


def _oriented_normals(unit: np.ndarray, nrm: np.ndarray | None, *, k: int, workers: int,
                      check_cancel: CheckCancel) -> tuple[np.ndarray, dict[str, Any]]:
    """The given normals, or ones estimated and oriented on the cloud; and the report's ``normals``."""
    if nrm is not None:
        return nrm, {"source": "given"}
    nrm, estimate = estimate_normals(unit, k=k, workers=workers, check_cancel=check_cancel)
    return nrm, {"source": "estimated", **estimate}


def _sampling_box(unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cloud's box grown by 5 % of its longest side: the field's domain and the extraction's."""
    lo = unit.min(axis=0)
    hi = unit.max(axis=0)
    margin = 0.05 * float((hi - lo).max())
    return lo - margin, hi + margin


def _normals_hold_at_creases(normals_report: dict[str, Any], params: ReconstructParams) -> bool:
    """Whether the grid's start may combine faces at creases (see :mod:`cam.reconstruct.prior`).

    Normals estimated with a fit widened for noise (to over twice ``normals_k``) are averaged across
    a crease over more than the holes in the samples that the combination is for, and planes tilted
    there put it on the wrong side: under a concave crease of a bracket at 0.25 % noise (k widened
    to 37) it left a tunnel, a handle the part does not have. Such clouds keep the blended planes.
    """
    return normals_report["source"] == "given" or normals_report["k"] <= 2 * params.normals_k


def _make_field(opts, lo, hi, unit, nrm, spacing, tree, workers, seed, dev, check_cancel, *, creases):
    """The field and its Adam parameter groups (per-level learning-rate factors for the grid)."""
    if opts["field"] == "grid":
        return _make_grid_field(opts, lo, hi, unit, nrm, spacing, tree, workers, dev, check_cancel, creases=creases)
    return _make_network(opts, unit, seed, dev), None


def _make_grid_field(opts, lo, hi, unit, nrm, spacing, tree, workers, dev, check_cancel, *, creases):
    """A grid pyramid started from the oriented-plane distance, and its per-level parameter groups."""
    field = GridField(lo, hi, finest_cells=opts["grid_cells"], levels=opts["levels"]).to(dev)
    # The coarsest level takes the prior everywhere (few vertices, so unbounded queries are
    # cheap); the finest level adds the detail in a band around the cloud, where training acts.
    coarse = plane_distance(field.vertices(0), unit, nrm, spacing=spacing, k=opts["prior_k"],
                            workers=workers, tree=tree, creases=creases, check_cancel=check_cancel)
    field.set_level(0, torch.as_tensor(coarse))
    lo_f, cell, dims = field.lo.detach().cpu().double().numpy(), field.cell[-1], field.dims[-1]
    axes = [lo_f[a] + cell * np.arange(dims[a]) for a in range(3)]
    band = 4.0 * cell
    near = band_vertices(unit, lo_f, cell, dims, band)
    i, j, k = np.unravel_index(near, tuple(int(d) for d in dims))
    fine = np.full(int(np.prod(dims)), np.nan)
    fine[near] = plane_distance(np.stack([axes[0][i], axes[1][j], axes[2][k]], axis=1), unit, nrm, spacing=spacing,
                                k=opts["prior_k"], workers=workers, tree=tree, max_distance=band,
                                creases=creases, check_cancel=check_cancel)
    with torch.no_grad():
        base = field.lattice(axes).reshape(-1).double().cpu().numpy()
    residual = np.where(np.isfinite(fine), fine - base, 0.0)
    field.set_level(-1, torch.as_tensor(residual))
    # Adam moves every touched vertex by about the learning rate whatever its gradient, so the
    # step is set per level as a fraction of that level's cell: a fixed step would make the
    # finest level's gradient (value differences over a small cell) noisy.
    groups = [{"params": [p], "lr_scale": h} for p, h in zip(field.values, field.cell, strict=True)]
    return field, groups


def _make_network(opts, unit, seed, dev):
    """The paper's MLP, started as the sphere of the cloud's mean radius."""
    gen = torch.Generator().manual_seed(seed)
    radius = float(np.linalg.norm(unit, axis=1).mean())
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        field = IGRNetwork(width=opts["width"], depth=opts["depth"], radius=radius, generator=gen)
    return field.to(dev)


def _train(field, groups, unit, nrm, sigma, lo, hi, opts, params: ReconstructParams, dev, progress, check_cancel):
    """The IGR training run on the normalised cloud; returns its report."""
    gen = torch.Generator(device=dev).manual_seed(params.seed)
    settings = TrainSettings(iterations=opts["iterations"], batch_size=opts["batch_size"],
                             learning_rate=opts["learning_rate"], lr_final_ratio=opts["lr_final_ratio"],
                             schedule=opts["schedule"], lam=params.eikonal_weight, tau=params.normal_weight)
    return train_igr(field, _tensor(unit, dev), _tensor(nrm, dev), _tensor(sigma, dev),
                     (_tensor(lo, dev), _tensor(hi, dev)), settings, generator=gen, param_groups=groups,
                     progress=progress_between(progress, 0.05, 0.9) if progress else None,
                     check_cancel=check_cancel)


def _lattice_evaluator(field, dev: torch.device):
    """``evaluate(xs, ys, zs)`` for :func:`extract_surface`: the field on the lattice they span."""

    def evaluate(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            if isinstance(field, GridField):
                return field.lattice([xs, ys, zs]).cpu().numpy()
            q = _tensor(np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3), dev)
            # Chunks bound the MLP's activations (an 8x512 net holds 2 kB per point and layer).
            f = torch.cat([field(c, with_grad=False)[0] for c in torch.split(q, 65536)])
            return f.cpu().numpy().reshape(len(xs), len(ys), len(zs))

    return evaluate


def _extract_within_cap(evaluate, lo, hi, unit, *, resolution: int, params: ReconstructParams, field_cell: float,
                        workers: int, progress: Progress | None, check_cancel: CheckCancel):
    """Marching cubes (and sharpening) at ``resolution``, or at the coarser one a pilot extraction predicts
    within ``max_faces``, then on coarser lattices while over it."""
    max_faces = params.max_faces
    resolution = _predicted_resolution(evaluate, lo, hi, unit, resolution=resolution, max_faces=max_faces,
                                       check_cancel=check_cancel)
    for _ in range(4):
        verts, faces, mesh_report = extract_surface(evaluate, lo, hi, resolution=resolution, points=unit,
                                                    check_cancel=check_cancel)
        mesh_report["resolution"] = resolution
        fits = max_faces is None or len(faces) <= max_faces or resolution == 16
        if fits and params.sharpen:
            # Sharpening adds a few per cent of faces, so the cap is checked again after it.
            verts, faces, mesh_report = _sharpen(verts, faces, mesh_report, field_cell, workers, check_cancel)
            fits = max_faces is None or len(faces) <= max_faces or resolution == 16
        if fits:
            break
        # Faces grow with the square of the resolution; 0.97 leaves room for the estimate's error.
        coarser = max(16, min(resolution - 1, int(resolution * np.sqrt(max_faces / len(faces)) * 0.97)))
        if progress is not None:
            progress(0.96, f"{len(faces)} faces at {resolution} cells; extracting at {coarser}")
        resolution = coarser
    return verts, faces, mesh_report


def _predicted_resolution(evaluate, lo, hi, unit, *, resolution: int, max_faces: int | None,
                          check_cancel: CheckCancel) -> int:
    """``resolution``, or the finest coarser one whose mesh an extraction at a quarter of it predicts
    within ``max_faces`` (faces grow with the square of the resolution).

    The pilot costs a sixty-fourth of the extraction it spares: a capped mesh was extracted at the
    preset's resolution first only to learn its face count (the README example's 20,000-face cap
    ends near 54 cells of the preset's 384).
    """
    pilot = resolution // 4
    if max_faces is None or pilot < 16:
        return resolution
    _, faces, _ = extract_surface(evaluate, lo, hi, resolution=pilot, points=unit, check_cancel=check_cancel)
    if len(faces) * (resolution / pilot) ** 2 <= max_faces:
        return resolution
    return max(16, min(resolution, int(pilot * np.sqrt(max_faces / len(faces)) * 0.97)))


def _sharpen(verts, faces, report, field_cell, workers, check_cancel):
    """The creases restored on a marching-cubes mesh (normalised frame); the report gains ``sharpened``."""
    check_cancel()
    # The bevel spans the field's finest cell or two lattice cells, whichever is wider.
    size = max(field_cell, 2.0 * report["cell"])
    verts, faces, sharpened = sharpen_creases(verts, faces, feature_size=size, workers=workers,
                                              check_cancel=check_cancel)
    report["sharpened"] = sharpened
    report["watertight"] = is_watertight(faces)
    return verts, faces, report


@contextmanager
def _torch_threads(threads: int | None) -> Iterator[None]:
    previous = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


@contextmanager
def _timed(timings: dict[str, float], name: str) -> Iterator[None]:
    """Records the seconds the block took as ``timings[name]``."""
    start = time.perf_counter()
    yield
    timings[name] = time.perf_counter() - start


def _tensor(a: np.ndarray, dev: torch.device) -> torch.Tensor:
    return torch.as_tensor(a, dtype=torch.float32, device=dev)


def _no_cancel() -> None:
    pass
