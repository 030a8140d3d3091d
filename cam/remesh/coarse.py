"""A coarse triangle mesh of a part whose edges follow its creases: the first step of the crease-first layout.

An isotropic remeshing (split the edges over 4/3 of the target length, collapse those under 4/5 of it, flip edges
towards valence six, move vertices towards their neighbours' centre along the surface, a few rounds), with the
creases of :class:`cam.remesh.features.CreaseFeatures` kept as paths of edges throughout: an edge on a chain is
never flipped, a point split on it is put on the chain, a vertex inside a chain slides along it only, and a chain's
ends never move. Every other vertex stays on its own region's triangles. Collapses (the compiled
:mod:`cam.remesh._collapsekernel`) also coarsen a dense input, and stop where the planes they merge lie farther than
a limit from the vertex kept, so curved regions keep more vertices than flat ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam import CheckCancel
from cam.remesh._collapsekernel import (
    collapse_short_edges,
    plane_quadrics,
    point_plane_quadrics,
)
from cam.remesh.features import CORNER, ON_CHAIN, SMOOTH, CreaseFeatures
from cam.remesh.relax import (
    face_normals,
    neighbour_centres,
    slide_on_surface,
    undo_turned,
)

__all__ = ["CoarseMesh", "EditableMesh", "coarse_triangulation", "edge_table"]

# Isotropic remeshing's split and collapse lengths, as multiples of the target edge length.
_SPLIT, _COLLAPSE = 4.0 / 3.0, 4.0 / 5.0
# A region aims for edges no longer than this many times its width (a fillet strip between two creases would
# otherwise be spanned by slivers from one crease to the other).
_WIDTH = 6.0
# A collapse may turn a triangle's normal this far at most, degrees.
_MAX_TURN_DEG = 35.0
# Vertex moves per round, as a share of the way to the neighbours' centre.
_RELAX = 0.5


@dataclass(frozen=True, eq=False)
class CoarseMesh:
    """A coarse mesh (triangles, or quads once split) whose edges follow the crease chains of the features it
    was made from.

    Attributes
    ----------
    vertices : (n, 3) float64
        Vertices on the part's surface, mm.
    faces : (m, 3) or (m, 4) int64
        Triangles or quads, oriented like the part's triangles.
    face_region : (m,) int64
        The region of the part each face covers.
    vertex_kind : (n,) int8
        SMOOTH, ON_CHAIN or CORNER (`cam.remesh.features`).
    vertex_chain : (n,) int64
        Chain of an ON_CHAIN vertex, -1 for the others.
    vertex_arc : (n,) float64
        Its arc length along the chain, mm.
    chain_ends : (c, 2) int64
        Each chain's two end vertices.
    chain_lengths : (c,) float64
        Each chain's length, mm (the arc length of its far end).
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_region: np.ndarray
    vertex_kind: np.ndarray
    vertex_chain: np.ndarray
    vertex_arc: np.ndarray
    chain_ends: np.ndarray
    chain_lengths: np.ndarray

    def chain_sequences(self) -> list[np.ndarray]:
        """Each chain's vertices end to end, int64 arrays."""
        inner = np.flatnonzero(self.vertex_kind == ON_CHAIN)
        order = inner[np.lexsort((self.vertex_arc[inner], self.vertex_chain[inner]))]
        split = np.searchsorted(self.vertex_chain[order], np.arange(len(self.chain_ends) + 1))
        return [np.concatenate([[a], order[split[c]:split[c + 1]], [b]])
                for c, (a, b) in enumerate(self.chain_ends.tolist())]

    def crease_edges(self) -> dict[tuple[int, int], tuple[int, float, float]]:
        """Each edge on a chain, as a sorted vertex pair, with its chain and the arc lengths of the pair's first
        and second vertex along it (mm)."""
        out = {}
        for c, seq in enumerate(self.chain_sequences()):
            arc = np.concatenate([[0.0], self.vertex_arc[seq[1:-1]], [self.chain_lengths[c]]])
            for i in range(len(seq) - 1):
                a, b = int(seq[i]), int(seq[i + 1])
                out[(min(a, b), max(a, b))] = (c, arc[i], arc[i + 1]) if a < b else (c, arc[i + 1], arc[i])
        return out


def _flip_gain(valence: np.ndarray, counted: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
               d: np.ndarray) -> np.ndarray:
    """Squared distance from six of the valences before flipping edge a-b (third corners c and d) less after:
    a and b lose an edge, c and d gain one; vertices not ``counted`` (chain ends) add nothing."""
    return (counted[a] * ((valence[a] - 6) ** 2 - (valence[a] - 7) ** 2)
            + counted[b] * ((valence[b] - 6) ** 2 - (valence[b] - 7) ** 2)
            + counted[c] * ((valence[c] - 6) ** 2 - (valence[c] - 5) ** 2)
            + counted[d] * ((valence[d] - 6) ** 2 - (valence[d] - 5) ** 2))


def edge_table(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edges of a closed manifold mesh of triangles or quads (int (m, 3) or (m, 4)) and the two faces beside
    each.

    Returns int64 (e, 2) edges as sorted vertex pairs (a < b) and int64 (e, 2) faces: the first runs a → b,
    the second b → a. ValueError when an edge is not shared by exactly two faces one each way.
    """
    faces = np.asarray(faces, dtype=np.int64)
    k = faces.shape[1]
    directed = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    face = np.repeat(np.arange(len(faces)), k)
    n = int(faces.max()) + 1
    lo, hi = directed.min(axis=1), directed.max(axis=1)
    key = lo * n + hi
    order = np.argsort(key, kind="stable")
    key, lo, hi, face, forward = key[order], lo[order], hi[order], face[order], (directed[order, 0] < directed[order, 1])
    if len(key) % 2 or not (key[0::2] == key[1::2]).all() or (forward[0::2] == forward[1::2]).any() or (
            len(key) > 2 and (key[2::2] == key[1:-1:2]).any()):
        raise ValueError("the mesh is not a closed, consistently oriented manifold")
    first_forward = forward[0::2]
    faces_of = np.where(first_forward[:, None], np.stack([face[0::2], face[1::2]], axis=1),
                        np.stack([face[1::2], face[0::2]], axis=1))
    return np.stack([lo[0::2], hi[0::2]], axis=1), faces_of


def coarse_triangulation(features: CreaseFeatures, *, edge_mm: float, min_edge_mm: float, error_share: float = 0.05,
                         rounds: int = 6, check_cancel: CheckCancel | None = None) -> EditableMesh:
    """Remesh the features' triangle mesh to edges about ``edge_mm`` long, its creases kept as edge paths.

    A region narrower than ``edge_mm`` (`CreaseFeatures.region_width_mm`) aims for edges as long as it is wide,
    but not under ``min_edge_mm``: triangles between two creases closer than their edges are long would be
    slivers that pair into no quad.

    Parameters
    ----------
    features : CreaseFeatures
        The part's mesh, chains and regions.
    edge_mm : float
        Target edge length, mm (> 0).
    min_edge_mm : float
        The shortest target a narrow region gets, mm (> 0).
    error_share : float
        A collapse is refused where the planes merged into the vertex kept lie farther from it (root mean
        square) than this share of its target length: curved regions keep shorter edges.
    rounds : int
        Rounds of split, collapse, flip and smoothing.
    check_cancel : callable or None
        Called between the steps.

    Returns
    -------
    EditableMesh
        The coarse triangle mesh, to be edited on (`EditableMesh.result` is its `CoarseMesh`).
    """
    if not edge_mm > 0 or not min_edge_mm > 0 or not error_share > 0:
        raise ValueError(f"need edge_mm, min_edge_mm and error_share > 0, got {edge_mm}, {min_edge_mm} and "
                         f"{error_share}")
    mesh = EditableMesh(features)
    region_size = np.minimum(edge_mm, np.maximum(_WIDTH * features.region_width_mm, min_edge_mm))
    for _ in range(rounds):
        for step in (lambda: mesh.split_long(region_size),
                     lambda: mesh.collapse_short(region_size, error_share),
                     mesh.flip_to_valence, mesh.relax):
            step()
            if check_cancel is not None:
                check_cancel()
    return mesh


class EditableMesh:
    """A coarse mesh while it is being remeshed: `CoarseMesh`'s arrays (replaced as they change), the vertices'
    plane quadrics, and the features it is made on. Splits, collapses and flips need triangles; `relax` takes
    triangles or quads."""

    def __init__(self, features: CreaseFeatures):
        self.features = features
        self.V = features.vertices.copy()
        self.F = features.triangles.copy()
        self.region = features.face_region.copy()
        self.kind = features.vertex_kind.copy()
        self.chain = features.vertex_chain.copy()
        self.arc = features.vertex_arc.copy()
        self.ends = np.array([c.ids[[0, -1]] for c in features.chains], dtype=np.int64).reshape(-1, 2)
        self.Q, self.W = plane_quadrics(self.V, self.F)
        self.lengths = np.array([c.length for c in features.chains])
        self._compact()

    # -- bookkeeping

    def result(self) -> CoarseMesh:
        return CoarseMesh(self.V, self.F, self.region, self.kind, self.chain, self.arc, self.ends, self.lengths)

    def _compact(self) -> None:
        """Drop the vertices no triangle uses, renumbering the rest."""
        used = np.zeros(len(self.V), dtype=bool)
        used[self.F.ravel()] = True
        used[self.ends.ravel()] = True
        new = np.cumsum(used) - 1
        self.V, self.kind, self.chain, self.arc = self.V[used], self.kind[used], self.chain[used], self.arc[used]
        self.Q, self.W = self.Q[used], self.W[used]
        self.F, self.ends = new[self.F], new[self.ends]

    def add_vertices(self, points: np.ndarray, kind: np.ndarray, chain: np.ndarray, arc: np.ndarray,
                     quadric: np.ndarray, weight: np.ndarray) -> np.ndarray:
        """Append vertices (their points, kinds, chains, arcs, quadrics and weights); returns their ids."""
        ids = np.arange(len(self.V), len(self.V) + len(points))
        self.V = np.concatenate([self.V, points])
        self.kind = np.concatenate([self.kind, kind.astype(np.int8)])
        self.chain = np.concatenate([self.chain, chain])
        self.arc = np.concatenate([self.arc, arc])
        self.Q = np.concatenate([self.Q, quadric])
        self.W = np.concatenate([self.W, weight])
        return ids

    def _chain_neighbours(self) -> np.ndarray:
        cn = np.full((len(self.V), 2), -1, dtype=np.int64)
        for seq in self.result().chain_sequences():
            cn[seq[1:-1], 0] = seq[:-2]
            cn[seq[1:-1], 1] = seq[2:]
        return cn

    def _vertex_region(self) -> np.ndarray:
        region = np.full(len(self.V), -1, dtype=np.int64)
        region[self.F.ravel()] = np.repeat(self.region, self.F.shape[1])
        return region

    # -- the four steps

    def vertex_size(self, region_size: np.ndarray) -> np.ndarray:
        """Each vertex's target edge length: the least of its faces' regions' (``region_size`` mm per region)."""
        size = np.full(len(self.V), np.inf)
        np.minimum.at(size, self.F.ravel(), np.repeat(region_size[self.region], self.F.shape[1]))
        return size

    def split_long(self, region_size: np.ndarray) -> None:
        """Split every edge over 4/3 of its ends' smaller target length at its middle (on the chain for a crease
        edge), in rounds of edges whose triangles are all different."""
        for _ in range(64):
            edges, faces = edge_table(self.F)
            size = self.vertex_size(region_size)
            length = np.linalg.norm(self.V[edges[:, 0]] - self.V[edges[:, 1]], axis=1)
            over = length / np.minimum(size[edges[:, 0]], size[edges[:, 1]])
            long = np.flatnonzero(over > _SPLIT)
            if not len(long):
                return
            long = long[np.argsort(-over[long], kind="stable")]
            taken = np.zeros(len(self.F), dtype=bool)
            chosen = []
            for e in long.tolist():
                f1, f2 = faces[e]
                if not taken[f1] and not taken[f2]:
                    taken[f1] = taken[f2] = True
                    chosen.append(e)
            self._split(edges[chosen], faces[chosen])

    def edge_middles(self, edges: np.ndarray, regions: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The middle of each edge (sorted vertex pairs (k, 2)) on the part: at the middle arc length of its chain
        for an edge on one, else the chord's middle projected onto the edge's region (``regions`` (k,)).

        Returns the points (k, 3) mm, their kinds (SMOOTH or ON_CHAIN), chains (-1 off one), arc lengths (mm) and
        the surface's unit normals at the projected ones (zero at the others)."""
        creases = self.result().crease_edges()
        k = len(edges)
        points = 0.5 * (self.V[edges[:, 0]] + self.V[edges[:, 1]])
        kind = np.full(k, SMOOTH, dtype=np.int8)
        chain = np.full(k, -1, dtype=np.int64)
        arc = np.zeros(k)
        normals = np.zeros((k, 3))
        for i, key in enumerate(map(tuple, edges.tolist())):
            hit = creases.get(key)
            if hit is not None:
                kind[i], chain[i], arc[i] = ON_CHAIN, hit[0], 0.5 * (hit[1] + hit[2])
                points[i] = self.features.chain_points(hit[0], arc[i:i + 1])[0]
        smooth = np.flatnonzero(kind == SMOOTH)
        if len(smooth):
            points[smooth], normals[smooth] = self.features.project(points[smooth], regions[smooth])
        return points, kind, chain, arc, normals

    def _split(self, edges: np.ndarray, faces: np.ndarray) -> None:
        points, kind, chain, arc, normals = self.edge_middles(edges, self.region[faces[:, 0]])
        quadric = 0.5 * (self.Q[edges[:, 0]] + self.Q[edges[:, 1]])
        weight = 0.5 * (self.W[edges[:, 0]] + self.W[edges[:, 1]])
        # a middle off the creases takes the surface's own plane there: an end's quadric may hold the far side
        # of a crease it lies on
        smooth = kind == SMOOTH
        quadric[smooth] = weight[smooth, None] * point_plane_quadrics(points[smooth], normals[smooth])
        # f1 runs a -> b with third corner c; f2 runs b -> a with third corner d.
        f1, f2 = faces[:, 0], faces[:, 1]
        a, b = edges[:, 0], edges[:, 1]
        c = self.F[f1].sum(axis=1) - a - b
        d = self.F[f2].sum(axis=1) - a - b
        m = self.add_vertices(points, kind, chain, arc, quadric, weight)
        self.F[f1] = np.stack([a, m, c], axis=1)
        self.F[f2] = np.stack([b, m, d], axis=1)
        self.F = np.concatenate([self.F, np.stack([m, b, c], axis=1), np.stack([m, a, d], axis=1)])
        self.region = np.concatenate([self.region, self.region[f1], self.region[f2]])

    def collapse_short(self, region_size: np.ndarray, error_share: float) -> None:
        """Collapse the edges under 4/5 of their ends' smaller target length where no edge grows over 4/3 of it
        (`collapse_short_edges`)."""
        alive = np.ones(len(self.F), dtype=bool)
        kind = self.kind.copy()
        collapse_short_edges(self.V, self.F, alive, kind, self._chain_neighbours(), self.Q, self.W,
                             self.vertex_size(region_size), _COLLAPSE, _SPLIT, error_share, _MAX_TURN_DEG, 8)
        self.F, self.region = self.F[alive], self.region[alive]
        self._compact()

    def flip_to_valence(self) -> None:
        """Flip edges on no chain where that brings the four vertices' valences nearer six (chain ends left out)
        and both new triangles face the way the old ones did: best first, each gain taken with the valences
        as the flips before it left them, a triangle flipped once a round (a lat-long sphere's pole, of valence
        96, loses many edges in one round)."""
        counted = (self.kind != CORNER).astype(np.int64)
        for _ in range(32):
            creases = self.result().crease_edges()
            edges, faces = edge_table(self.F)
            a, b = edges[:, 0], edges[:, 1]
            c = self.F[faces[:, 0]].sum(axis=1) - a - b
            d = self.F[faces[:, 1]].sum(axis=1) - a - b
            valence = np.bincount(edges.ravel(), minlength=len(self.V))
            gain = _flip_gain(valence, counted, a, b, c, d)
            crease = np.array([(x, y) in creases for x, y in edges.tolist()], dtype=bool)
            candidates = np.flatnonzero((gain > 0) & ~crease)
            if not len(candidates):
                return
            existing = set(map(tuple, edges.tolist()))
            taken = np.zeros(len(self.F), dtype=bool)
            flipped = 0
            for e in candidates[np.argsort(-gain[candidates], kind="stable")].tolist():
                ea, eb, ec, ed = int(a[e]), int(b[e]), int(c[e]), int(d[e])
                f1, f2 = faces[e]
                if taken[f1] or taken[f2] or ec == ed or min(valence[ea], valence[eb]) <= 3:
                    continue
                if _flip_gain(valence, counted, *(np.array([x]) for x in (ea, eb, ec, ed)))[0] <= 0:
                    continue
                if (min(ec, ed), max(ec, ed)) in existing or not self._flip_keeps_facing(ea, eb, ec, ed):
                    continue
                taken[f1] = taken[f2] = True
                existing.add((min(ec, ed), max(ec, ed)))
                valence[[ea, eb]] -= 1
                valence[[ec, ed]] += 1
                # f1 ran a -> b (third corner c), f2 b -> a (third d): the new pair is (a, d, c) and (d, b, c)
                self.F[f1] = (ea, ed, ec)
                self.F[f2] = (ed, eb, ec)
                flipped += 1
            if not flipped:
                return

    def _flip_keeps_facing(self, a: int, b: int, c: int, d: int) -> bool:
        """Whether both triangles after flipping a-b (third corners c and d) face within 60° of both before it
        (so that no flip folds across a bend the edges are too long to follow)."""
        V = self.V
        old = [np.cross(V[b] - V[a], V[c] - V[a]), np.cross(V[a] - V[b], V[d] - V[b])]
        new = [np.cross(V[d] - V[a], V[c] - V[a]), np.cross(V[b] - V[d], V[c] - V[d])]
        return all(np.dot(n, o) > 0.5 * np.linalg.norm(n) * np.linalg.norm(o) for n in new for o in old)

    def relax(self, steps: int = 2) -> None:
        """Move each vertex part of the way to its neighbours' centre (`cam.remesh.relax`): along the surface on its
        region for a vertex on no crease, along its chain for one inside a chain; a corner stays. A move that
        turns a face over is taken back."""
        edges, _ = edge_table(self.F)
        region = self._vertex_region()
        smooth = np.flatnonzero(self.kind == SMOOTH)
        cn = self._chain_neighbours()
        inner = np.flatnonzero(self.kind == ON_CHAIN)
        for _ in range(steps):
            old = [(self.V, self.V.copy()), (self.arc, self.arc.copy())]
            before = face_normals(self.V, self.F)
            if len(smooth):
                centres = neighbour_centres(self.V, edges)
                self.V[smooth] = slide_on_surface(self.features, self.V[smooth], region[smooth], centres[smooth],
                                                  _RELAX)
            if len(inner):
                target = 0.5 * (self._arc_of(cn[inner, 0], inner) + self._arc_of(cn[inner, 1], inner))
                self.arc[inner] += _RELAX * (target - self.arc[inner])
                for c in np.unique(self.chain[inner]).tolist():
                    rows = inner[self.chain[inner] == c]
                    self.V[rows] = self.features.chain_points(c, self.arc[rows])
            undo_turned(self.V, self.F, before, old)

    def _arc_of(self, vertices: np.ndarray, along: np.ndarray) -> np.ndarray:
        """Arc lengths of ``vertices`` on the chains of the vertices ``along`` (a chain's end: 0 or its length)."""
        out = self.arc[vertices].copy()
        chains = self.chain[along]
        is_end = self.kind[vertices] == CORNER
        first = self.ends[chains, 0] == vertices
        out[is_end & first] = 0.0
        out[is_end & ~first] = self.lengths[chains[is_end & ~first]]
        return out
