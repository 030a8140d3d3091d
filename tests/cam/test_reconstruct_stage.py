"""The `reconstruct` stage wiring (worker.stages.reconstruct) and a real CAD part from ../shared/data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cam import GeometryError
from cam.io import read_ply, write_ply_points
from core.params import JobParams
from worker.context import StageCanceled, StageContext, StageSkipped
from worker.stages.reconstruct import run_reconstruct

SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
FAST = {"iterations": 100, "batch_size": 2048, "grid_cells": 48, "resolution": 96, "seed": 3}


def _cloud(tmp_path: Path, n: int = 3000, normals: bool = True) -> Path:
    i = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1.0 - 2.0 * i / n), np.pi * (1.0 + 5.0**0.5) * i
    v = np.column_stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])
    return write_ply_points(tmp_path / "cloud.ply", 20.0 * v + 5.0, v if normals else None)


def _ctx(tmp_path: Path, cloud: Path, params: dict, **callbacks) -> StageContext:
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    return StageContext(job_id="j", stage="reconstruct", inputs={"cloud.ply": cloud}, out_dir=out,
                        params=JobParams.model_validate({"reconstruct": params}),
                        settings={"blas_threads": 1}, **callbacks)


@pytest.mark.parametrize("normals", [True, False])
def test_stage_writes_a_watertight_mesh_raw(tmp_path, normals):
    seen = []
    ctx = _ctx(tmp_path, _cloud(tmp_path, normals=normals), FAST, progress=lambda f, m=None: seen.append(f))
    out = run_reconstruct(ctx)
    assert set(out) == {"mesh_raw.ply"} and out["mesh_raw.ply"] == ctx.output("mesh_raw.ply")
    mesh = read_ply(out["mesh_raw.ply"])
    assert mesh.faces is not None and len(mesh.faces) > 1000
    r = np.linalg.norm(mesh.points - 5.0, axis=1)
    assert np.abs(r - 20.0).max() < 0.2
    assert seen[-1] == 1.0 and len(seen) > FAST["iterations"]
    # The header says where the normals came from; a closed sphere's estimated ones are all told by the
    # space around it.
    told = [c for c in mesh.comments if "normals" in c]
    assert told and (("normals given" in told[0]) if normals
                     else "turned outward by the space around the cloud (100% of points voted)" in told[0])


def test_stage_cancel_raises_stage_canceled(tmp_path):
    calls = {"n": 0}

    def check_cancel():
        calls["n"] += 1
        if calls["n"] > 10:
            raise StageCanceled("canceled")

    ctx = _ctx(tmp_path, _cloud(tmp_path), dict(FAST, iterations=100_000), check_cancel=check_cancel)
    with pytest.raises(StageCanceled):
        run_reconstruct(ctx)
    assert not ctx.output("mesh_raw.ply").exists()


def test_stage_bad_cloud_is_a_geometry_error(tmp_path):
    """The core's GeometryError reaches the runner as it is, which shows its message to the user."""
    flat = np.column_stack([np.random.default_rng(0).uniform(0, 10, size=(500, 2)), np.zeros(500)])
    cloud = write_ply_points(tmp_path / "cloud.ply", flat)
    with pytest.raises(GeometryError, match="coplanar"):
        run_reconstruct(_ctx(tmp_path, cloud, FAST))


def test_stage_skips_a_mesh_upload(tmp_path):
    ctx = StageContext(job_id="j", stage="reconstruct", inputs={}, out_dir=tmp_path,
                       params=JobParams(), settings={})
    with pytest.raises(StageSkipped, match="mesh"):
        run_reconstruct(ctx)


def test_stage_defaults_come_from_the_core(tmp_path):
    """An empty params group runs with the core's defaults (only cheap here: a tiny override)."""
    ctx = _ctx(tmp_path, _cloud(tmp_path, n=1500), {"iterations": 5, "grid_cells": 32, "resolution": 64})
    assert read_ply(run_reconstruct(ctx)["mesh_raw.ply"]).faces is not None


@pytest.mark.skipif(not (SHARED_DATA / "fandisk_gt.obj").exists(), reason="../shared/data is absent")
def test_fandisk_cloud_gives_one_watertight_part_close_to_the_truth():
    import trimesh

    from cam.params import ReconstructParams
    from cam.reconstruct import reconstruct_surface

    gt = trimesh.load(SHARED_DATA / "fandisk_gt.obj", process=False)
    gt.apply_scale(10.0)
    pts, fi = trimesh.sample.sample_surface(gt, 20000, seed=0)
    # max_faces=None: the core's default before it took ReconstructParams (whose default caps at 200,000).
    result = reconstruct_surface(pts, gt.face_normals[fi],
                                 ReconstructParams(grid_cells=96, resolution=192, max_faces=None, seed=0), threads=1)
    mesh = trimesh.Trimesh(result.vertices, result.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.body_count == 1
    assert abs(mesh.volume - gt.volume) < 0.01 * gt.volume
    # The reconstructed vertices lie on the true surface: distance to the tangent plane of the
    # nearest of many true samples (exact on the flat faces): half within 0.02 % of the diagonal,
    # 99 % (which includes the edges, rounded by about one grid cell) within 0.5 %.
    from scipy.spatial import cKDTree

    check, cfi = trimesh.sample.sample_surface(gt, 200000, seed=1)
    verts = result.vertices[:: max(1, len(result.vertices) // 20000)]
    _, j = cKDTree(check).query(verts)
    d = np.abs(np.einsum("ij,ij->i", verts - check[j], gt.face_normals[cfi[j]]))
    diag = np.linalg.norm(gt.extents)
    assert np.median(d) < 0.0002 * diag and np.quantile(d, 0.99) < 0.005 * diag
