"""The self-check across gaps in the scan (cam.reconstruct.fidelity): the true surface across an unscanned
band passes as bridged; a sheet over a face or a fin out of an edge, as far from the cloud, does not.

The meshes are the true box, finely subdivided, so that the only thing measured is the rule: where the
band is wider than twice the allowance, the true surface is farther than the allowance from every point.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from cam.reconstruct.fidelity import BRIDGE_TOLERANCES, measure_fidelity

SIZE = np.array([60.0, 40.0, 20.0])
# The band's direction crosses each face at the same slant, so that it is equally wide on all of them,
# and its middle (x + y + z = 10 mm) passes 5.8 mm from the nearest corners (x + y + z = 0 or 20): a
# corner left unscanned is outside the scanned faces' hull by about 0.8 of its distance from them, and
# passes only to about 1.2 allowances (see cam.reconstruct.fidelity).
DIAGONAL = np.ones(3) / np.sqrt(3.0)
MIDDLE = 10.0 / np.sqrt(3.0)


def _box_mesh(max_edge: float = 0.5) -> trimesh.Trimesh:
    box = trimesh.creation.box(SIZE)
    return trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=max_edge))


def _box_cloud(n: int, rng: np.random.Generator, band: float = 0.0) -> np.ndarray:
    """n points uniform on the box's surface, less those within band / 2 of the plane x + y + z = 10 mm
    (an unscanned band ``band`` mm wide along DIAGONAL)."""
    box = trimesh.creation.box(SIZE)
    area = box.area_faces / box.area
    tri = rng.choice(len(box.faces), size=n, p=area)
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    a, b, c = (box.vertices[box.faces[tri, j]] for j in range(3))
    pts = a + u[:, None] * (b - a) + v[:, None] * (c - a)
    return pts[np.abs(pts @ DIAGONAL - MIDDLE) >= band / 2.0]


def test_the_true_surface_across_an_unscanned_band_passes_as_bridged():
    rng = np.random.default_rng(0)
    mesh = _box_mesh()
    whole = measure_fidelity(mesh.vertices, mesh.faces, _box_cloud(20_000, rng))
    assert whole.ok and whole.bridged_vertices == 0 and whole.mesh_to_cloud < whole.tolerance
    # A band 1.7 allowances wide along DIAGONAL is 2.1 allowances wide on each face (sqrt(3/2) times):
    # its middle is 1.04 allowances from the nearest point on a face and more on an edge it crosses
    # (sqrt(3) times as wide along the edge; 1.28 measured), within the bridge's bound.
    band = 1.7 * whole.tolerance
    pts = _box_cloud(20_000, rng, band)
    fid = measure_fidelity(mesh.vertices, mesh.faces, pts)
    to_cloud = cKDTree(pts).query(mesh.vertices)[0]
    assert fid.tolerance < fid.mesh_to_cloud <= BRIDGE_TOLERANCES * fid.tolerance
    assert fid.ok and fid.far_vertices == 0
    assert fid.bridged_vertices == int(np.sum(to_cloud > fid.tolerance)) > 0
    assert fid.bridge_distance == fid.mesh_to_cloud
    assert abs(np.dot(fid.bridged_at, DIAGONAL) - MIDDLE) < band / 2.0  # the farthest lies in the band


def _with(mesh: trimesh.Trimesh, extents, centre) -> trimesh.Trimesh:
    """``mesh`` and a thin box of ``extents`` at ``centre``, finely subdivided: a planted sheet."""
    sheet = trimesh.creation.box(extents)
    sheet.apply_translation(centre)
    sheet = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(sheet.vertices, sheet.faces, max_edge=0.5))
    return trimesh.util.concatenate([mesh, sheet])


def test_a_sheet_over_a_face_or_a_fin_out_of_an_edge_is_refused_within_the_bridge_s_bound():
    """Both are as far from the cloud as a bridge may be, but outside the hull of the points round them by
    about that distance: not a gap in the scan. A scan's isolated outliers round a sheet would put it
    inside the points' hull: they take no part in it."""
    rng = np.random.default_rng(1)
    mesh = _box_mesh()
    pts = _box_cloud(20_000, rng)
    tolerance = measure_fidelity(mesh.vertices, mesh.faces, pts).tolerance
    out = 1.25 * tolerance
    top = SIZE[2] / 2.0
    sheet = _with(mesh, (10.0, 10.0, 0.2), (0.0, 0.0, top + out))
    fin = _with(mesh, (out, 10.0, 0.2), (SIZE[0] / 2.0 + out / 2.0, 0.0, top - 0.1))
    outliers = rng.uniform(-SIZE / 2.0 - 10.0, SIZE / 2.0 + 10.0, size=(len(pts) // 100, 3))
    cases = {"sheet over the top face": (sheet, pts), "fin out of the top face's edge": (fin, pts),
             "sheet over the top face, 1 % outliers": (sheet, np.vstack([pts, outliers]))}
    for name, (both, cloud) in cases.items():
        fid = measure_fidelity(both.vertices, both.faces, cloud)
        beyond = int(np.sum(cKDTree(cloud).query(both.vertices)[0] > fid.tolerance))
        assert fid.tolerance < fid.mesh_to_cloud <= BRIDGE_TOLERANCES * fid.tolerance, name
        assert not fid.ok and fid.far_vertices == beyond > 0 and fid.bridged_vertices == 0, name


def test_mesh_raw_s_header_says_where_the_surface_was_guessed():
    from worker.stages.reconstruct import _fidelity_comment

    rng = np.random.default_rng(0)
    mesh = _box_mesh()
    tolerance = measure_fidelity(mesh.vertices, mesh.faces, _box_cloud(20_000, rng)).tolerance
    fid = measure_fidelity(mesh.vertices, mesh.faces, _box_cloud(20_000, rng, 1.7 * tolerance))
    comment = _fidelity_comment(fid.report())
    x, y, z = fid.bridged_at
    assert (f"{fid.bridged_vertices} vertices bridge a gap in the scan, up to {fid.bridge_distance:.3g} mm from it "
            f"near ({x:.1f}, {y:.1f}, {z:.1f}): surface guessed, not scanned") in comment
    assert "bridge" not in _fidelity_comment(measure_fidelity(mesh.vertices, mesh.faces, _box_cloud(20_000, rng))
                                             .report())
