"""Property tests: on generated quad meshes every segmentation is a partition into valid rectangular patches."""

from __future__ import annotations

import numpy as np
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from cam.mesh.quads import quad_topology
from cam.params import SegmentParams
from cam.segment import segment_quads
from cam.segment.traces import straight_continuation, trace_line
from tests.cam.test_segment import check_partition
from tests.quadshapes import (
    quad_box,
    quad_capped_cylinder,
    quad_torus,
    quads_from_triangles,
)

FAST = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(n=st.tuples(st.integers(1, 5), st.integers(1, 5), st.integers(1, 5)),
       size=st.tuples(st.floats(1, 100), st.floats(1, 100), st.floats(1, 100)), method=st.sampled_from(["mst", "greedy"]))
def test_boxes_segment_into_their_faces(n, size, method):
    v, f = quad_box(n, size=size)
    seg = segment_quads(v, f, SegmentParams(method=method))
    assert check_partition(v, f, seg) == 5


@FAST
@given(seed=st.integers(0, 10_000), points=st.integers(5, 18), theta=st.floats(25, 85),
       remove_base=st.booleans(), method=st.sampled_from(["mst", "greedy"]))
def test_random_polyhedra_with_many_extraordinary_points(seed, points, theta, remove_base, method):
    rng = np.random.default_rng(seed)
    hull = trimesh.convex.convex_hull(rng.normal(size=(points, 3)) * rng.uniform(1, 50))
    v, f = quads_from_triangles(hull.vertices, hull.faces)
    seg = segment_quads(v, f, SegmentParams(sharp_angle_deg=theta, remove_base=remove_base, method=method))
    check_partition(v, f, seg)
    assert seg.stats["extraordinary_points"] > 0


@FAST
@given(seed=st.integers(0, 10_000), points=st.integers(4, 30), bump=st.floats(0, 5))
def test_random_open_sheets(seed, points, bump):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(size=(points, 2))
    tri = Delaunay(xy)
    v3 = np.c_[xy * 40, bump * np.sin(xy[:, 0] * 6)]
    v, f = quads_from_triangles(v3, tri.simplices)
    seg = segment_quads(v, f, SegmentParams(remove_base=False))
    check_partition(v, f, seg)


@FAST
@given(k=st.integers(1, 4), rings=st.integers(1, 3), layers=st.integers(1, 6), height=st.floats(1, 80),
       remove_base=st.booleans())
def test_capped_cylinders(k, rings, layers, height, remove_base):
    v, f = quad_capped_cylinder(k, rings, layers, radius=20.0, height=height)
    seg = segment_quads(v, f, SegmentParams(remove_base=remove_base))
    check_partition(v, f, seg)


@FAST
@given(nu=st.integers(3, 30), nv=st.integers(3, 30))
def test_torus_lines_close_and_every_line_ends(nu, nv):
    v, f = quad_torus(nu, nv)
    topo = quad_topology(f, len(v))
    straight = straight_continuation(topo)
    lengths = set()
    for h in range(0, 4 * len(f), max(1, len(f) // 7)):
        t = trace_line(topo, straight, h, stop=lambda g: False)
        assert t.reason == "self" and t.end == t.vertices[0]
        lengths.add(len(t.half_edges))
    assert lengths <= {nu, nv}
    seg = segment_quads(v, f, SegmentParams(remove_base=False))
    check_partition(v, f, seg)
