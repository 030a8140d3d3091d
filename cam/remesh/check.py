"""Inspect a quad mesh for what later stages rely on.

Later stages need pure quads, manifold edges and vertices, one consistent
orientation, no holes the input did not have, and no interior vertex of
valence 2 (two quads folded onto each other there). :func:`inspect_quad_mesh`
names every such defect it finds; :mod:`cam.remesh.repair` fixes the ones that
are small and safe to fix.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam.mesh.quads import QuadTopology, quad_topology, vertex_fans

__all__ = ["QuadMeshReport", "boundary_loops", "count_pinched_vertices", "inspect_quad_mesh"]


@dataclass(frozen=True)
class QuadMeshReport:
    """What :func:`inspect_quad_mesh` found. ``problems`` is empty for a mesh later stages accept.

    Attributes
    ----------
    n_vertices, n_faces
        Vertex and quad counts of the mesh inspected.
    boundary_loop_lengths
        Edges per boundary loop, ascending (empty for a closed mesh).
    non_manifold_vertices
        Vertices where faces touch only at a corner (more than one fan).
    interior_valence2
        Interior vertices with two edges.
    unused_vertices
        Vertices no face uses.
    components
        Connected pieces.
    euler_characteristic
        V - E + F over the used vertices (2 for a closed sphere-like part).
    valence_histogram
        Interior vertex count per valence.
    extraordinary_vertices
        Interior vertices whose valence is not 4.
    problems
        One sentence per defect; empty when later stages accept the mesh.
    """

    n_vertices: int
    n_faces: int
    boundary_loop_lengths: tuple[int, ...]
    non_manifold_vertices: int
    interior_valence2: int
    unused_vertices: int
    components: int
    euler_characteristic: int
    valence_histogram: dict[int, int]
    extraordinary_vertices: int
    problems: tuple[str, ...] = field(default=())

    def as_dict(self) -> dict:
        """The report as JSON-ready plain types (valence keys as strings, in ascending order)."""
        return {
            "vertices": self.n_vertices, "faces": self.n_faces,
            "boundary_loops": list(self.boundary_loop_lengths),
            "non_manifold_vertices": self.non_manifold_vertices, "interior_valence2": self.interior_valence2,
            "unused_vertices": self.unused_vertices, "components": self.components,
            "euler_characteristic": self.euler_characteristic,
            "valence_histogram": {str(k): v for k, v in sorted(self.valence_histogram.items())},
            "extraordinary_vertices": self.extraordinary_vertices, "problems": list(self.problems),
        }


def boundary_loops(topo: QuadTopology) -> list[list[int]]:
    """Boundary loops of a quad mesh as half-edges in order along the boundary.

    Parameters
    ----------
    topo
        Connectivity of the quad mesh.

    Returns
    -------
    list of list of int
        One list per loop of half-edge ids (``4 * face + corner``), each half-edge without a twin and each
        starting where the previous one ends; ``[]`` for a closed mesh.
    """
    twin = topo.twin
    boundary = np.flatnonzero(twin < 0)
    # Boundary half-edge h ends at v; the next boundary half-edge leaves v. At a pinch a vertex has
    # several; the clockwise walk from h around v picks the one of the same fan.
    following: dict[int, int] = {}
    for h in boundary.tolist():
        g = h - h % 4 + (h + 1) % 4  # next in the face: leaves dest(h)
        while twin[g] >= 0:
            t = int(twin[g])
            g = t - t % 4 + (t + 1) % 4
        following[h] = g
    loops: list[list[int]] = []
    seen: set[int] = set()
    for h in boundary.tolist():
        if h in seen:
            continue
        loop = []
        g = h
        while g not in seen:
            seen.add(g)
            loop.append(g)
            g = following[g]
        loops.append(loop)
    return loops


def count_pinched_vertices(topo: QuadTopology) -> int:
    """Vertices of ``topo`` where faces touch only at a corner (more than one fan of faces)."""
    return sum(len(vertex_fans(topo, v)) > 1 for v in np.flatnonzero(topo.face_count > 0).tolist())


def _components(faces: np.ndarray, n_vertices: int) -> int:
    """Connected pieces among the vertices the faces use."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    used = np.unique(faces)
    rows = np.repeat(faces[:, 0], 3)
    cols = faces[:, 1:].reshape(-1)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return len(np.unique(labels[used]))


def inspect_quad_mesh(vertices: np.ndarray, faces: np.ndarray, *, expected_boundary_loops: int = 0) -> QuadMeshReport:
    """Check a quad mesh for the defects later stages cannot take.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    faces
        int (m, 4) vertex indices, counter-clockwise seen from outside.
    expected_boundary_loops
        Boundary loops the source surface has (0 for a closed part); more
        loops than this are reported as holes.

    Returns
    -------
    QuadMeshReport
        Counts of the mesh; its ``problems`` name each defect found (a mesh whose connectivity cannot be
        built reports only why).
    """
    verts = np.asarray(vertices, dtype=np.float64)
    quads = np.asarray(faces, dtype=np.int64)
    n = len(verts)
    problems: list[str] = []
    if len(quads) == 0:
        return QuadMeshReport(n, 0, (), 0, 0, n, 0, 0, {}, 0, ("the mesh has no faces",))
    if not np.isfinite(verts).all():
        problems.append("some vertices have non-finite coordinates")
    try:
        topo = quad_topology(quads, n)
    except ValueError as exc:
        return QuadMeshReport(n, len(quads), (), 0, 0, 0, 0, 0, {}, 0, (str(exc),))
    loops = boundary_loops(topo)
    lengths = tuple(sorted(len(loop) for loop in loops))
    if len(loops) > expected_boundary_loops:
        problems.append(f"{len(loops) - expected_boundary_loops} hole(s): boundary loops of {list(lengths)} edges "
                        f"where the source has {expected_boundary_loops}")
    used = topo.face_count > 0
    pinched = count_pinched_vertices(topo)
    if pinched:
        problems.append(f"{pinched} non-manifold vertices (faces touch only at a corner)")
    valence2 = int(((topo.valence == 2) & ~topo.boundary_vertex & used).sum())
    if valence2:
        problems.append(f"{valence2} interior vertices of valence 2")
    unused = int((~used).sum())
    interior = used & ~topo.boundary_vertex
    hist = np.bincount(topo.valence[interior])
    euler = int(used.sum() - len(topo.edges) + len(quads))
    return QuadMeshReport(
        n_vertices=n, n_faces=len(quads), boundary_loop_lengths=lengths, non_manifold_vertices=pinched,
        interior_valence2=valence2, unused_vertices=unused, components=_components(quads, n),
        euler_characteristic=euler, valence_histogram={int(k): int(c) for k, c in enumerate(hist) if c},
        extraordinary_vertices=int((interior & (topo.valence != 4)).sum()), problems=tuple(problems),
    )
