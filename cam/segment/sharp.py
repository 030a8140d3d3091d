"""Sharp edges of a quad mesh: dihedral angle above θ, chained into curves, tiny isolated fragments dropped.

An edge is sharp when the angle between the normals of its two faces exceeds
``sharp_angle_deg`` (the paper's θ). Sharp edges are chained into curves
(maximal paths between vertices where the sharp network does not simply pass
through). A connected group of sharp edges that touches no other sharp edge
and has fewer than ``min_fragment_edges`` edges is noise (a zig-zag of one or
two edges on a curved region) and is dropped: a patch boundary there would
only cut a smooth surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cam.mesh.quads import QuadTopology

__all__ = ["SharpFeatures", "chain_edges", "find_sharp_edges"]


@dataclass(frozen=True, eq=False)
class SharpFeatures:
    """Sharp edges of one topology.

    Attributes
    ----------
    sharp
        bool (ne,): sharp after dropping fragments, indexed like ``topo.edges``.
    dihedral_deg
        float64 (ne,): angle between the two face normals, degrees (0 on a boundary).
    curves
        Vertex chains of the sharp network (a closed curve repeats its first vertex).
    dropped_edges
        How many sharp edges were dropped as fragments.
    """

    sharp: np.ndarray
    dihedral_deg: np.ndarray
    curves: tuple[tuple[int, ...], ...]
    dropped_edges: int


def chain_edges(edges: np.ndarray, n_vertices: int) -> list[list[int]]:
    """Chain undirected edges into vertex paths, split where a vertex does not have exactly two of them.

    Parameters
    ----------
    edges
        int (k, 2) vertex pairs.
    n_vertices
        Number of vertices the indices refer to.

    Returns
    -------
    list of list of int
        Vertex paths; each edge lies on exactly one, and a closed loop repeats its first vertex.
    """
    adjacency: dict[int, list[int]] = {}
    for e, (a, b) in enumerate(edges.tolist()):
        adjacency.setdefault(a, []).append(e)
        adjacency.setdefault(b, []).append(e)
    used = np.zeros(len(edges), dtype=bool)
    chains: list[list[int]] = []

    def walk(start: int, e: int) -> list[int]:
        path = [start]
        v = start
        while True:
            used[e] = True
            a, b = edges[e]
            v = int(b if a == v else a)
            path.append(v)
            if len(adjacency[v]) != 2:
                return path
            nxt = [f for f in adjacency[v] if not used[f]]
            if not nxt:
                return path  # came back around a closed loop
            e = nxt[0]

    for v, incident in adjacency.items():
        if len(incident) != 2:
            for e in incident:
                if not used[e]:
                    chains.append(walk(v, e))
    for e in range(len(edges)):
        if not used[e]:  # what is left are closed loops through degree-2 vertices only
            chains.append(walk(int(edges[e, 0]), e))
    return chains


def find_sharp_edges(
    topo: QuadTopology, normals: np.ndarray, *, sharp_angle_deg: float, min_fragment_edges: int = 3
) -> SharpFeatures:
    """Mark sharp edges.

    Parameters
    ----------
    topo
        Connectivity of the quad mesh.
    normals
        float (m, 3) unit face normals.
    sharp_angle_deg
        θ, degrees, in (0, 180) (:class:`cam.params.SegmentParams` holds it there): an interior edge is
        sharp when its dihedral angle exceeds it.
    min_fragment_edges
        Isolated sharp groups with fewer edges are dropped (0 keeps all).

    Returns
    -------
    SharpFeatures
        bool (ne,) sharp edges and float64 (ne,) dihedral angles in degrees, both indexed like
        ``topo.edges``, the sharp curves and how many edges were dropped as fragments.
    """
    ef = topo.edge_faces
    interior = ef[:, 1] >= 0
    cos = np.ones(len(ef))
    cos[interior] = np.einsum("ij,ij->i", normals[ef[interior, 0]], normals[ef[interior, 1]])
    dihedral = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    sharp = interior & (dihedral > sharp_angle_deg)
    dropped = 0
    if min_fragment_edges > 0 and sharp.any():
        ids = np.flatnonzero(sharp)
        a, b = topo.edges[ids, 0], topo.edges[ids, 1]
        graph = coo_matrix((np.ones(len(ids)), (a, b)), shape=(topo.n_vertices, topo.n_vertices))
        _, comp = connected_components(graph, directed=False)
        sizes = np.bincount(comp[a], minlength=topo.n_vertices)
        small = sizes[comp[a]] < min_fragment_edges
        # A fragment that touches the mesh boundary ends a real feature there: keep it.
        on_boundary = np.zeros(topo.n_vertices, dtype=bool)
        on_boundary[topo.edges[topo.boundary_edge].reshape(-1)] = True
        comp_touch = np.zeros(topo.n_vertices, dtype=bool)
        comp_touch[comp[a][on_boundary[a] | on_boundary[b]]] = True
        drop = ids[small & ~comp_touch[comp[a]]]
        sharp[drop] = False
        dropped = len(drop)
    curves = tuple(tuple(c) for c in chain_edges(topo.edges[sharp], topo.n_vertices))
    return SharpFeatures(sharp=sharp, dihedral_deg=dihedral, curves=curves, dropped_edges=dropped)
