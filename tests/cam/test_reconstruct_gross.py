"""Reconstruction without gross errors (issue 36): thin walls, through holes, clouds without normals,
and the self-check that refuses a mesh straying from its own cloud.

The parts are CSG solids (manifold3d) sampled with Gaussian noise of sigma = 0.25 % of the bounding-box
diagonal and no normals, as a scanner gives them. Before the fix, the normal orientation crossed the
2 mm walls and the 2 mm gap under a boss, so half a wall came out inside out and the field grew a
sheet of surface tens of millimetres from the part (Hausdorff 26-32 % of the diagonal).

The bound, for every part: Hausdorff distance (both directions) from the reconstruction to the true
surface <= 2 % of the diagonal, i.e. 8 sigma. The noisy points themselves reach about 4.3 sigma (1.1 %)
from the surface at these sizes, and the field's finest cell (0.5 mm here, 0.65 % of the diagonal)
rounds the sharp edges by about a cell; screened Poisson (depth 9) on the same kind of cloud, 50k
points, measured 0.72 % (bench/reconstruct.py), and ours 0.8-1.1 %. The distances are measured from
200,000 samples of each surface to the nearest of 200,000 samples of the other: an upper bound on the
exact distance, by at most the samples' spacing (~0.2 mm).

Settings: 50,000 points (the pipeline's design point; at 20,000 the noise leaves single bumps of 2-2.7 %
near the boss's rim), the `fast` preset with a finest grid of 128 cells and marching cubes at 192 (the
default is 192 and 384), so each reconstruction takes about a minute on two cores.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from cam import GeometryError
from cam.io import read_ply, write_ply_points
from cam.params import ReconstructParams
from cam.reconstruct import FidelityError, reconstruct_surface
from cam.reconstruct.fidelity import (
    MIN_CLUSTER,
    TOLERANCE_NOISE,
    TOLERANCE_SPACINGS,
    measure_fidelity,
)
from tests.cam.test_reconstruct import cube_cloud

manifold3d = pytest.importorskip("manifold3d")

NOISE = 0.0025  # sigma, share of the diagonal
BOUND = 0.02  # Hausdorff bound, share of the diagonal (8 sigma)
SETTINGS = {"grid_cells": 128, "resolution": 192, "max_faces": None, "seed": 0}


def _mesh(solid) -> trimesh.Trimesh:
    m = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(m.vert_properties, dtype=np.float64)[:, :3],
                           np.asarray(m.tri_verts, dtype=np.int64), process=True)


def coverage_bracket() -> trimesh.Trimesh:
    """bench/part_coverage.py's bracket: 60 x 40 x 40, an 8 mm base and upright, a boss with a 10 mm
    through hole (a solid of genus 1)."""
    from manifold3d import Manifold

    base = Manifold.cube([60.0, 40.0, 8.0])
    upright = Manifold.cube([8.0, 40.0, 40.0])
    boss = Manifold.cylinder(14.0, 9.0, circular_segments=96).translate([38.0, 20.0, 0.0])
    hole = Manifold.cylinder(30.0, 5.0, circular_segments=96).translate([38.0, 20.0, -5.0])
    return _mesh(base + upright + boss - hole)


def wall_bracket(wall: float) -> trimesh.Trimesh:
    """A 60 x 40 x 30 L-bracket with walls `wall` thick; a 10 mm hole through the upright, in a boss
    that stands 6 mm off it towards the base and ends (30 - wall) / 2 - 9 mm above the base's top
    (2 mm at wall = 8): a solid of genus 1."""
    from manifold3d import Manifold

    height = 30.0
    axis_z = (height + wall) / 2.0
    base = Manifold.cube([60.0, 40.0, wall])
    upright = Manifold.cube([wall, 40.0, height])
    boss = Manifold.cylinder(wall + 6.0, 9.0, circular_segments=96).rotate([0.0, 90.0, 0.0])
    hole = Manifold.cylinder(80.0, 5.0, circular_segments=96).rotate([0.0, 90.0, 0.0])
    return _mesh(base + upright + boss.translate([0.0, 20.0, axis_z]) - hole.translate([-20.0, 20.0, axis_z]))


def noisy_cloud(mesh: trimesh.Trimesh, n: int, seed: int) -> np.ndarray:
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    sigma = NOISE * float(np.linalg.norm(mesh.extents))
    return pts + np.random.default_rng(seed + 1).normal(size=pts.shape) * sigma


def hausdorff_share(vertices: np.ndarray, faces: np.ndarray, truth: trimesh.Trimesh) -> float:
    """Both directions' largest distance between the surfaces, from dense samples, over the true diagonal."""
    rec = trimesh.Trimesh(vertices, faces, process=False)
    a, _ = trimesh.sample.sample_surface(rec, 200_000, seed=11)
    b, _ = trimesh.sample.sample_surface(truth, 200_000, seed=12)
    there = cKDTree(b).query(a, workers=2)[0].max()
    back = cKDTree(a).query(b, workers=2)[0].max()
    return float(max(there, back) / np.linalg.norm(truth.extents))


def genus(vertices: np.ndarray, faces: np.ndarray) -> int:
    """Handles of a closed, connected surface, from its Euler characteristic V - E + F = 2 - 2g."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    euler = len(np.unique(faces)) - len(np.unique(edges, axis=0)) + len(faces)
    return (2 - euler) // 2


def reconstruct_without_normals(truth: trimesh.Trimesh, n: int = 50_000, seed: int = 0):
    result = reconstruct_surface(noisy_cloud(truth, n, seed), None, ReconstructParams(**SETTINGS), threads=2)
    mesh = trimesh.Trimesh(result.vertices, result.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.body_count == 1
    assert result.report["fidelity"]["ok"]
    return result


# --- gross errors: each cause found, with the Hausdorff bound ------------------------------------

def test_thin_walls_are_not_turned_inside_out():
    """2 mm walls at sigma 0.2 mm: the neighbourhoods the noisy cloud needs (about 30 points, 1.5 mm)
    reach the opposite face; the orientation must not copy its side across."""
    truth = wall_bracket(2.0)
    result = reconstruct_without_normals(truth)
    assert result.report["normals"]["flipped_share"] < 0.01
    assert hausdorff_share(result.vertices, result.faces, truth) <= BOUND


def test_through_hole_stays_open_and_close():
    """bench/part_coverage.py's bracket: the hole through boss and base stays a hole (genus 1)."""
    truth = coverage_bracket()
    result = reconstruct_without_normals(truth)
    assert genus(result.vertices, result.faces) == 1
    assert hausdorff_share(result.vertices, result.faces, truth) <= BOUND


def test_bracket_without_normals_has_no_spurious_sheet():
    """The issue's part: 60 x 40 x 30, 8 mm walls, a hole through the upright and a boss 2 mm above the
    base; its normals used to flip across that gap and the field grew a sheet 25 mm from the part."""
    truth = wall_bracket(8.0)
    result = reconstruct_without_normals(truth, seed=1)
    assert genus(result.vertices, result.faces) == 1
    assert hausdorff_share(result.vertices, result.faces, truth) <= BOUND


@pytest.mark.parametrize(("wall", "noise"), [(0.7, 0.001), (1.0, 0.0025)])
def test_walls_thinner_than_a_neighbourhood_keep_their_side(wall, noise):
    """An open tray 40 x 40 x 8 whose walls and floor are thinner than a neighbourhood of the noisy cloud
    (abc8 and abc9 of the bench corpus are such parts): the estimated normals came out inside out on about
    half the tray, and the field put a sheet 9.4 mm (16 % of the diagonal) from the cloud, which the
    self-check refused. The outside of the cloud now says which side is out (tests/cam/test_normals_outside.py).
    0.7 mm walls at 0.25 % noise (sigma 0.14 mm) are refused with a message: see the next test."""
    from tests.cam.test_normals_outside import sampled, tray

    truth = tray(wall)
    pts, _ = sampled(truth, noise)
    result = reconstruct_surface(pts, None, ReconstructParams(**SETTINGS), threads=2)
    mesh = trimesh.Trimesh(result.vertices, result.faces, process=False)
    assert mesh.is_watertight and mesh.body_count == 1 and result.report["fidelity"]["ok"]
    assert result.report["normals"]["orientation"] == "outside"
    assert hausdorff_share(result.vertices, result.faces, truth) <= BOUND


def test_walls_too_thin_for_the_noise_are_refused_with_a_message():
    """0.7 mm walls at sigma 0.14 mm: the two faces' samples overlap and no orientation is consistent; the
    stage says so and what to do instead of passing a surface turned inside out."""
    from tests.cam.test_normals_outside import sampled, tray

    pts, _ = sampled(tray(0.7), 0.0025)
    with pytest.raises(GeometryError, match="cannot be oriented consistently.*upload oriented normals"):
        reconstruct_surface(pts, None, ReconstructParams(**SETTINGS), threads=2)


def test_low_noise_bracket_has_no_lump_at_its_corners():
    """The same bracket at a tenth of a per cent of noise, the pipeline's own settings: the field used to
    bulge 4.3 mm out of the upright's convex corner (plane distances blended by squared distance, which
    far from the cloud leaves only the nearest point's plane, and at a corner or edge that is as often
    the other face's), so the self-check refused the cleaner cloud while it passed the noisier one."""
    truth = wall_bracket(8.0)
    pts, _ = trimesh.sample.sample_surface(truth, 50_000, seed=0)
    pts = pts + np.random.default_rng(1).normal(size=pts.shape) * 0.001 * float(np.linalg.norm(truth.extents))
    result = reconstruct_surface(pts, None, ReconstructParams(max_faces=None, seed=0), threads=2)
    assert result.report["fidelity"]["ok"]
    assert genus(result.vertices, result.faces) == 1
    assert hausdorff_share(result.vertices, result.faces, truth) <= BOUND


# --- the self-check ------------------------------------------------------------------------------

def _sphere_cloud(n: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """n points spread evenly on a sphere (Fibonacci spiral), with outward normals."""
    i = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1.0 - 2.0 * i / n), np.pi * (1.0 + 5.0**0.5) * i
    v = np.column_stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])
    return radius * v, v


def test_fidelity_measures_a_true_mesh_as_close_and_a_planted_sheet_as_far():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=20.0)
    pts, _ = _sphere_cloud(5000, 20.0)
    good = measure_fidelity(sphere.vertices, sphere.faces, pts)
    spacing = float(np.median(cKDTree(pts).query(pts, k=2)[0][:, 1]))
    assert good.ok and good.far_vertices == 0 and good.far_points == 0
    assert good.spacing == pytest.approx(spacing) and good.noise < 0.05 * spacing
    assert good.tolerance == pytest.approx(TOLERANCE_SPACINGS * spacing + TOLERANCE_NOISE * good.noise)
    # Vertices on the sphere lie within the cloud's gaps of a point; the points lie on the mesh but within
    # the tolerance the distance is to the nearest vertex, an upper bound of at most an edge.
    assert good.mesh_to_cloud < spacing and good.cloud_to_mesh <= sphere.edges_unique_length.max()

    # A planted sheet 15 mm off the sphere: the surface where nothing was scanned.
    sheet = trimesh.creation.box((10.0, 10.0, 0.5))
    sheet.apply_translation((0.0, 0.0, 35.0))
    both = trimesh.util.concatenate([sphere, sheet])
    bad = measure_fidelity(both.vertices, both.faces, pts)
    assert not bad.ok and bad.far_vertices == len(sheet.vertices)
    assert bad.mesh_to_cloud == pytest.approx(np.linalg.norm(sheet.vertices, axis=1).max() - 20.0, abs=0.5)
    assert bad.far_vertices_at[2] > 34.0


def test_fidelity_allows_isolated_outliers_but_not_a_cluster():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=20.0)
    pts, _ = _sphere_cloud(5000, 20.0)
    rng = np.random.default_rng(0)
    lone = rng.uniform(-40.0, 40.0, size=(20, 3))
    lone = lone[np.linalg.norm(lone, axis=1) > 32.0]  # well beyond the tolerance (about 3 mm) from the sphere
    with_outliers = measure_fidelity(sphere.vertices, sphere.faces, np.vstack([pts, lone]))
    assert with_outliers.ok and with_outliers.outliers == len(lone) and with_outliers.far_points == 0
    cluster = np.array([0.0, 0.0, 35.0]) + rng.normal(size=(MIN_CLUSTER + 5, 3)) * 0.3
    with_cluster = measure_fidelity(sphere.vertices, sphere.faces, np.vstack([pts, cluster]))
    assert not with_cluster.ok and with_cluster.far_points == len(cluster)
    assert with_cluster.cloud_to_mesh == pytest.approx(np.linalg.norm(cluster, axis=1).max() - 20.0, abs=0.1)


FAST = {"iterations": 150, "batch_size": 2048, "grid_cells": 48, "resolution": 96, "max_faces": None, "seed": 0}


def test_normals_inside_out_on_one_face_are_refused_with_a_message():
    """A planted failure: an export that flipped the top face's normals makes the field wrong inside the
    cube; the mesh then holds surface 16 mm from every point, and the stage must say so."""
    pts, nrm = cube_cloud(6000, 40.0, np.random.default_rng(3))
    top = nrm[:, 2] > 0  # the +z face
    nrm[top] *= -1.0
    with pytest.raises(FidelityError, match="strays up to .* from every scanned point") as caught:
        reconstruct_surface(pts, nrm, ReconstructParams(**FAST), threads=2)
    message = str(caught.value)
    assert "normals inside out" in message and "Upload the cloud with oriented normals" in message
    assert caught.value.fidelity.mesh_to_cloud > 0.15 * caught.value.fidelity.diagonal


def test_stage_refuses_a_cloud_whose_stray_cluster_the_surface_leaves_out(tmp_path):
    """A planted failure through the stage: 40 points in a 1.5 mm ball 25 mm above the cube (under the
    1 % of the cloud a surface component must carry, so the extraction drops their blob)."""
    from core.params import JobParams
    from worker.context import StageContext
    from worker.stages.reconstruct import run_reconstruct

    rng = np.random.default_rng(3)
    pts, _ = cube_cloud(6000, 40.0, rng)
    ball = rng.normal(size=(40, 3))
    stray = ball / np.linalg.norm(ball, axis=1, keepdims=True) * 1.5 + [0.0, 0.0, 45.0]
    cloud = write_ply_points(tmp_path / "cloud.ply", np.vstack([pts, stray]), None)
    out = tmp_path / "out"
    out.mkdir()
    ctx = StageContext(job_id="j", stage="reconstruct", inputs={"cloud.ply": cloud}, out_dir=out,
                       params=JobParams.model_validate({"reconstruct": FAST}), settings={"blas_threads": 2})
    with pytest.raises(GeometryError, match=r"40 scanned points lie up to .* from the reconstructed surface, "
                                            r"farthest near \(.*, 4\d\.\d\)") as caught:
        run_reconstruct(ctx)
    assert "crop stray points" in str(caught.value)
    assert not ctx.output("mesh_raw.ply").exists()


def test_stage_writes_the_measured_distance_into_mesh_raw(tmp_path):
    from core.params import JobParams
    from worker.context import StageContext
    from worker.stages.reconstruct import run_reconstruct

    pts, nrm = _sphere_cloud(3000, 20.0)
    cloud = write_ply_points(tmp_path / "cloud.ply", pts + 5.0, nrm)
    out = tmp_path / "out"
    out.mkdir()
    ctx = StageContext(job_id="j", stage="reconstruct", inputs={"cloud.ply": cloud}, out_dir=out,
                       params=JobParams.model_validate({"reconstruct": FAST}), settings={"blas_threads": 2})
    path = run_reconstruct(ctx)["mesh_raw.ply"]
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "comment fidelity: every vertex within" in header and "allowed" in header
    mesh = read_ply(path)
    within = float(header.split("every vertex within ")[1].split(" mm")[0])
    assert cKDTree(pts + 5.0).query(mesh.points)[0].max() == pytest.approx(within, rel=1e-2)
