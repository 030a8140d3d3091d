"""The paper's weighted graph of extraordinary points and its minimum spanning tree (Kruskal).

Nodes are the extraordinary points (EPs: interior vertices whose valence is
not 4), the auxiliary vertices where two connection edges cross, and one node
per connected piece of the a-priori features (sharp edges and mesh
boundaries). Edges come from tracing the grid lines (separatrices) leaving
each EP (:mod:`cam.segment.traces`):

- a line that reaches another EP is a *standard* connection edge;
- a line that reaches a feature or the boundary first is an *NF* edge (it
  joins the EP to the feature network instead of to another EP). A line may
  run along a sharp curve; where it would cross one it ends there instead, so
  no connection edge crosses an a-priori sharp edge;
- lines that close on themselves or never arrive anywhere are dropped.

Where two connection edges pass through the same vertex, that vertex becomes
an auxiliary node and both edges are split there; the pieces touching an
auxiliary node are *auxiliary* edges. Weights (the paper's eq. 4): a standard
edge weighs Σ SC_i·length_i over its mesh edges, with SC_i = ``sc`` on sharp
mesh edges and 1 elsewhere; NF edges are multiplied by ``nc`` and auxiliary
edges by ``ac``. An EP that lies on a feature is joined to that feature's node
at weight 0 (it is attached already). Kruskal's algorithm then gives a
minimum spanning tree per connected part of the graph, from which auxiliary
vertices left as leaves are pruned (they are Steiner points, not terminals).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cam.mesh.quads import QuadTopology
from cam.segment.traces import trace_line

__all__ = ["ConnectionGraph", "GraphEdge", "build_connection_graph", "kruskal"]


@dataclass(frozen=True)
class GraphEdge:
    """One edge of the connection graph: nodes, the mesh half-edges along it, its weight and kind.

    ``kind`` is ``"standard"``, ``"nf"``, ``"aux"`` or ``"attach"`` (EP on a feature, no mesh edges).
    """

    a: int
    b: int
    half_edges: tuple[int, ...]
    weight: float
    kind: str


@dataclass(frozen=True, eq=False)
class ConnectionGraph:
    """Nodes as ``(kind, id)`` with kind ``"ep"`` (vertex), ``"aux"`` (vertex) or ``"feature"`` (component);
    ``edges``; ``mst`` the indices of the edges Kruskal kept; ``connections`` the traced lines before splitting."""

    nodes: tuple[tuple[str, int], ...]
    edges: tuple[GraphEdge, ...]
    mst: tuple[int, ...]
    connections: int
    dropped_lines: int


def kruskal(n_nodes: int, edges: list[tuple[float, int, int]]) -> list[int]:
    """Kruskal's minimum spanning forest.

    Parameters
    ----------
    n_nodes
        Nodes are 0 .. n_nodes - 1.
    edges
        ``(weight, a, b)`` per edge.

    Returns
    -------
    list of int
        Indices into ``edges`` of the forest's edges, in the order taken (by weight; ties: lower index first).
    """
    parent = list(range(n_nodes))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    chosen = []
    for i in sorted(range(len(edges)), key=lambda i: (edges[i][0], i)):
        _, a, b = edges[i]
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[ra] = rb
            chosen.append(i)
    return chosen


def _prune_steiner_leaves(nodes: list[tuple[str, int]], edges: list[GraphEdge], tree: list[int]) -> list[int]:
    """Drop tree edges that end in an auxiliary leaf, repeatedly.

    A spanning tree must reach every node, auxiliary vertices included; an
    auxiliary vertex that only hangs off the tree connects nothing and would
    leave a loose clipping line, so it is pruned (auxiliary vertices are
    Steiner points: kept only where the tree passes through them).
    """
    keep = set(tree)
    incident: dict[int, set[int]] = {}
    for i in tree:
        incident.setdefault(edges[i].a, set()).add(i)
        incident.setdefault(edges[i].b, set()).add(i)
    leaves = [v for v, inc in incident.items() if len(inc) == 1 and nodes[v][0] == "aux"]
    while leaves:
        v = leaves.pop()
        if len(incident.get(v, ())) != 1:
            continue
        (i,) = incident[v]
        keep.discard(i)
        for w in (edges[i].a, edges[i].b):
            incident[w].discard(i)
            if w != v and len(incident[w]) == 1 and nodes[w][0] == "aux":
                leaves.append(w)
    return sorted(keep)


def _feature_components(topo: QuadTopology, feature: np.ndarray) -> np.ndarray:
    """int64 (n,): component id of each vertex in the feature-edge graph, -1 for vertices on no feature edge."""
    ids = np.flatnonzero(feature)
    n = topo.n_vertices
    a, b = topo.edges[ids, 0], topo.edges[ids, 1]
    graph = coo_matrix((np.ones(len(ids)), (a, b)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    on = np.zeros(n, dtype=bool)
    on[a] = on[b] = True
    return np.where(on, comp, -1).astype(np.int64)


def build_connection_graph(
    topo: QuadTopology,
    straight: np.ndarray,
    vertices: np.ndarray,
    extraordinary: np.ndarray,
    sharp: np.ndarray,
    *,
    sc: float,
    nc: float,
    ac: float,
) -> ConnectionGraph:
    """Trace every EP's lines, build the weighted graph and its minimum spanning forest.

    Parameters
    ----------
    topo
        Connectivity of the segmentation domain.
    straight
        int64 (4m,): its :func:`cam.segment.traces.straight_continuation`.
    vertices
        float (n, 3), mm (edge lengths).
    extraordinary
        bool (n,): the EPs.
    sharp
        bool (ne,): a-priori sharp edges, indexed like ``topo.edges``.
    sc, nc, ac
        The paper's SC, NC, AC (the bounds of :class:`cam.params.SegmentParams`).

    Returns
    -------
    ConnectionGraph
        Its nodes, its edges (weights in mm times the factors), the edges of the spanning forest, and how
        many lines were traced and dropped.
    """
    feature = sharp | topo.boundary_edge
    comp = _feature_components(topo, feature)
    stop = _line_stop(topo, straight, extraordinary, sharp, feature)
    lines, dropped = _trace_ep_lines(topo, straight, extraordinary, stop)
    length = np.linalg.norm(vertices[topo.edges[:, 0]] - vertices[topo.edges[:, 1]], axis=1)
    cost = length * np.where(sharp, sc, 1.0)
    nodes, edges = _graph_of_lines(topo, lines, extraordinary, comp, cost, nc=nc, ac=ac)
    mst = _prune_steiner_leaves(nodes, edges, kruskal(len(nodes), [(e.weight, e.a, e.b) for e in edges]))
    return ConnectionGraph(nodes=tuple(nodes), edges=tuple(edges), mst=tuple(sorted(mst)),
                           connections=len(lines), dropped_lines=dropped)


#: A traced line: its half-edges, its vertices (start, then the end of each half-edge) and its kind.
_Line = tuple[tuple[int, ...], tuple[int, ...], str]


def _line_stop(topo: QuadTopology, straight: np.ndarray, extraordinary: np.ndarray, sharp: np.ndarray,
               feature: np.ndarray) -> Callable[[int], bool]:
    """The stop rule of a connection line: True after half-edge h when the line ends at h's end vertex."""
    edge_of, dest = topo.edge_of, topo.dest
    sharp_degree = np.bincount(topo.edges[sharp].reshape(-1), minlength=topo.n_vertices)
    feature_degree = np.bincount(topo.edges[feature].reshape(-1), minlength=topo.n_vertices)

    def stop(h: int) -> bool:
        w = int(dest[h])
        if extraordinary[w] or topo.boundary_vertex[w]:
            return True
        if feature_degree[w] == 0:
            return False
        nxt = int(straight[h])
        # Running along a simple sharp curve is fine; touching or crossing a feature ends the line.
        along = sharp[edge_of[h]] and nxt >= 0 and sharp[edge_of[nxt]] and sharp_degree[w] == 2
        return not along

    return stop


def _trace_ep_lines(topo: QuadTopology, straight: np.ndarray, extraordinary: np.ndarray,
                    stop: Callable[[int], bool]) -> tuple[dict[tuple[int, ...], _Line], int]:
    """Every line leaving an EP that ends by the stop rule, once per set of edges, and how many were dropped.

    A line traced from both of its ends is kept as first traced (EPs in index order).
    """
    edge_of = topo.edge_of
    lines: dict[tuple[int, ...], _Line] = {}
    dropped = 0
    for v in np.flatnonzero(extraordinary).tolist():
        for h in topo.outgoing(v).tolist():
            t = trace_line(topo, straight, h, stop=stop)
            if t.reason != "stop":
                dropped += 1
                continue
            kind = "standard" if extraordinary[t.end] else "nf"
            key = tuple(sorted(int(edge_of[g]) for g in t.half_edges))
            lines.setdefault(key, (t.half_edges, t.vertices, kind))
    return lines, dropped


def _graph_of_lines(topo: QuadTopology, lines: dict[tuple[int, ...], _Line], extraordinary: np.ndarray,
                    comp: np.ndarray, cost: np.ndarray, *, nc: float,
                    ac: float) -> tuple[list[tuple[str, int]], list[GraphEdge]]:
    """The graph's nodes (EPs first, in index order, then as the lines meet them) and weighted edges.

    ``cost``: float (ne,) weighted length of each mesh edge, mm; ``comp``: int64 (n,) feature component
    of each vertex (-1 off the features).
    """
    aux = _auxiliary_vertices(lines)
    nodes: list[tuple[str, int]] = []
    index: dict[tuple[str, int], int] = {}

    def node(kind: str, ident: int) -> int:
        key = (kind, ident)
        if key not in index:
            index[key] = len(nodes)
            nodes.append(key)
        return index[key]

    for v in np.flatnonzero(extraordinary).tolist():
        node("ep", v)
    edges: list[GraphEdge] = []
    for hes, verts, kind in lines.values():
        end_node = node("ep", verts[-1]) if kind == "standard" else node("feature", int(comp[verts[-1]]))
        cuts = [i for i, w in enumerate(verts) if 0 < i < len(verts) - 1 and w in aux]
        bounds = [0, *cuts, len(verts) - 1]
        for s, e in itertools.pairwise(bounds):
            a = node("ep", verts[0]) if s == 0 else node("aux", verts[s])
            b = end_node if e == len(verts) - 1 else node("aux", verts[e])
            piece = hes[s:e]
            weight = float(cost[topo.edge_of[list(piece)]].sum())
            piece_kind = kind
            if kind == "nf":
                weight *= nc
            if s > 0 or e < len(verts) - 1:
                weight *= ac
                piece_kind = "aux"
            edges.append(GraphEdge(a, b, tuple(piece), weight, piece_kind))
    for v in np.flatnonzero(extraordinary & (comp >= 0)).tolist():
        edges.append(GraphEdge(node("ep", v), node("feature", int(comp[v])), (), 0.0, "attach"))
    return nodes, edges


def _auxiliary_vertices(lines: dict[tuple[int, ...], _Line]) -> set[int]:
    """Vertices inside (not at the ends of) two or more lines: where connection edges cross."""
    inner_count: dict[int, int] = {}
    for _, verts, _ in lines.values():
        for w in verts[1:-1]:
            inner_count[w] = inner_count.get(w, 0) + 1
    return {w for w, c in inner_count.items() if c >= 2}
