"""Clipping edges: complete a set of cut edges until every patch it bounds is a rectangular quad grid.

A patch is a rectangular grid exactly when, at every vertex, each run of its
faces between two consecutive clipping edges (a *sector*) holds one face (a
corner) or two (the boundary goes straight on), every vertex inside it is
regular, and it is a disk. So a sector of three or more faces, an
extraordinary point with no clipping edge, and the loose end of a clipping
line all need another clipping line. :func:`complete_cuts` adds them in the
paper's spirit, shortest first:

- at the loose end of a line at a regular vertex (a sharp feature that fades
  out, priority 4) the line is extended straight on;
- at an extraordinary point (priority 5) the sector is split by one of its
  grid lines, the one that meets an existing clipping edge soonest;

each new line runs until it meets a clipping edge, an extraordinary point or
its own track. :func:`cut_open_cylinders` then cuts patches that are not disks
(a band around a cylinder, a torus) with the shortest grid line across them.
Every step adds at least one edge, so the process ends: at worst every edge is
a clipping edge and every quad its own patch.
"""

from __future__ import annotations

import heapq
import itertools

import numpy as np

from cam import CheckCancel
from cam.mesh.quads import QuadTopology, prev_he, vertex_fans
from cam.segment.traces import Trace, trace_line

__all__ = ["CutState", "complete_cuts", "cut_open_cylinders", "patch_labels"]


class CutState:
    """Mutable set of clipping edges over a topology, with what the completion asks of it.

    Parameters
    ----------
    topo
        Connectivity of the domain.
    straight
        int64 (4m,): its :func:`cam.segment.traces.straight_continuation`.
    vertices
        float (n, 3), mm (line lengths).
    cut
        bool (ne,): the clipping edges to start from, indexed like ``topo.edges`` (copied).

    Attributes
    ----------
    cut
        bool (ne,): the clipping edges; boundary edges are always in it.
    on_cut
        int64 (n,): clipping edges at each vertex.
    length
        float64 (ne,): edge lengths, mm.
    """

    def __init__(self, topo: QuadTopology, straight: np.ndarray, vertices: np.ndarray, cut: np.ndarray) -> None:
        self.topo = topo
        self.straight = straight
        self.cut = cut.copy() | topo.boundary_edge
        self.on_cut = np.bincount(topo.edges[self.cut].reshape(-1), minlength=topo.n_vertices)
        self.length = np.linalg.norm(vertices[topo.edges[:, 0]] - vertices[topo.edges[:, 1]], axis=1)
        self._fans: dict[int, list[tuple[list[int], bool]]] = {}
        self._dest = topo.dest
        self.added_lines = 0

    def fans(self, v: int) -> list[tuple[list[int], bool]]:
        """The fans of faces around ``v`` (see :func:`cam.mesh.quads.vertex_fans`), computed once per vertex."""
        if v not in self._fans:
            self._fans[v] = vertex_fans(self.topo, v)
        return self._fans[v]

    def add(self, half_edges: tuple[int, ...] | list[int]) -> list[int]:
        """Make the edges of ``half_edges`` clipping edges; returns the vertices whose clipping edges changed."""
        touched = []
        for h in half_edges:
            e = int(self.topo.edge_of[h])
            if not self.cut[e]:
                self.cut[e] = True
                a, b = self.topo.edges[e]
                self.on_cut[a] += 1
                self.on_cut[b] += 1
                touched += [int(a), int(b)]
        if touched:
            self.added_lines += 1
        return touched

    def trace(self, h: int) -> Trace:
        """The grid line from ``origin(h)`` along ``h`` until a clipping vertex, an irregular vertex or its own track."""
        on_cut, dest = self.on_cut, self._dest
        return trace_line(self.topo, self.straight, h, stop=lambda g: on_cut[dest[g]] > 0)

    def trace_cost(self, t: Trace) -> float:
        """Length, mm, of the trace's edges that are not clipping edges yet: what adding it costs."""
        edges = self.topo.edge_of[list(t.half_edges)]
        return float(self.length[edges][~self.cut[edges]].sum())

    def split_candidates(self, v: int) -> list[int]:
        """Outgoing half-edges at ``v`` that would fix one bad sector there (empty when ``v`` is fine).

        Only the first bad sector found is considered; the caller comes back
        to ``v`` after fixing it.
        """
        edge_of, cut = self.topo.edge_of, self.cut
        for hes, closed in self.fans(v):
            n = len(hes)
            if closed:
                cuts = [i for i in range(n) if cut[edge_of[hes[i]]]]
                if not cuts:
                    if n == 4:
                        continue
                    return list(hes)  # an EP inside a patch: any of its lines starts the fix
                sectors = []
                for a, b in zip(cuts, cuts[1:] + [cuts[0] + n]):
                    sectors.append((a, b - a))
            else:
                edges = [edge_of[h] for h in hes] + [edge_of[prev_he(hes[-1])]]
                cuts = [i for i in range(n + 1) if cut[edges[i]]]
                sectors = [(a, b - a) for a, b in itertools.pairwise(cuts)]
            for start, size in sectors:
                if size <= 2:
                    continue
                # Split so that one side has exactly 2 faces (a straight boundary), or 1+2 for a sector of 3.
                offsets = [1, 2] if size == 3 else sorted({2, size - 2})
                return [hes[(start + j) % n] for j in offsets]
        return []


def complete_cuts(state: CutState, *, vertices_to_check: np.ndarray | list[int] | None = None,
                  check_cancel: CheckCancel | None = None) -> int:
    """Add clipping lines until no vertex has a bad sector.

    Lines are added shortest first (a heap of proposals, each re-checked
    when it comes up, since earlier lines shorten or remove later ones).

    Parameters
    ----------
    state
        The clipping edges so far; lines are added to it in place.
    vertices_to_check
        int (k,) vertices to start from (default: those on a clipping edge and the irregular ones).
    check_cancel
        Called every 64 lines; what it raises propagates.

    Returns
    -------
    int
        Lines added.
    """
    topo = state.topo
    if vertices_to_check is None:
        irregular = ~topo.regular_interior() & (topo.face_count > 0)
        vertices_to_check = np.flatnonzero((state.on_cut > 0) | irregular)
    heap: list[tuple[float, int, int]] = []
    counter = 0

    def propose(v: int) -> None:
        nonlocal counter
        cands = state.split_candidates(v)
        if not cands:
            return
        best = min((state.trace_cost(state.trace(h)), i) for i, h in enumerate(cands))
        counter += 1
        heapq.heappush(heap, (best[0], counter, v))

    for v in np.asarray(vertices_to_check, dtype=np.int64).tolist():
        propose(v)
    added = 0
    while heap:
        _cost, _, v = heapq.heappop(heap)
        cands = state.split_candidates(v)
        if not cands:
            continue
        traces = [state.trace(h) for h in cands]
        costs = [state.trace_cost(t) for t in traces]
        best = int(np.argmin(costs))
        if heap and costs[best] > heap[0][0] + 1e-12:
            counter += 1
            heapq.heappush(heap, (costs[best], counter, v))  # got longer than the next proposal: wait
            continue
        touched = state.add(traces[best].half_edges)
        added += 1
        for w in {v, *touched, traces[best].end}:
            propose(w)
        if check_cancel is not None and added % 64 == 0:
            check_cancel()
    return added


def patch_labels(topo: QuadTopology, cut: np.ndarray) -> np.ndarray:
    """Patches of faces joined across non-clipping edges.

    Parameters
    ----------
    topo
        Connectivity of the domain.
    cut
        bool (ne,): clipping edges, indexed like ``topo.edges``.

    Returns
    -------
    ndarray
        int64 (m,) patch id of each face; patches are numbered in the order of their lowest face.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    ef = topo.edge_faces
    link = ~cut & (ef[:, 1] >= 0)
    m = len(topo.faces)
    graph = coo_matrix((np.ones(int(link.sum())), (ef[link, 0], ef[link, 1])), shape=(m, m))
    _, labels = connected_components(graph, directed=False)
    first = np.full(labels.max() + 1, m)
    np.minimum.at(first, labels, np.arange(m))
    rank = np.argsort(np.argsort(first))
    return rank[labels].astype(np.int64)


def corner_counts(topo: QuadTopology, cut: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """int64 (patches,): face corners whose two edges both are clipping edges, per patch."""
    e = topo.edge_of.reshape(-1, 4)
    c = cut[e]
    corners = c & np.roll(c, 1, axis=1)  # corner i: edges i (leaving) and i-1 (arriving)
    return np.bincount(labels, weights=corners.sum(axis=1), minlength=labels.max() + 1).astype(np.int64)


def cut_open_cylinders(state: CutState, *, check_cancel: CheckCancel | None = None) -> int:
    """Cut every patch without corners (annulus, torus) with its shortest grid line.

    Parameters
    ----------
    state
        The clipping edges so far; lines are added to it in place.
    check_cancel
        Called after each line; what it raises propagates.

    Returns
    -------
    int
        Lines added (one per patch without corners).
    """
    topo = state.topo
    labels = patch_labels(topo, state.cut)
    corners = corner_counts(topo, state.cut, labels)
    added = 0
    for p in np.flatnonzero(corners == 0).tolist():
        faces = np.flatnonzero(labels == p)
        hes = (faces[:, None] * 4 + np.arange(4)).reshape(-1)
        starts = []
        for h in hes.tolist():
            v = int(topo.faces.reshape(-1)[h])
            # Lines into the patch from its boundary: the edge leaves a clipping vertex and is not clipping.
            if not state.cut[topo.edge_of[h]] and state.on_cut[v] > 0:
                starts.append(h)
        if not starts:
            # No boundary at all (a torus): any line, which closes on itself.
            starts = [int(hes[0])]
            t = trace_line(topo, state.straight, starts[0], stop=lambda g: False)
        else:
            traces = [state.trace(h) for h in starts]
            t = min(traces, key=state.trace_cost)
        state.add(t.half_edges)
        added += 1
        if check_cancel is not None:
            check_cancel()
    return added
