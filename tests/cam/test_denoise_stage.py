"""The `denoise` stage around cam.denoise.mesh_tgv: files, the enabled switch, cancel, errors, and params bounds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pydantic
import pytest
import trimesh

from cam import GeometryError
from cam.io import read_ply, write_ply_mesh
from core.params import DenoiseParams, JobParams
from worker.context import StageCanceled, StageContext, StageError, StageSkipped
from worker.stages.denoise import run_denoise


def _noisy_box(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    box = trimesh.creation.box(extents=(20.0, 20.0, 20.0)).subdivide().subdivide().subdivide()
    v, f = np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int64)
    rng = np.random.default_rng(7)
    noisy = v + trimesh.Trimesh(v, f, process=False).vertex_normals * rng.normal(scale=0.3, size=(len(v), 1))
    return write_ply_mesh(tmp_path / "mesh_raw.ply", noisy, f), noisy, f


def _ctx(tmp_path: Path, src: Path, denoise: dict | None = None, **callbacks) -> StageContext:
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    return StageContext(job_id="j", stage="denoise", inputs={"mesh_raw.ply": src}, out_dir=out,
                        params=JobParams.model_validate({"denoise": denoise or {}}), settings={},
                        **callbacks)


def test_stage_writes_a_denoised_mesh_and_its_report(tmp_path):
    src, noisy, f = _noisy_box(tmp_path)
    seen = []
    out = run_denoise(_ctx(tmp_path, src, progress=lambda x, m=None: seen.append(x)))
    assert set(out) == {"mesh.ply", "denoise.json"}
    mesh = read_ply(out["mesh.ply"])
    assert np.array_equal(mesh.faces, f) and mesh.points.shape == noisy.shape
    # The box's faces are planes |x_i| = 10: denoising must bring the vertices closer to them.
    before = np.abs(np.abs(noisy).max(axis=1) - 10.0).mean()
    after = np.abs(np.abs(mesh.points).max(axis=1) - 10.0).mean()
    assert after < 0.5 * before
    report = json.loads(out["denoise.json"].read_text())
    assert report["iterations"] >= 1 and seen and seen[-1] == 1.0


def test_a_filter_that_would_change_the_part_passes_the_input_on(tmp_path):
    # A CAD export: a block with two round pockets, 96 % of its faces slivers. MeshTGV shrinks it (to a
    # quarter of its volume); plan must machine the part, not that, so the input goes on as mesh.ply.
    mf = pytest.importorskip("manifold3d")
    solid = (mf.Manifold.cube((60.0, 40.0, 20.0)) - mf.Manifold.cylinder(15.0, 8.0, 8.0, 48).translate((20.0, 20.0, 8.0))
             - mf.Manifold.cylinder(15.0, 5.0, 5.0, 48).translate((42.0, 20.0, 8.0))).to_mesh()
    v, f = np.asarray(solid.vert_properties, dtype=np.float64)[:, :3], np.asarray(solid.tri_verts, dtype=np.int64)
    src = write_ply_mesh(tmp_path / "mesh_raw.ply", v, f)
    with pytest.raises(StageSkipped, match=r"^MeshTGV would change the part, not only its noise \(the surface moved by "
                                           r"up to .* mm \(.*% of the part's diagonal; volume ×0\.\d+\)\): mesh_raw.ply "
                                           r"is passed on as mesh.ply") as info:
        run_denoise(_ctx(tmp_path, src))
    assert info.value.outputs["mesh.ply"].read_bytes() == src.read_bytes()
    shift = json.loads(info.value.outputs["denoise.json"].read_text())["shift"]
    assert not shift["kept"] and shift["volume_ratio"] < 0.95 and shift["max_mm"] > 0.05 * shift["diagonal_mm"]


def test_the_noisy_box_is_kept_and_its_shift_reported(tmp_path):
    src, noisy, f = _noisy_box(tmp_path)
    out = run_denoise(_ctx(tmp_path, src))
    shift = json.loads(out["denoise.json"].read_text())["shift"]
    # Noise of 0.3 mm on a 20 mm box: the filter moves the surface by about that, and keeps the volume.
    assert shift["kept"] and shift["max_mm"] < 1.5 and abs(shift["volume_ratio"] - 1.0) < 0.05


def test_disabled_passes_the_mesh_on_unchanged(tmp_path):
    src, _, _ = _noisy_box(tmp_path)
    with pytest.raises(StageSkipped, match="enabled is false") as info:
        run_denoise(_ctx(tmp_path, src, {"enabled": False}))
    passed = info.value.outputs["mesh.ply"]
    assert passed.read_bytes() == src.read_bytes() and not passed.is_symlink()


def test_cancel_stops_the_stage(tmp_path):
    src, _, _ = _noisy_box(tmp_path)

    def cancel():
        raise StageCanceled()

    with pytest.raises(StageCanceled):
        run_denoise(_ctx(tmp_path, src, check_cancel=cancel))


def test_a_degenerate_mesh_names_the_file(tmp_path):
    """The core's GeometryError comes out as a StageError that says which file it is about."""
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    src = write_ply_mesh(tmp_path / "mesh_raw.ply", flat, np.array([[0, 1, 2], [1, 2, 3]]))
    with pytest.raises(StageError, match=r"^cannot denoise mesh_raw.ply: all 2 faces are degenerate") as info:
        run_denoise(_ctx(tmp_path, src))
    assert isinstance(info.value.__cause__, GeometryError)


def test_a_point_cloud_is_a_clear_error(tmp_path):
    from cam.io import write_ply_points

    src = write_ply_points(tmp_path / "mesh_raw.ply", np.random.default_rng(0).normal(size=(50, 3)))
    with pytest.raises(StageError, match="no faces"):
        run_denoise(_ctx(tmp_path, src))


# name: (default, lower, upper, lower_inclusive); upper is inclusive. The numbers the filter is tuned for.
FILTER_BOUNDS: dict[str, tuple[float | None, float, float, bool]] = {
    "alpha0": (None, 0.0, 100.0, False),  # None: chosen from the measured noise
    "alpha1": (None, 0.0, 100.0, False),
    "penalty0": (2.0, 0.0, 1000.0, False),
    "penalty1": (2.0, 0.0, 1000.0, False),
    "vertex_iterations": (None, 0, 1000, True),  # None: chosen with the weights
    "flip_repair_rounds": (5, 0, 100, True),
    "max_iterations": (100, 1, 10000, True),
    "tolerance": (1e-5, 0.0, 1.0, True),
    "noise_reference_deg": (0.0, 0.0, 180.0, True),
}


def test_jobparams_carry_the_cores_defaults_and_bounds():
    defaults = DenoiseParams()
    for name, (default, low, high, low_inclusive) in FILTER_BOUNDS.items():
        assert getattr(defaults, name) == default, name
        DenoiseParams(**{name: high})
        with pytest.raises(pydantic.ValidationError):
            DenoiseParams(**{name: high * 1.5 + 1})
        if low_inclusive:
            DenoiseParams(**{name: low})
        else:
            with pytest.raises(pydantic.ValidationError):
                DenoiseParams(**{name: low})
