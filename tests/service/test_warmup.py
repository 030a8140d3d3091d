"""The worker's warm-up (`worker.warmup`): after it, a real job compiles no kernel; it follows the pipeline."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from core.config import Settings
from tests.conftest import ROOT
from worker.warmup import make_warmup_cloud, warm_stages


def test_warmup_cloud_lies_on_its_block_and_dome():
    cloud = make_warmup_cloud(np.random.default_rng(3), n_points=4000)
    p, n = cloud[:, :3], cloud[:, 3:]
    assert cloud.shape == (4000, 6)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    x, y, z = p.T
    side = (np.isclose(np.abs(x), 20) | np.isclose(np.abs(y), 20)) & (z >= 0) & (z <= 10)
    bottom = np.isclose(z, 0) & (np.abs(x) <= 20) & (np.abs(y) <= 20)
    base = np.sqrt(15.0**2 - 9.0**2)  # the dome's centre is 9 mm below the top face
    top = np.isclose(z, 10) & (np.hypot(x, y) >= base) & (np.abs(x) <= 20) & (np.abs(y) <= 20)
    dome = np.isclose(np.linalg.norm(p - [0, 0, 1.0], axis=1), 15.0) & (z >= 10)
    assert np.all(side | bottom | top | dome)
    assert min(side.sum(), bottom.sum(), top.sum(), dome.sum()) > 100
    # outward normals: the sides' along their axis, the dome's radial
    on_dome = dome & ~top  # (the rim, where both meet, goes either way)
    np.testing.assert_allclose(n[on_dome], (p[on_dome] - [0, 0, 1.0]) / 15.0, atol=1e-12)
    np.testing.assert_array_equal(n[bottom & ~side], np.tile([0.0, 0, -1], ((bottom & ~side).sum(), 1)))
    np.testing.assert_array_equal(n[top & ~side & ~dome], np.tile([0.0, 0, 1], ((top & ~side & ~dome).sum(), 1)))
    assert np.all(np.sum(n[side] * np.sign(p[side]) * (np.abs(p[side]) == 20), axis=1) == 1)
    with pytest.raises(ValueError, match="n_points"):
        make_warmup_cloud(np.random.default_rng(0), n_points=10)


def test_warm_stages_follow_the_pipeline():
    everything = ["ingest", "reconstruct", "denoise", "remesh", "segment", "fit", "plan", "verify"]
    assert warm_stages(Settings(pipeline="")) == everything
    assert warm_stages(Settings(pipeline="ingest")) == []  # it compiles nothing
    # a mesh-only service still needs its mesh made; a test stage compiles nothing
    assert warm_stages(Settings(pipeline="ingest,reconstruct,denoise")) == everything[:3]
    assert warm_stages(Settings(pipeline="ingest,denoise,plan,verify")) == everything
    assert warm_stages(Settings(stage_plugins="tests.plugins.dwell", pipeline="ingest,dwell")) == []


def _cache_files(folder):
    return {(p.relative_to(folder), p.stat().st_mtime_ns, p.stat().st_size) for p in folder.rglob("*") if p.is_file()}


@pytest.mark.slow
def test_a_job_after_the_warm_up_compiles_nothing(tmp_path):
    # A cache of its own, empty: what a fresh install or a new container has (about a minute to compile).
    cache = tmp_path / "numba-cache"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    env.pop("CLOUD2CNC_PIPELINE", None)

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "cloud2cnc.cli", *args], capture_output=True, text=True,
                              cwd=ROOT, env=env, timeout=600, check=False)

    r = cli("warm-up")
    assert r.returncode == 0, r.stderr
    assert "compiled the kernels" in r.stderr
    stamps = list(cache.rglob("cloud2cnc-warm-*"))
    assert len(stamps) == 1
    r = cli("warm-up")
    assert r.returncode == 0 and "nothing to compile" in r.stderr, r.stderr
    before = _cache_files(cache)
    # The README example as a user runs it: a different part and parameters, the stages' processes forked.
    r = cli("run", str(ROOT / "examples" / "dome_block.xyz"), "--out", str(tmp_path / "job"),
            "--set", "tool.radius_mm=2", "--set", "reconstruct.max_faces=20000", "--set", "fit.max_refinements=0")
    assert r.returncode == 0, r.stderr[-3000:]
    compiled = sorted(str(name) for name, *_ in _cache_files(cache) - before)
    assert compiled == [], f"the job compiled what the warm-up did not: {compiled}"
