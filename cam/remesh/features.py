"""The creases a crease-first layout is built on: chains of triangle-mesh edges, their corners, and the regions
they cut the surface into.

A crease-first layout (:mod:`cam.remesh.layout`) makes every crease a chain of quad edges, so it needs the creases
as paths of mesh vertices, not as loose edges: :func:`find_crease_features` takes the crease chains of
:func:`cam.remesh.chains.crease_chains` (sharp creases, gentle ones that run on for two quads, cut where they turn
sharply), merges regions narrower than half a quad by dropping their least sharp chain (a denoised crease often
shows as two parallel lines of gentler edges joined by rungs), drops short spurs (a crease under a quad long that
ends in the middle of a face: a bevel's or a scan's stub, which no quad edge needs to follow), and labels each vertex: on no crease, inside one chain (it may slide
along that chain only), or at a chain's end (a corner: it never moves). The chains cut the triangles into regions;
a point made inside a region is projected onto that region's triangles only, so that a point on one side of a
thin wall or a sharp edge never lands on the other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cam.mesh.closest import MeshIndex, closest_points, mesh_index, triangle_normals
from cam.remesh.chains import (
    Chain,
    chain_from_points,
    chains_from_edges,
    crease_chains,
    points_at,
)

__all__ = ["CORNER", "ON_CHAIN", "SMOOTH", "CreaseFeatures", "find_crease_features"]

# Vertex kinds.
SMOOTH, ON_CHAIN, CORNER = 0, 1, 2
# A region narrower than this share of a quad (twice its area over its perimeter) is merged into a neighbour.
_THIN = 0.5


@dataclass(frozen=True, eq=False)
class CreaseFeatures:
    """A triangle mesh with its crease chains and regions (see :func:`find_crease_features`).

    Attributes
    ----------
    vertices : (p, 3) float64
        The triangle mesh's vertices, mm.
    triangles : (q, 3) int64
        Its triangles.
    chains : list of Chain
        The crease chains kept, each with its vertex ids (``Chain.ids``), two ends each.
    face_region : (q,) int64
        Each triangle's region: triangles joined across edges that are on no chain.
    vertex_kind : (p,) int8
        SMOOTH, ON_CHAIN (inside exactly one chain) or CORNER (a chain's end).
    vertex_chain : (p,) int64
        The chain of an ON_CHAIN vertex, -1 for the others.
    vertex_arc : (p,) float64
        Arc length of an ON_CHAIN vertex along its chain, mm; 0 for the others.
    spurs_dropped : int
        Crease chains dropped as spurs.
    spur_length_mm : float
        Their length, mm.
    thin_dropped : int
        Crease chains dropped because they bounded a thin region.
    thin_length_mm : float
        Their length, mm.
    region_width_mm : (r,) float64
        Each region's width: twice its area over the length of the chains between it and other regions, mm
        (infinite for a region no chain bounds).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    chains: list[Chain]
    face_region: np.ndarray
    vertex_kind: np.ndarray
    vertex_chain: np.ndarray
    vertex_arc: np.ndarray
    spurs_dropped: int
    spur_length_mm: float
    thin_dropped: int
    thin_length_mm: float
    region_width_mm: np.ndarray
    _indexes: dict = field(default_factory=dict, repr=False)

    def region_index(self, region: int) -> MeshIndex:
        """The closest-point index of one region's triangles (built once, when first asked for)."""
        if region not in self._indexes:
            self._indexes[region] = mesh_index(self.vertices, self.triangles[self.face_region == region])
        return self._indexes[region]

    def project(self, points: np.ndarray, regions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest points (float64 (n, 3), mm) on each point's own region and the unit normals there ((n, 3)).

        ``points`` float (n, 3) mm; ``regions`` int (n,): the region each point belongs to.
        """
        points = np.asarray(points, dtype=np.float64)
        regions = np.asarray(regions, dtype=np.int64)
        out, normals = np.empty_like(points), np.empty_like(points)
        for r in np.unique(regions).tolist():
            rows = np.flatnonzero(regions == r)
            index = self.region_index(r)
            out[rows], _, tri, _ = closest_points(index, points[rows])
            normals[rows] = triangle_normals(index, tri)
        return out, normals

    def chain_points(self, chain: int, arc: np.ndarray) -> np.ndarray:
        """Points (float64 (k, 3), mm) of chain ``chain`` at arc lengths ``arc`` (mm, (k,))."""
        return points_at(self.chains[chain], np.asarray(arc, dtype=np.float64))


def find_crease_features(vertices: np.ndarray, triangles: np.ndarray, *, crease_angle_deg: float,
                         gentle_angle_deg: float, corner_turn_deg: float, quad_mm: float) -> CreaseFeatures:
    """The crease chains of a closed triangle mesh, cleaned of thin regions and spurs, and the regions they cut it
    into.

    Parameters
    ----------
    vertices : (p, 3) float64
        Vertices, mm.
    triangles : (q, 3) int64
        Triangles, a closed manifold surface.
    crease_angle_deg : float
        Edges whose faces' normals differ by more than this are creases, degrees.
    gentle_angle_deg : float
        Edges over this angle are creases where their chain runs on for two quads, degrees.
    corner_turn_deg : float
        A chain that turns by more than this within half a quad has a corner there, degrees.
    quad_mm : float
        The layout's quad size, mm: regions narrower than half of it are merged into a neighbour, and chains
        with a free end shorter than it are spurs and dropped.

    Returns
    -------
    CreaseFeatures
    """
    tv = np.asarray(vertices, dtype=np.float64)
    tf = np.asarray(triangles, dtype=np.int64)
    chains, _ = crease_chains(tv, tf, crease_angle_deg=crease_angle_deg, gentle_angle_deg=gentle_angle_deg,
                              corner_turn_deg=corner_turn_deg, quad_mm=quad_mm)
    chains = [half for chain in chains for half in _split_loop(chain)]
    chains, merged = _merge_thin_regions(tv, tf, chains, _THIN * quad_mm)
    chains, dropped = _drop_spurs(chains, quad_mm)
    if merged or dropped:
        # what is left walked anew: pieces that met at a junction whose other creases were dropped join up
        kept = np.concatenate([np.stack([c.ids[:-1], c.ids[1:]], axis=1) for c in chains]) if chains else []
        chains = [half for chain in chains_from_edges(tv, kept, corner_turn_deg=corner_turn_deg, quad_mm=quad_mm)
                  for half in _split_loop(chain)]
        chains, again = _drop_spurs(chains, quad_mm)
        dropped += again
    kind = np.full(len(tv), SMOOTH, dtype=np.int8)
    chain_of = np.full(len(tv), -1, dtype=np.int64)
    arc_of = np.zeros(len(tv))
    for c, chain in enumerate(chains):
        inner = chain.ids[1:-1]
        kind[inner] = ON_CHAIN
        chain_of[inner] = c
        arc_of[inner] = chain.arc[1:-1]
    for chain in chains:
        kind[chain.ids[[0, -1]]] = CORNER
        chain_of[chain.ids[[0, -1]]] = -1
    region = _regions(tf, chains)
    return CreaseFeatures(vertices=tv, triangles=tf, chains=chains, face_region=region,
                          region_width_mm=_region_widths(tv, tf, chains, region),
                          vertex_kind=kind, vertex_chain=chain_of, vertex_arc=arc_of, spurs_dropped=len(dropped),
                          spur_length_mm=float(sum(c.length for c in dropped)), thin_dropped=len(merged),
                          thin_length_mm=float(sum(c.length for c in merged)))


def _split_loop(chain: Chain) -> list[Chain]:
    """A chain that ends where it starts, cut in two at its middle vertex (a chain needs two ends); others as they are."""
    if chain.ids[0] != chain.ids[-1] or len(chain.ids) < 4:
        return [chain]
    mid = len(chain.ids) // 2
    return [chain_from_points(chain.points[:mid + 1], (int(chain.ids[0]), int(chain.ids[mid])), ids=chain.ids[:mid + 1]),
            chain_from_points(chain.points[mid:], (int(chain.ids[mid]), int(chain.ids[-1])), ids=chain.ids[mid:])]


def _merge_thin_regions(tv: np.ndarray, tf: np.ndarray, chains: list[Chain], width_mm: float
                        ) -> tuple[list[Chain], list[Chain]]:
    """The chains without those dropped to merge thin regions, and the dropped ones.

    A denoised or scanned crease is often found as two parallel lines of gentler edges joined by rungs (a
    ladder), which cut the surface into slivers no quad fits in. While a region is narrower than ``width_mm``
    (twice its area over its perimeter), the chain on its border whose edges are least sharp (mean dihedral;
    the shorter on a tie) is dropped, merging the regions on its two sides.
    """
    if not chains:
        return chains, []
    region = _regions(tf, chains)
    area = _region_areas(tv, tf, region)
    sides, angle = _chain_sides(tv, tf, chains, region)
    length = np.array([c.length for c in chains])
    parent = np.arange(len(area))

    def find(r: int) -> int:
        while parent[r] != r:
            parent[r] = parent[parent[r]]
            r = parent[r]
        return r

    kept = np.ones(len(chains), dtype=bool)
    while True:
        roots = np.array([find(r) for r in range(len(area))])
        a, b = roots[sides[:, 0]], roots[sides[:, 1]]
        border = kept & (a != b)
        perimeter = np.bincount(a[border], weights=length[border], minlength=len(area)) + np.bincount(
            b[border], weights=length[border], minlength=len(area))
        total = np.bincount(roots, weights=area, minlength=len(area))
        width = np.where(perimeter > 0, 2.0 * total / np.maximum(perimeter, 1e-300), np.inf)
        thin = int(np.argmin(width))
        if not width[thin] < width_mm:
            break
        on_it = np.flatnonzero(border & ((a == thin) | (b == thin)))
        drop = on_it[np.lexsort((length[on_it], angle[on_it]))[0]]
        kept[drop] = False
        parent[find(int(a[drop]))] = find(int(b[drop]))
    return [c for c, k in zip(chains, kept, strict=True) if k], [c for c, k in zip(chains, kept, strict=True) if not k]


def _region_widths(tv: np.ndarray, tf: np.ndarray, chains: list[Chain], region: np.ndarray) -> np.ndarray:
    """Twice each region's area over its perimeter of chains (those with another region on their other side), mm."""
    area = _region_areas(tv, tf, region)
    perimeter = np.zeros(len(area))
    if chains:
        sides, _ = _chain_sides(tv, tf, chains, region)
        length = np.array([c.length for c in chains])
        border = sides[:, 0] != sides[:, 1]
        np.add.at(perimeter, sides[border, 0], length[border])
        np.add.at(perimeter, sides[border, 1], length[border])
    return np.where(perimeter > 0, 2.0 * area / np.maximum(perimeter, 1e-300), np.inf)


def _region_areas(tv: np.ndarray, tf: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Each region's area, mm² ((r,))."""
    p = tv[tf]
    return np.bincount(region, weights=0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1))


def _chain_sides(tv: np.ndarray, tf: np.ndarray, chains: list[Chain], region: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The regions on the two sides of each chain (int64 (c, 2), from its first edge) and the mean angle between
    its edges' two faces' normals (degrees, (c,))."""
    n = len(tv)
    edges = np.stack([tf, np.roll(tf, -1, axis=1)], axis=2).reshape(-1, 2)
    key = np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])
    face = np.repeat(np.arange(len(tf)), 3)
    order = np.argsort(key, kind="stable")
    key, face = key[order], face[order]
    p = tv[tf]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    sides = np.empty((len(chains), 2), dtype=np.int64)
    angle = np.empty(len(chains))
    for c, chain in enumerate(chains):
        ids = chain.ids
        k = np.searchsorted(key, np.minimum(ids[:-1], ids[1:]) * n + np.maximum(ids[:-1], ids[1:]))
        f1, f2 = face[k], face[k + 1]
        sides[c] = region[f1[0]], region[f2[0]]
        cos = np.clip(np.einsum("ij,ij->i", normal[f1], normal[f2]), -1.0, 1.0)
        angle[c] = float(np.degrees(np.arccos(cos)).mean())
    return sides, angle


def _drop_spurs(chains: list[Chain], quad_mm: float) -> tuple[list[Chain], list[Chain]]:
    """The chains without spurs (a chain under ``quad_mm`` long with an end no other chain meets), and the spurs;
    dropping one may make another a spur, so this repeats until none is left."""
    dropped: list[Chain] = []
    while True:
        degree: dict[int, int] = {}
        for chain in chains:
            for end in chain.ends:
                degree[end] = degree.get(end, 0) + 1
        spur = [c.length < quad_mm and min(degree[e] for e in c.ends) == 1 for c in chains]
        if not any(spur):
            return chains, dropped
        dropped += [c for c, s in zip(chains, spur, strict=True) if s]
        chains = [c for c, s in zip(chains, spur, strict=True) if not s]


def _regions(tf: np.ndarray, chains: list[Chain]) -> np.ndarray:
    """Region of each triangle: connected components of the triangles joined across edges on no chain."""
    n = int(tf.max()) + 1
    edges = np.stack([tf, np.roll(tf, -1, axis=1)], axis=2).reshape(-1, 2)
    key = np.minimum(edges[:, 0], edges[:, 1]) * n + np.maximum(edges[:, 0], edges[:, 1])
    cut = np.zeros(0, dtype=np.int64)
    if chains:
        pairs = np.concatenate([np.stack([c.ids[:-1], c.ids[1:]], axis=1) for c in chains])
        cut = np.minimum(pairs[:, 0], pairs[:, 1]) * n + np.maximum(pairs[:, 0], pairs[:, 1])
    face = np.repeat(np.arange(len(tf)), 3)
    order = np.argsort(key, kind="stable")
    key, face = key[order], face[order]
    # On a closed manifold mesh every edge key appears twice, in two triangles, next to each other when sorted.
    joined = (key[:-1] == key[1:]) & ~np.isin(key[:-1], cut)
    a, b = face[:-1][joined], face[1:][joined]
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(tf), len(tf)))
    return connected_components(graph, directed=False)[1].astype(np.int64)
