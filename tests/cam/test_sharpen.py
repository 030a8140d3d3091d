"""Crease sharpening after marching cubes (cam.reconstruct.sharpen) on exact signed distances.

Marching cubes of an exact box distance bevels every edge over about a cell; the
sharpened mesh must put the bevel's vertices back on the box's faces and its new
vertices on the box's edges, stay closed, and leave smooth surfaces alone.
"""

from __future__ import annotations

import numpy as np
import pytest
from skimage.measure import marching_cubes

from cam.reconstruct.extract import is_watertight
from cam.reconstruct.sharpen import sharpen_creases

H = 0.04  # lattice cell
HALF = np.array([1.03, 0.81, 0.57])  # box half-sizes, off the lattice so every edge is bevelled


def _extract(sdf, lo=-1.5, hi=1.5):
    axis = np.arange(lo, hi, H)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    v, f, _, _ = marching_cubes(sdf(x, y, z), 0.0, spacing=(H, H, H), gradient_direction="ascent")
    return v + axis[0], f.astype(np.int64)


def _box_sdf(x, y, z, half=HALF):
    q = np.stack([np.abs(x), np.abs(y), np.abs(z)], axis=-1) - np.asarray(half)
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def _face_data(v, f):
    t = v[f]
    cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    return cross / (2.0 * area[:, None]), area, t.mean(axis=1)


def _edge_band_share(v, f, within_deg=1.0):
    """Area share of the faces along the box's edges (away from corners) whose normal is an axis."""
    normal, area, centre = _face_data(v, f)
    off_axis = np.degrees(np.arccos(np.clip(np.abs(normal).max(axis=1), -1.0, 1.0)))
    gap = np.abs(np.abs(centre) - HALF)
    band = ((gap < 2 * H).sum(axis=1) == 2) & ((gap < 16 * H).sum(axis=1) < 3)
    return area[band & (off_axis < within_deg)].sum() / area[band].sum()


def test_box_edges_come_back_sharp_and_closed():
    v, f = _extract(_box_sdf)
    v2, f2, report = sharpen_creases(v, f, feature_size=2 * H)
    assert report["moved"] > 0 and report["split"] > 0
    assert len(v2) == len(v) + report["split"]
    assert is_watertight(f2)
    # Moved vertices land on a face of the box (they started on the bevel, up to a cell inside).
    moved = np.linalg.norm(v2[: len(v)] - v, axis=1) > 0
    assert moved.any()
    assert np.abs(np.abs(v2[: len(v)][moved]) - HALF).min(axis=1).max() < 1e-12
    # Crease points lie on an edge of the box (two coordinates at the half-sizes) away from the
    # corners, where a third plane enters the vertex's neighbourhood and the bevel is kept.
    new = v2[len(v):]
    gap = np.abs(np.abs(new) - HALF)
    away = (gap < 8 * H).sum(axis=1) < 3
    assert away.sum() > 100
    assert np.sort(gap[away], axis=1)[:, 1].max() < 1e-12
    # The bevel's tilted faces are gone from the edges: most of the band now faces an axis.
    before, after = _edge_band_share(v, f), _edge_band_share(v2, f2)
    assert before < 0.7 and after > 0.85
    # No sliver or turned-over face was made.
    _, area, _ = _face_data(v2, f2)
    assert area.min() > 1e-3 * _face_data(v, f)[1].min()


def _sharp_edge_degrees(v, f, angle_deg=60.0):
    """How many edges whose faces' normals differ by over `angle_deg` meet at each vertex (v,)."""
    normal, _, _ = _face_data(v, f)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    face = np.tile(np.arange(len(f)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, face = edges[order], face[order]
    # A closed manifold: each edge appears twice, its two faces side by side once sorted.
    pairs = edges[0::2]
    cos = (normal[face[0::2]] * normal[face[1::2]]).sum(axis=1)
    sharp = pairs[cos < np.cos(np.radians(angle_deg))]
    return np.bincount(sharp.ravel(), minlength=len(v))


@pytest.mark.parametrize("half", [tuple(HALF), (0.97, 0.73, 0.61), (1.01, 0.79, 0.59)])
def test_box_edges_become_simple_chains_of_mesh_edges(half):
    """Away from the corners, the sharp mesh edges lie on the box's edges in simple chains.

    Every vertex there with a sharp edge has exactly two. A right-angle crease's split point lies on the
    circle over the edge it splits, and a bound of half the edge's length from its midpoint refused a
    share of them by rounding alone; and a vertex left a fraction of a cell beside the crease made a notch.
    Both left spurs and gaps (242, 282 and 73 vertices without two sharp edges on these boxes), which
    QuadriFlow's sharp edges then follow.
    """
    half = np.asarray(half)
    v, f = _extract(lambda x, y, z: _box_sdf(x, y, z, half))
    v2, f2, _ = sharpen_creases(v, f, feature_size=2 * H)
    assert is_watertight(f2)
    degree = _sharp_edge_degrees(v2, f2)
    gap = np.abs(np.abs(v2) - half)
    away = (gap < 8 * H).sum(axis=1) < 3
    on_chain = away & (degree > 0)
    assert on_chain.sum() > 200  # about one per lattice cell along the edges
    assert np.array_equal(degree[on_chain], np.full(on_chain.sum(), 2))
    assert np.sort(gap[on_chain], axis=1)[:, 1].max() < 1e-12  # on a box edge


@pytest.mark.parametrize("half", [tuple(HALF), (0.97, 0.73, 0.61), (1.01, 0.79, 0.59)])
def test_edges_are_sharp_up_to_three_cells_from_the_corners(half):
    """Along an edge up to a corner, the two faces' planes are the nearest ones: the bevel is undone there too.

    The planes' neighbourhood reaches several feature sizes, so a third face enters it well before the
    corner; taken whole it left the last four to eight cells of every edge bevelled (a quarter of a cell
    deep on two of these boxes). Every vertex farther than three cells from the corners lies on the box.
    """
    half = np.asarray(half)
    v, f = _extract(lambda x, y, z: _box_sdf(x, y, z, half))
    v2, f2, _ = sharpen_creases(v, f, feature_size=2 * H)
    assert is_watertight(f2)
    depth = (half - np.abs(v2)).min(axis=1)  # below the nearest face of the box
    from_corner = np.linalg.norm(np.abs(v2) - half, axis=1)
    assert (from_corner <= 3 * H).sum() <= 8 * 30  # about 25 vertices at each corner are left as they are
    assert depth[from_corner > 3 * H].max() < 1e-12
    _, area, _ = _face_data(v2, f2)
    assert area.min() > 1e-3 * _face_data(v, f)[1].min()


def test_vertices_next_to_a_crease_are_moved_onto_it():
    """Where the box's edges pass a quarter of a cell from the lattice, vertices next to them are moved
    onto the edge, not split beside it; no face turns over or becomes a sliver."""
    v, f = _extract(_box_sdf)
    v2, f2, report = sharpen_creases(v, f, feature_size=2 * H)
    # No lattice vertex lies on a box edge (the edges are off the lattice): those there now were snapped.
    gap = np.abs(np.abs(v2[: len(v)]) - HALF)
    on_edge = np.sort(gap, axis=1)[:, 1] < 1e-12
    assert not (np.sort(np.abs(np.abs(v) - HALF), axis=1)[:, 1] < 1e-12).any()
    assert 100 < on_edge.sum() <= report["snapped"]
    assert np.abs(v2[: len(v)][on_edge] - v[on_edge]).max() < H  # a fraction of a cell along its face
    _, area, _ = _face_data(v2, f2)
    assert area.min() > 1e-3 * _face_data(v, f)[1].min()


def test_winding_and_volume_are_kept():
    v, f = _extract(_box_sdf)
    v2, f2, _ = sharpen_creases(v, f, feature_size=2 * H)

    def volume(v, f):
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0

    true = 8.0 * HALF.prod()
    assert np.sign(volume(v2, f2)) == np.sign(volume(v, f))
    # The bevels cut material off every edge; restoring them brings the volume closer to the box's.
    assert abs(abs(volume(v2, f2)) - true) < abs(abs(volume(v, f)) - true)


@pytest.mark.parametrize("radius", [0.15, 1.2])  # tighter than the planes' reach, and looser
def test_smooth_surfaces_are_left_alone(radius):
    """A sphere is untouched; on a capped cylinder only the rims move, never the side."""
    v, f = _extract(lambda x, y, z: np.sqrt(x**2 + y**2 + z**2) - radius)
    v2, f2, report = sharpen_creases(v, f, feature_size=2 * H)
    assert report == {"moved": 0, "split": 0, "snapped": 0}
    assert np.array_equal(v2, v) and np.array_equal(f2, f)

    v, f = _extract(lambda x, y, z: np.maximum(np.hypot(x, y) - radius, np.abs(z) - 1.0))
    v2, _, _ = sharpen_creases(v, f, feature_size=2 * H)
    side = np.abs(v[:, 2]) < 1.0 - 4 * H
    assert np.array_equal(v2[: len(v)][side], v[side])


def test_bad_feature_size_is_refused():
    v, f = _extract(_box_sdf)
    with pytest.raises(ValueError, match="feature_size"):
        sharpen_creases(v, f, feature_size=0.0)


def test_check_cancel_stops_the_work_between_phases():
    v, f = _extract(_box_sdf)
    calls = []

    class Stop(Exception):
        pass

    def check_cancel():
        calls.append(None)
        raise Stop

    with pytest.raises(Stop):
        sharpen_creases(v, f, feature_size=2 * H, check_cancel=check_cancel)
    assert len(calls) == 1
