"""Compile the geometry kernels before the first job, not during it.

`cam`'s compiled loops (numba, ``cache=True``) are compiled the first time a process calls them and kept
in numba's cache on disk: about 39 s of the README example's first run on two cores (64.4 s against 25.4 s
once cached, bench/results/warmup.md), half of it in `denoise`. A worker therefore runs :func:`warm_kernels` in a child process
before it takes work: a small job of the pipeline's own stages on a block with a dome made here, which
calls every kernel with the argument types a real job passes, so numba compiles and stores them all. Its
pool's processes then load the kernels from the cache. A stamp beside numba's cache says the work is done
for this code, numba, Python and CPU (what numba's own cache is keyed on), so a later start skips it.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

if TYPE_CHECKING:
    from core.config import Settings

__all__ = ["WarmupReport", "main", "make_warmup_cloud", "run_warm_up", "stamp_path", "warm_kernels", "warm_stages"]

# The job's parameters: small and coarse, so that what is not compiling takes seconds (the README example's
# defaults would add 20 s), with a second setup; the kernels and their argument types are the same at any size.
_PARAMS = {"tool": {"radius_mm": 3.0}, "reconstruct": {"max_faces": 8000, "iterations": 10},
           "denoise": {"max_iterations": 10}, "remesh": {"target_faces": 800, "candidates": 1},
           "fit": {"max_refinements": 0}, "toolpath": {"scallop_height_mm": 0.3}}
_POINTS = 1500
# Over ten times the warm-up on an empty cache (51 s on a two-core AMD EPYC); past it the worker starts all the
# same and its first jobs compile what is left.
_TIMEOUT_S = 600.0


@dataclass(frozen=True)
class WarmupReport:
    """What :func:`warm_kernels` did: why it ran no job (`skipped`; None: it ran one), the seconds it took and
    each stage's status; `stamp` is the stamp's path (None where no stage would compile anything)."""

    skipped: str | None
    seconds: float
    stages: dict[str, str]
    stamp: Path | None


def make_warmup_cloud(rng: np.random.Generator, *, n_points: int = _POINTS) -> np.ndarray:
    """Points and normals of a 40 x 40 x 10 mm block with a spherical dome (radius 15 mm, 6 mm high) on top.

    Parameters
    ----------
    rng : numpy.random.Generator
        Where the points are drawn from (uniform by area).
    n_points : int
        How many points.

    Returns
    -------
    ndarray, shape (n_points, 6), float64
        x, y, z, nx, ny, nz (mm; unit outward normals).
    """
    if n_points < 100:
        raise ValueError(f"n_points must be at least 100, got {n_points}")
    half, height, radius, cap = 20.0, 10.0, 15.0, 6.0
    centre_z = height + cap - radius
    base = np.sqrt(radius**2 - (height - centre_z) ** 2)  # the dome's foot on the top face
    areas = np.array([4 * 2 * half * height, (2 * half) ** 2 - np.pi * base**2, (2 * half) ** 2,
                      2 * np.pi * radius * cap])  # sides, top less the dome's foot, bottom, dome
    counts = rng.multinomial(n_points, areas / areas.sum())
    return np.concatenate([_sides(rng, counts[0], half, height), _top(rng, counts[1], half, height, base),
                           _bottom(rng, counts[2], half), _dome(rng, counts[3], radius, centre_z, height)])


def _sides(rng, n, half, height):
    side = rng.integers(0, 4, n)
    t, z = rng.uniform(-half, half, n), rng.uniform(0.0, height, n)
    normal = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0]])[side]
    x = np.where(normal[:, 0] != 0, normal[:, 0] * half, t)
    y = np.where(normal[:, 1] != 0, normal[:, 1] * half, t)
    return np.column_stack([x, y, z, normal])


def _top(rng, n, half, height, base):
    xy = np.zeros((0, 2))
    while len(xy) < n:  # rejection: outside the dome's foot
        draw = rng.uniform(-half, half, (2 * n + 8, 2))
        xy = np.concatenate([xy, draw[np.hypot(draw[:, 0], draw[:, 1]) > base]])
    xy = xy[:n]
    return np.column_stack([xy, np.full(n, height), np.zeros(n), np.zeros(n), np.ones(n)])


def _bottom(rng, n, half):
    xy = rng.uniform(-half, half, (n, 2))
    return np.column_stack([xy, np.zeros(n), np.zeros(n), np.zeros(n), -np.ones(n)])


def _dome(rng, n, radius, centre_z, height):
    # Uniform on a sphere's zone: z uniform between the zone's planes (Archimedes), the angle uniform.
    z = rng.uniform(height, centre_z + radius, n)
    phi = rng.uniform(0.0, 2 * np.pi, n)
    r = np.sqrt(np.maximum(radius**2 - (z - centre_z) ** 2, 0.0))
    normal = np.column_stack([r * np.cos(phi), r * np.sin(phi), z - centre_z]) / radius
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z, normal])


def warm_stages(settings: Settings) -> list[str]:
    """The built-in stages the warm-up runs for `settings`' pipeline: DESIGN's order up to the last built-in stage
    the pipeline runs (a pipeline without `reconstruct` still needs a mesh), none where that is `ingest`."""
    from core.stages import STAGES, load_stages

    built_in = [s.name for s in STAGES]
    configured = {s.name for s in load_stages(settings.stage_plugins, settings.pipeline)}
    last = max((built_in.index(n) for n in configured if n in built_in), default=-1)
    return built_in[:last + 1] if last > 0 else []  # ingest alone compiles nothing


def stamp_path(stages: list[str]) -> Path:
    """Where the stamp of a warm-up through `stages` goes: numba's cache folder of `cam`'s kernels, under a name
    keyed on what numba's cache is keyed on (the kernels' source files, numba's and Python's versions, the
    CPU), so that it goes when the cache goes and stops matching when the cache would."""
    import llvmlite.binding as llvm
    import numba

    from cam.mesh._compiled import dot3

    cam_root = Path(dot3.py_func.__code__.co_filename).resolve().parents[1]
    digest = hashlib.sha256(",".join(stages).encode())
    for path in sorted(cam_root.rglob("*.py")):
        if b"from numba import" in path.read_bytes():  # numba checks a kernel's own file only
            st = path.stat()
            digest.update(f"{path.relative_to(cam_root)}\0{st.st_mtime_ns}\0{st.st_size}\0".encode())
    cpu = numba.config.CPU_NAME or llvm.get_host_cpu_name()
    features = numba.config.CPU_FEATURES or llvm.get_host_cpu_features().flatten()
    digest.update(f"{numba.__version__}\0{sys.version}\0{cpu}\0{features}".encode())
    return Path(dot3._cache._cache_path) / f"cloud2cnc-warm-{digest.hexdigest()[:20]}"


def warm_kernels(settings: Settings, *, force: bool = False) -> WarmupReport:
    """Run the warm-up job (see the module's docstring) through `warm_stages(settings)` unless its stamp is
    there (`force`: even so).

    Returns
    -------
    WarmupReport
        Raises nothing for a stage that fails: its status says so (the kernels of the stages before it are
        compiled all the same), and no stamp is written.
    """
    from core.config import Settings
    from worker.local import run_local

    t0 = time.perf_counter()
    stages = warm_stages(settings)
    if not stages:  # nothing to compile, and no numba to load for the stamp's name either
        return WarmupReport("the pipeline runs ingest alone", time.perf_counter() - t0, {}, None)
    stamp = stamp_path(stages)
    if stamp.exists() and not force:
        return WarmupReport(f"{stamp.name} is there", time.perf_counter() - t0, {}, stamp)
    cloud = make_warmup_cloud(np.random.default_rng(0))
    with tempfile.TemporaryDirectory(prefix="cloud2cnc-warmup-") as tmp:
        upload = Path(tmp) / "warmup.xyz"
        np.savetxt(upload, cloud, fmt="%.5f", header="x y z nx ny nz (mm): cloud2cnc's warm-up block")
        # One process: the processes a stage forks would each compile the same kernels, side by side.
        settings_1 = Settings(stage_processes=1, pipeline="", stage_plugins="")
        with open(Path(tmp) / "log.txt", "w") as stream:
            reports = run_local(upload, Path(tmp) / "job", params=_PARAMS, settings=settings_1, until=stages[-1],
                                stream=stream)
    statuses = {r.name: r.status if r.error is None or r.status == "skipped" else f"{r.status}: {r.error}"
                for r in reports}
    _call_data_dependent(stages)
    if len(statuses) == len(stages) and all(status in ("succeeded", "skipped") for status in statuses.values()):
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(f"{','.join(stages)}\n")
    return WarmupReport(None, time.perf_counter() - t0, statuses, stamp)


def _call_data_dependent(stages: list[str]) -> None:
    """Kernels a job calls only on some parts or with some parameters: the planner's foot search inside one piece
    of a surface with C0 lines (`cam.plan.gouge`), called here on a flat bicubic patch; the crease-first layout's
    collapses (`remesh.layout = "creases"`, `cam.remesh.coarse`), on an octahedron."""
    if "plan" in stages:
        from cam.spline._compiled import project_in_boxes

        knots = np.array([0.0, 0, 0, 0, 1, 1, 1, 1])
        grid = np.linspace(0.0, 1.0, 4)
        net = np.stack([*np.meshgrid(grid, grid, indexing="ij"), np.zeros((4, 4))], axis=-1)
        project_in_boxes(knots, knots, net, np.array([[0.5, 0.5, 1.0]]), np.array([[0.4, 0.4]]),
                         np.zeros((1, 2)), np.ones((1, 2)), (3, 3), 12)
    if "remesh" in stages:
        from cam.remesh._collapsekernel import collapse_short_edges, plane_quadrics

        vertices = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])
        faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
        quadric, weight = plane_quadrics(vertices, faces)
        collapse_short_edges(vertices, faces, np.ones(8, dtype=bool), np.zeros(6, dtype=np.int8),
                             np.full((6, 2), -1, dtype=np.int64), quadric, weight, np.ones(6), 0.8, 4.0 / 3.0, 0.05,
                             35.0, 8)


def run_warm_up(*, timeout_s: float = _TIMEOUT_S, stream: TextIO = sys.stderr) -> int:
    """`python -m worker.warmup` in a child process (a worker runs it before it takes work, so that its pool's
    processes, forked later, load what the child compiled), its line passed on to `stream`; the child's
    exit status, or 124 when it ran past `timeout_s` and was killed (the worker starts all the same)."""
    print("cloud2cnc warm-up: compiling the geometry kernels if this code has not yet on this machine "
          "(about a minute on two cores); jobs wait for it", file=stream, flush=True)
    try:
        done = subprocess.run([sys.executable, "-m", "worker.warmup", "--parent-pid", str(os.getpid())],
                              capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        print(f"cloud2cnc warm-up: stopped after {timeout_s:.0f} s; the first jobs compile what is left",
              file=stream, flush=True)
        return 124
    stream.write(done.stderr[-4000:])
    stream.flush()
    return done.returncode


def main(argv: list[str] | None = None) -> int:
    """`python -m worker.warmup [--force] [--parent-pid PID]`: the warm-up for this environment's settings; one
    line on stderr. With a parent pid it ends, with what it started, when that process is gone (a worker
    stopped or killed while it waits: `worker.lifeline.follow_parent`)."""
    import argparse

    from core.config import Settings
    from worker.lifeline import follow_parent

    parser = argparse.ArgumentParser(prog="python -m worker.warmup")
    parser.add_argument("--force", action="store_true", help="run the job even where its stamp is there")
    parser.add_argument("--parent-pid", type=int, help="end when this process (our parent) is gone")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.parent_pid is not None:
        follow_parent(args.parent_pid)
    report = warm_kernels(Settings(), force=args.force)
    if report.skipped:
        print(f"cloud2cnc warm-up: nothing to compile ({report.skipped})", file=sys.stderr)
        return 0
    failed = {name: status for name, status in report.stages.items() if status not in ("succeeded", "skipped")}
    print(f"cloud2cnc warm-up: compiled the kernels in {report.seconds:.1f} s"
          + (f"; stages that did not succeed: {failed} (their kernels compile in the first job)" if failed else ""),
          file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
