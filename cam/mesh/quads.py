"""Half-edge connectivity of a quad mesh, and the questions the remesh and segment stages ask of it.

Half-edge ``h = 4 f + i`` runs from ``faces[f, i]`` to ``faces[f, (i + 1) % 4]``
inside face ``f``; faces are counter-clockwise seen from outside, so the face
lies to the left of each of its half-edges. ``twin[h]`` is the opposite
half-edge in the neighbouring face, -1 on a boundary. Around a vertex,
``rotate(h) = twin[prev(h)]`` steps from one outgoing half-edge to the next one
(counter-clockwise), crossing face ``h // 4``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["QuadTopology", "face_areas", "face_normals", "quad_topology", "vertex_fans"]


@dataclass(frozen=True, eq=False)
class QuadTopology:
    """Connectivity of a consistently oriented, edge-manifold quad mesh (see the module docstring for the
    half-edge numbering); build it with `quad_topology`.

    Attributes
    ----------
    faces : (m, 4) int64
        Vertex indices of each quad, as given.
    n_vertices : int
        Number of vertices (unused ones included; they have no half-edges).
    twin : (4m,) int64
        The opposite half-edge, -1 on a boundary.
    edge_of : (4m,) int64
        Undirected edge id of each half-edge.
    edges : (ne, 2) int64
        The two vertices of each edge, smaller index first.
    edge_faces : (ne, 2) int64
        The face(s) of each edge, -1 where there is none.
    boundary_edge : (ne,) bool
        The edge has one face.
    valence : (n,) int64
        Edges per vertex.
    face_count : (n,) int64
        Faces per vertex.
    boundary_vertex : (n,) bool
        The vertex has a boundary edge.
    out_ptr : (n + 1,) int64
        CSR row pointers of the outgoing half-edges per vertex: ``out_he[out_ptr[v]:out_ptr[v+1]]``.
    out_he : (4m,) int64
        The outgoing half-edges, grouped by vertex.
    """

    faces: np.ndarray
    n_vertices: int
    twin: np.ndarray
    edge_of: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray
    boundary_edge: np.ndarray
    valence: np.ndarray
    face_count: np.ndarray
    boundary_vertex: np.ndarray
    out_ptr: np.ndarray
    out_he: np.ndarray

    @property
    def origin(self) -> np.ndarray:
        """Start vertex of each half-edge: (4m,) int64."""
        return self.faces.reshape(-1)

    @property
    def dest(self) -> np.ndarray:
        """End vertex of each half-edge: (4m,) int64."""
        return np.roll(self.faces, -1, axis=1).reshape(-1)

    def outgoing(self, v: int) -> np.ndarray:
        """Outgoing half-edges of vertex ``v`` (unordered).

        Parameters
        ----------
        v : int
            Vertex index.

        Returns
        -------
        half_edges : (k,) int64
            A view into `out_he`.
        """
        return self.out_he[self.out_ptr[v]:self.out_ptr[v + 1]]

    def regular_interior(self) -> np.ndarray:
        """Interior vertices with 4 edges and 4 faces (one closed fan).

        Returns
        -------
        mask : (n,) bool
            True at the regular interior vertices.
        """
        return (~self.boundary_vertex) & (self.valence == 4) & (self.face_count == 4)


def next_he(h: int) -> int:
    """The next half-edge in the same face (counter-clockwise).

    Parameters
    ----------
    h : int
        Half-edge index.

    Returns
    -------
    int
        The half-edge that starts where ``h`` ends.
    """
    return h - h % 4 + (h + 1) % 4


def prev_he(h: int) -> int:
    """The previous half-edge in the same face.

    Parameters
    ----------
    h : int
        Half-edge index.

    Returns
    -------
    int
        The half-edge that ends where ``h`` starts.
    """
    return h - h % 4 + (h + 3) % 4


def quad_topology(faces: np.ndarray, n_vertices: int) -> QuadTopology:
    """Build the half-edge connectivity of a quad mesh.

    Parameters
    ----------
    faces : (m, 4) array_like of int
        Vertex indices in ``[0, n_vertices)``, counter-clockwise seen from outside.
    n_vertices : int
        Number of vertices.

    Returns
    -------
    topology : QuadTopology
        The connectivity; ``faces`` converted to int64.

    Raises
    ------
    ValueError
        For faces of the wrong shape or range, a degenerate quad (a repeated vertex), an edge shared by
        more than two faces, or two faces that run through a shared edge in the same direction
        (inconsistent orientation).
    """
    quads = np.asarray(faces)
    if quads.ndim != 2 or quads.shape[1] != 4 or (quads.size and quads.dtype.kind not in "iu"):
        raise ValueError(f"faces must be an (m, 4) integer array, got shape {quads.shape} dtype {quads.dtype}")
    quads = quads.astype(np.int64)
    if quads.size and (quads.min() < 0 or quads.max() >= n_vertices):
        raise ValueError(f"faces index vertices {quads.min()}..{quads.max()} but there are {n_vertices}")
    srt = np.sort(quads, axis=1)
    degenerate = np.flatnonzero((srt[:, 1:] == srt[:, :-1]).any(axis=1))
    if len(degenerate):
        raise ValueError(f"{len(degenerate)} quads repeat a vertex (first: face {degenerate[0]})")
    origin = quads.reshape(-1)
    dest = np.roll(quads, -1, axis=1).reshape(-1)
    n = np.int64(max(n_vertices, 1))
    directed = origin * n + dest
    order = np.argsort(directed, kind="stable")
    sorted_keys = directed[order]
    dup = np.flatnonzero(sorted_keys[1:] == sorted_keys[:-1])
    if len(dup):
        h = order[dup[0]]
        raise ValueError(
            f"{len(dup)} half-edges appear twice: faces are inconsistently oriented or an edge is shared by more "
            f"than two faces (first at edge {origin[h]}-{dest[h]})"
        )
    reverse = dest * n + origin
    pos = np.searchsorted(sorted_keys, reverse)
    pos = np.minimum(pos, len(sorted_keys) - 1)
    twin = np.where(sorted_keys[pos] == reverse, order[pos], -1).astype(np.int64)

    lo, hi = np.minimum(origin, dest), np.maximum(origin, dest)
    edges_keys, edge_of = np.unique(lo * n + hi, return_inverse=True)
    edge_of = edge_of.reshape(-1).astype(np.int64)
    counts = np.bincount(edge_of, minlength=len(edges_keys))
    if (counts > 2).any():
        bad = int(np.flatnonzero(counts > 2)[0])
        raise ValueError(f"{int((counts > 2).sum())} edges are shared by more than two faces "
                         f"(first: {edges_keys[bad] // n}-{edges_keys[bad] % n})")
    edges = np.stack([edges_keys // n, edges_keys % n], axis=1)
    edge_faces = np.full((len(edges), 2), -1, dtype=np.int64)
    he_faces = np.arange(len(origin)) // 4
    first = np.full(len(edges), -1, dtype=np.int64)
    # The first half-edge of each edge fills column 0, its twin column 1.
    seen_order = np.argsort(edge_of, kind="stable")
    e_sorted = edge_of[seen_order]
    starts = np.flatnonzero(np.r_[True, e_sorted[1:] != e_sorted[:-1]])
    first[e_sorted[starts]] = seen_order[starts]
    edge_faces[:, 0] = he_faces[first]
    tw = twin[first]
    edge_faces[:, 1] = np.where(tw >= 0, he_faces[np.maximum(tw, 0)], -1)
    boundary_edge = counts == 1

    valence = np.bincount(edges.reshape(-1), minlength=n_vertices).astype(np.int64)
    face_count = np.bincount(origin, minlength=n_vertices).astype(np.int64)
    boundary_vertex = np.zeros(n_vertices, dtype=bool)
    boundary_vertex[edges[boundary_edge].reshape(-1)] = True
    out_order = np.argsort(origin, kind="stable")
    out_ptr = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(origin, minlength=n_vertices), out=out_ptr[1:])
    return QuadTopology(
        faces=quads, n_vertices=int(n_vertices), twin=twin, edge_of=edge_of, edges=edges, edge_faces=edge_faces,
        boundary_edge=boundary_edge, valence=valence, face_count=face_count, boundary_vertex=boundary_vertex,
        out_ptr=out_ptr, out_he=out_order.astype(np.int64),
    )


def vertex_fans(topo: QuadTopology, v: int) -> list[tuple[list[int], bool]]:
    """The fans of faces around vertex ``v``, each as outgoing half-edges in counter-clockwise order.

    Face ``h // 4`` of each listed half-edge ``h`` lies between edge ``h`` and the next listed one. An
    open fan (on a boundary) starts at the outgoing boundary half-edge and its last edge is
    ``prev(half_edges[-1])`` (an incoming boundary half-edge). A manifold vertex has exactly one fan; a
    pinch has several.

    Parameters
    ----------
    topo : QuadTopology
        The mesh connectivity.
    v : int
        Vertex index.

    Returns
    -------
    fans : list of (list of int, bool)
        ``(half_edges, closed)`` per fan; empty for a vertex without faces.
    """
    outgoing = [int(h) for h in topo.outgoing(v)]
    remaining = set(outgoing)
    twin = topo.twin
    fans: list[tuple[list[int], bool]] = []
    # Open fans begin at an outgoing half-edge that has no twin: nothing lies clockwise of it.
    starts = [h for h in outgoing if twin[h] < 0] + outgoing
    for start in starts:
        if start not in remaining:
            continue
        fan = []
        h = start
        closed = False
        while True:
            fan.append(h)
            remaining.discard(h)
            nxt = int(twin[prev_he(h)])
            if nxt < 0:
                break
            if nxt == start:
                closed = True
                break
            if nxt not in remaining:  # defensive: a corrupt ring must not loop forever
                break
            h = nxt
        fans.append((fan, closed))
    return fans


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals of quads from the cross product of their diagonals (robust for warped quads).

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex coordinates in mm.
    faces : (m, 4) int
        Vertex indices of each quad, counter-clockwise seen from outside.

    Returns
    -------
    normals : (m, 3) float64
        Unit normals; zero for a quad whose diagonals are parallel.
    """
    p = np.asarray(vertices, dtype=np.float64)[faces]
    n = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of each quad: half the norm of the diagonal cross product.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex coordinates in mm.
    faces : (m, 4) int
        Vertex indices of each quad.

    Returns
    -------
    areas : (m,) float64
        In mm².
    """
    p = np.asarray(vertices, dtype=np.float64)[faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1]), axis=1)
