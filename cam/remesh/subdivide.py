"""Fill a coarse quad layout with grids of quads that meet along every coarse edge.

Each coarse edge is cut into its count of pieces (:mod:`cam.remesh.quantize`): along its chain, by arc length, for
an edge on a crease (so the crease is a path of quad edges, its points on the crease), else along the chord,
projected onto the region. A coarse quad becomes a grid (Coons interpolation of its four sides, projected onto
its region). Every point is then moved towards its neighbours' centre along the surface a few times, the points on
creases staying where they are, so that the grids of neighbouring coarse quads blend.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.remesh.coarse import CoarseMesh
from cam.remesh.features import CreaseFeatures
from cam.remesh.relax import (
    face_normals,
    neighbour_centres,
    slide_on_surface,
    undo_turned,
)

__all__ = ["QuadLayout", "subdivide_layout"]

# Smoothing rounds of the finished layout and the share of the way to the neighbours' centre per round.
_SMOOTH_ROUNDS = 30
_SMOOTH_STEP = 0.5


@dataclass(frozen=True, eq=False)
class QuadLayout:
    """A quad mesh made from a coarse layout.

    Attributes
    ----------
    vertices : (n, 3) float64
        mm, on the part's surface.
    quads : (m, 4) int64
        Counter-clockwise like the part's triangles.
    on_crease : (n,) bool
        Vertices on a crease chain (its points and corners).
    vertex_region : (n,) int64
        The region of the part each vertex lies in (one of them for a vertex on a crease).
    """

    vertices: np.ndarray
    quads: np.ndarray
    on_crease: np.ndarray
    vertex_region: np.ndarray


class _Builder:
    """The layout's points (a buffer that doubles as it fills), their regions, and its quads as they are made."""

    def __init__(self, coarse: CoarseMesh, features: CreaseFeatures):
        self.coarse = coarse
        self.features = features
        n = len(coarse.vertices)
        self.buffer = np.empty((max(16, 8 * n), 3))
        self.buffer[:n] = coarse.vertices
        self.region = np.full(len(self.buffer), -1, dtype=np.int64)
        self.crease = np.zeros(len(self.buffer), dtype=bool)
        self.crease[:n] = coarse.vertex_kind != 0
        self.count = n
        self.faces: list[np.ndarray] = []
        self.sides: dict[tuple[int, int], np.ndarray] = {}

    def add(self, points: np.ndarray, region: int, on_crease: bool = False) -> np.ndarray:
        while self.count + len(points) > len(self.buffer):
            grow = len(self.buffer)
            self.buffer = np.concatenate([self.buffer, np.empty((grow, 3))])
            self.region = np.concatenate([self.region, np.full(grow, -1, dtype=np.int64)])
            self.crease = np.concatenate([self.crease, np.zeros(grow, dtype=bool)])
        ids = np.arange(self.count, self.count + len(points))
        self.buffer[ids], self.region[ids], self.crease[ids] = points, region, on_crease
        self.count += len(points)
        return ids

    def point(self, ids: np.ndarray) -> np.ndarray:
        return self.buffer[ids]

    def side(self, u: int, v: int) -> np.ndarray:
        """Vertex ids from u to v along the coarse edge (u, v)."""
        key = (min(u, v), max(u, v))
        ids = self.sides[key]
        return ids if u == key[0] else ids[::-1]


def subdivide_layout(coarse: CoarseMesh, features: CreaseFeatures, edges: np.ndarray, counts: np.ndarray
                     ) -> QuadLayout:
    """The quad mesh of a coarse quad layout.

    Parameters
    ----------
    coarse : CoarseMesh
        The coarse quads (``faces`` (q, 4)), whose vertices are the layout's corners.
    features : CreaseFeatures
        The part's triangle mesh, chains and regions.
    edges, counts
        The coarse edges (sorted vertex pairs, (e, 2)) and the quad edges each is cut into
        (`cam.remesh.quantize.quantize_edge_counts`).
    """
    build = _Builder(coarse, features)
    creases = coarse.crease_edges()
    edge_region = {}
    for face, r in zip(coarse.faces.tolist(), coarse.face_region.tolist(), strict=True):
        for j in range(4):
            a, b = face[j], face[(j + 1) % 4]
            edge_region[(min(a, b), max(a, b))] = r
    for key, n in zip(map(tuple, edges.tolist()), counts.tolist(), strict=True):
        _cut_edge(build, key, n, creases.get(key), edge_region[key])
    for face, r in zip(coarse.faces.tolist(), coarse.face_region.tolist(), strict=True):
        v0, v1, v2, v3 = face
        _grid(build, build.side(v0, v1), build.side(v3, v2), build.side(v0, v3), build.side(v1, v2), r)
    vertices = build.buffer[:build.count].copy()
    region = build.region[:build.count].copy()
    on_crease = build.crease[:build.count].copy()
    quads = np.concatenate(build.faces).astype(np.int64)
    # a coarse vertex takes the region of a quad it is a corner of
    region[coarse.faces.ravel()] = np.repeat(coarse.face_region, 4)
    vertices = _smooth(vertices, quads, on_crease, region, features)
    return QuadLayout(vertices=vertices, quads=quads, on_crease=on_crease, vertex_region=region)


def _cut_edge(build: _Builder, key: tuple[int, int], n: int, crease: tuple[int, float, float] | None,
              region: int) -> None:
    a, b = key
    if n <= 1:
        build.sides[key] = np.array([a, b], dtype=np.int64)
        return
    t = np.arange(1, n) / n
    if crease is not None:
        chain, arc_a, arc_b = crease
        points = build.features.chain_points(chain, arc_a + t * (arc_b - arc_a))
        ids = build.add(points, region, on_crease=True)
    else:
        pa, pb = build.coarse.vertices[a], build.coarse.vertices[b]
        points = pa[None] + t[:, None] * (pb - pa)[None]
        points = build.features.project(points, np.full(len(points), region))[0]
        ids = build.add(points, region)
    build.sides[key] = np.concatenate([[a], ids, [b]])


def _grid(build: _Builder, bottom: np.ndarray, top: np.ndarray, left: np.ndarray, right: np.ndarray,
          region: int) -> None:
    """A grid of quads inside four sides given as vertex ids: bottom runs q0 → q1, top q3 → q2, left q0 → q3,
    right q1 → q2 (q0..q3 counter-clockwise)."""
    nu, nv = len(bottom) - 1, len(left) - 1
    ids = np.empty((nu + 1, nv + 1), dtype=np.int64)
    ids[:, 0], ids[:, nv], ids[0, :], ids[nu, :] = bottom, top, left, right
    if nu > 1 and nv > 1:
        pb, pt, pl, pr = (build.point(s) for s in (bottom, top, left, right))
        u = (np.arange(1, nu) / nu)[:, None, None]
        v = (np.arange(1, nv) / nv)[None, :, None]
        inner = ((1 - v) * pb[1:-1, None] + v * pt[1:-1, None] + (1 - u) * pl[None, 1:-1] + u * pr[None, 1:-1]
                 - ((1 - u) * (1 - v) * pb[0] + u * (1 - v) * pb[-1] + (1 - u) * v * pt[0] + u * v * pt[-1]))
        flat = inner.reshape(-1, 3)
        flat = build.features.project(flat, np.full(len(flat), region))[0]
        ids[1:nu, 1:nv] = build.add(flat, region).reshape(nu - 1, nv - 1)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    build.faces.append(np.stack([ids[i, j], ids[i + 1, j], ids[i + 1, j + 1], ids[i, j + 1]], axis=-1).reshape(-1, 4))


def _smooth(vertices: np.ndarray, quads: np.ndarray, on_crease: np.ndarray, region: np.ndarray,
            features: CreaseFeatures) -> np.ndarray:
    """The points on no crease moved towards their neighbours' centre along the surface a few times
    (`cam.remesh.relax`); a move that turns a quad over is taken back."""
    free = np.flatnonzero(~on_crease)
    v = vertices.copy()
    if not len(free):
        return v
    edges = np.unique(np.sort(np.stack([quads, np.roll(quads, -1, axis=1)], axis=2).reshape(-1, 2), axis=1), axis=0)
    before = face_normals(v, quads)
    for _ in range(_SMOOTH_ROUNDS):
        old = [(v, v.copy())]
        v[free] = slide_on_surface(features, v[free], region[free], neighbour_centres(v, edges)[free], _SMOOTH_STEP)
        undo_turned(v, quads, before, old)
    return v
