"""Check a quad mesh for what later stages rely on, and repair what is small and safe.

Later stages need pure quads, manifold edges and vertices, one consistent
orientation, no holes the input did not have, and no interior vertex of
valence 2 (two quads folded onto each other there). Two repairs are safe
because they change no geometry beyond one quad: merging the two quads around
an interior valence-2 vertex into one, and closing a hole bounded by exactly
four edges with one quad. Anything else is reported, not guessed at.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cam.mesh.quads import QuadTopology, quad_topology, vertex_fans

__all__ = ["QuadMeshReport", "boundary_loops", "drop_unused_vertices", "inspect_quad_mesh", "repair_quad_mesh"]


@dataclass(frozen=True)
class QuadMeshReport:
    """What :func:`inspect_quad_mesh` found. ``problems`` is empty for a mesh later stages accept."""

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
    """Boundary loops as lists of half-edges (each without a twin), in order along the boundary."""
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


def _components(faces: np.ndarray, n_vertices: int) -> int:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    used = np.unique(faces)
    rows = np.repeat(faces[:, 0], 3)
    cols = faces[:, 1:].reshape(-1)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return len(np.unique(labels[used]))


def inspect_quad_mesh(vertices: np.ndarray, faces: np.ndarray, *, expected_boundary_loops: int = 0) -> QuadMeshReport:
    """Check a quad mesh.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    faces
        int (m, 4).
    expected_boundary_loops
        Boundary loops the source surface has (0 for a closed part); more
        loops than this are reported as holes.

    Returns
    -------
    :class:`QuadMeshReport`; its ``problems`` name each defect found.
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
    pinched = 0
    for v in np.flatnonzero(used).tolist():
        if len(vertex_fans(topo, v)) > 1:
            pinched += 1
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


def drop_unused_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove vertices no face uses; returns the new vertices and the re-indexed faces."""
    used = np.zeros(len(vertices), dtype=bool)
    used[np.asarray(faces).reshape(-1)] = True
    new_index = np.cumsum(used) - 1
    return np.asarray(vertices)[used], new_index[faces]


def _merge_valence2(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, int]:
    """Replace the two quads around each interior valence-2 vertex by one quad; returns faces and merges done."""
    merges = 0
    # Each merge lowers the valence of two neighbours, which can make another valence-2 vertex: repeat.
    for _ in range(len(faces)):
        topo = quad_topology(faces, n_vertices)
        candidates = np.flatnonzero((topo.valence == 2) & (topo.face_count == 2) & ~topo.boundary_vertex)
        if not len(candidates):
            break
        v = int(candidates[0])
        h1, h2 = (int(h) for h in topo.outgoing(v))
        f1, f2 = h1 // 4, h2 // 4
        # f1 = v->a->b->c, f2 = v->c->d->a: the merged quad is a->b->c->d.
        q1 = np.roll(faces[f1], -(h1 % 4))
        q2 = np.roll(faces[f2], -(h2 % 4))
        a, b, c = q1[1], q1[2], q1[3]
        d = q2[2]
        if q2[1] != c or q2[3] != a or len({a, b, c, d}) < 4:
            raise ValueError(f"cannot merge the quads around valence-2 vertex {v}: they do not form a quad")
        keep = np.ones(len(faces), dtype=bool)
        keep[[f1, f2]] = False
        faces = np.vstack([faces[keep], [[a, b, c, d]]])
        merges += 1
    return faces, merges


def _collapse_folded(verts: np.ndarray, faces: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Collapse quads whose diagonal is shorter than ``ratio`` × the median edge (a fold: two corners coincide).

    The diagonal's ends merge at their midpoint and the quad disappears; its
    two pairs of sides are glued, which keeps the mesh manifold and oriented
    unless the two ends share another neighbour (then the topology check fails).
    """
    p = verts[faces]
    median_edge = float(np.median(np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2)))
    diag = np.stack([np.linalg.norm(p[:, 2] - p[:, 0], axis=1), np.linalg.norm(p[:, 3] - p[:, 1], axis=1)], axis=1)
    folded = np.flatnonzero(diag.min(axis=1) < ratio * median_edge)
    if not len(folded):
        return verts, faces, 0
    verts = verts.copy()
    target = np.arange(len(verts))

    def find(v: int) -> int:
        while target[v] != v:
            v = int(target[v])
        return v

    keep = np.ones(len(faces), dtype=bool)
    for f in folded.tolist():
        k = int(np.argmin(diag[f]))
        a, b = find(int(faces[f, k])), find(int(faces[f, k + 2]))
        if a != b:
            verts[a] = 0.5 * (verts[a] + verts[b])
            target[b] = a
        keep[f] = False
    roots = np.fromiter((find(v) for v in range(len(verts))), dtype=np.int64, count=len(verts))
    return verts, roots[faces[keep]], len(folded)


def _pair_triangle_holes(verts: np.ndarray, quads: np.ndarray,
                         triangles: list[list[int]]) -> tuple[np.ndarray, np.ndarray, int]:
    """Close 3-edge holes two at a time (see :func:`_pair_round`); strips that crossed wait for the next round.

    Returns the new vertices, quads and the number of pairs closed.

    Raises
    ------
    ValueError
        When some triangle cannot be paired (odd count, no strip to another one).
    """
    left = [list(t) for t in triangles]
    pairs = 0
    while left:
        verts, quads, rest = _pair_round(verts, quads, left)
        if len(rest) == len(left):
            raise ValueError(f"{len(left)} of {len(triangles)} triangular holes could not be paired "
                             "along a strip of quads")
        pairs += (len(left) - len(rest)) // 2
        left = rest
    return verts, quads, pairs


def _pair_round(verts: np.ndarray, quads: np.ndarray,
                triangles: list[list[int]]) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """Close 3-edge holes two at a time: fill each with a triangle and split the quad strip between a pair.

    A triangle gains a fourth corner when one of its edges gets a midpoint;
    the quad across that edge is split in two by the line from this midpoint
    to the midpoint of its opposite edge, and so on along the strip until it
    reaches the other triangle, which takes the last midpoint. Every face
    stays a quad and no T-junction is left. Pairs are chosen shortest strip
    first; strips may not share quads.

    Returns the new vertices and quads, and the triangles left unpaired.
    """
    tris = [list(t) for t in triangles]
    verts_list = [verts]
    n_verts = len(verts)
    quads = quads.copy()

    def key(a: int, b: int) -> tuple[int, int]:
        return (a, b) if a < b else (b, a)

    edge_map: dict[tuple[int, int], list[tuple[str, int]]] = {}
    for kind, faces in (("q", quads.tolist()), ("t", tris)):
        for idx, face in enumerate(faces):
            k = len(face)
            for i in range(k):
                edge_map.setdefault(key(face[i], face[(i + 1) % k]), []).append((kind, idx))

    def strip(t: int, edge: tuple[int, int]) -> tuple[list[tuple[int, int]], int, tuple[int, int]] | None:
        path: list[tuple[int, int]] = []
        came = ("t", t)
        visited: set[int] = set()
        cur = edge
        for _ in range(len(quads) + 1):
            others = [r for r in edge_map.get(key(*cur), []) if r != came]
            if len(others) != 1:
                return None
            kind, idx = others[0]
            if kind == "t":
                return (path, idx, cur) if idx != t else None
            if idx in visited:
                return None
            visited.add(idx)
            q = quads[idx].tolist()
            i = next(j for j in range(4) if key(q[j], q[(j + 1) % 4]) == key(*cur))
            path.append((idx, i))
            cur = (q[(i + 2) % 4], q[(i + 3) % 4])
            came = ("q", idx)
        return None

    candidates = []
    for t, tri in enumerate(tris):
        for i in range(3):
            found = strip(t, (tri[i], tri[(i + 1) % 3]))
            if found is not None:
                path, other, last = found
                candidates.append((len(path), t, (tri[i], tri[(i + 1) % 3]), path, other, last))
    candidates.sort(key=lambda c: c[0])
    paired: set[int] = set()
    used_quads: set[int] = set()
    midpoint: dict[tuple[int, int], int] = {}
    removed: set[int] = set()
    new_faces: list[list[int]] = []

    def mid(a: int, b: int) -> int:
        nonlocal n_verts
        k = key(a, b)
        if k not in midpoint:
            midpoint[k] = n_verts
            verts_list.append(0.5 * (verts[a] + verts[b])[None])
            n_verts += 1
        return midpoint[k]

    def tri_to_quad(t: int, edge: tuple[int, int]) -> list[int]:
        tri = tris[t]
        i = next(j for j in range(3) if key(tri[j], tri[(j + 1) % 3]) == key(*edge))
        return [tri[i], mid(*edge), tri[(i + 1) % 3], tri[(i + 2) % 3]]

    for _, t, first, path, other, last in candidates:
        if t in paired or other in paired or any(idx in used_quads for idx, _ in path):
            continue
        paired |= {t, other}
        new_faces.append(tri_to_quad(t, first))
        for idx, i in path:
            used_quads.add(idx)
            removed.add(idx)
            q = quads[idx].tolist()
            q0, q1, q2, q3 = q[i], q[(i + 1) % 4], q[(i + 2) % 4], q[(i + 3) % 4]
            m_in, m_out = mid(q0, q1), mid(q2, q3)
            new_faces += [[q0, m_in, m_out, q3], [m_in, q1, q2, m_out]]
        new_faces.append(tri_to_quad(other, last))
    keep = np.ones(len(quads), dtype=bool)
    keep[list(removed)] = False
    out = np.vstack([quads[keep], np.asarray(new_faces, dtype=np.int64).reshape(-1, 4)])
    left = [tri for t, tri in enumerate(tris) if t not in paired]
    return np.vstack(verts_list), out, left


def split_into_quads(vertices: np.ndarray, quads: np.ndarray,
                     triangles: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Split every face into quads at its edge midpoints and centroid (a quad into 4, a triangle into 3).

    The result is pure quads whatever mix of triangles and quads came in, with
    the same orientation and boundary; it has four times as many faces.
    Returns vertices float64 (n', 3) and quads int64 (m', 4).
    """
    verts = [np.asarray(vertices, dtype=np.float64)]
    count = len(verts[0])
    midpoint: dict[tuple[int, int], int] = {}
    points: list[np.ndarray] = []
    out: list[list[int]] = []

    def new_point(p: np.ndarray) -> int:
        nonlocal count
        points.append(p)
        count += 1
        return count - 1

    def mid(a: int, b: int) -> int:
        k = (a, b) if a < b else (b, a)
        if k not in midpoint:
            midpoint[k] = new_point(0.5 * (verts[0][a] + verts[0][b]))
        return midpoint[k]

    for face in list(np.asarray(quads, dtype=np.int64).tolist()) + [list(t) for t in triangles]:
        k = len(face)
        c = new_point(verts[0][face].mean(axis=0))
        for i in range(k):
            out.append([face[i], mid(face[i], face[(i + 1) % k]), c, mid(face[i - 1], face[i])])
    allv = np.vstack([verts[0], np.asarray(points).reshape(-1, 3)])
    return allv, np.asarray(out, dtype=np.int64).reshape(-1, 4)


def repair_quad_mesh(
    vertices: np.ndarray, faces: np.ndarray, *, expected_boundary_loops: int = 0, fold_ratio: float = 0.01,
    split_unpaired: bool = False,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Apply the safe repairs: collapse folded quads, merge quads at interior valence-2 vertices,
    close 3-edge holes in pairs and 4-edge holes with a quad, drop unused vertices.

    ``fold_ratio``: a quad whose shorter diagonal is below this fraction of the
    median edge length is folded (QuadriFlow leaves a few at sharp corners,
    with two corners at the same point) and is collapsed along that diagonal.

    ``split_unpaired``: when the 3-edge holes cannot be paired, fill each with a
    triangle and split every face into quads (:func:`split_into_quads`, four
    times the faces) instead of raising.

    Holes are closed only while the mesh has more boundary loops than
    ``expected_boundary_loops``, smallest first. Returns vertices float64
    (n', 3), faces int64 (m', 4) and the repairs done as sentences.

    Raises
    ------
    ValueError
        When the connectivity cannot be built (see :func:`quad_topology`) or
        a valence-2 vertex sits between quads that do not merge into one.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    quads = np.asarray(faces, dtype=np.int64)
    repairs: list[str] = []
    verts, quads, folded = _collapse_folded(verts, quads, fold_ratio)
    if folded:
        repairs.append(f"collapsed {folded} folded quad(s) (a diagonal shorter than {fold_ratio:g} × the median edge)")
    quads, merges = _merge_valence2(quads, len(verts))
    if merges:
        repairs.append(f"merged the quads around {merges} interior valence-2 vertices")
    topo = quad_topology(quads, len(verts))
    loops = sorted(boundary_loops(topo), key=len)
    excess = len(loops) - expected_boundary_loops
    triangles = [[int(topo.origin[h]) for h in loop][::-1] for loop in loops if len(loop) == 3]
    if excess > 0 and triangles and len(triangles) <= excess:
        try:
            verts, quads, pairs = _pair_triangle_holes(verts, quads, triangles)
            repairs.append(f"closed {2 * pairs} triangular hole(s) in pairs, splitting the strip of quads between them")
        except ValueError as exc:
            if not split_unpaired:
                raise
            verts, quads = split_into_quads(verts, quads, triangles)
            repairs.append(f"{exc}: filled {len(triangles)} triangular hole(s) and split every face into quads")
        topo = quad_topology(quads, len(verts))
        loops = sorted(boundary_loops(topo), key=len)
        excess = len(loops) - expected_boundary_loops
    filled = 0
    new_faces = []
    for loop in loops:
        if filled >= excess or len(loop) != 4:
            continue
        # Boundary half-edges run with the existing faces on their left; the patch runs the other way.
        ring = [int(topo.origin[h]) for h in loop]
        new_faces.append(ring[::-1])
        filled += 1
    if filled:
        quads = np.vstack([quads, np.asarray(new_faces, dtype=np.int64)])
        repairs.append(f"closed {filled} hole(s) of 4 edges with a quad each")
        quads, merges = _merge_valence2(quads, len(verts))
        if merges:
            repairs.append(f"merged the quads around {merges} interior valence-2 vertices")
    verts2, quads2 = drop_unused_vertices(verts, quads)
    if len(verts2) != len(verts):
        repairs.append(f"dropped {len(verts) - len(verts2)} unused vertices")
    return verts2, quads2, repairs
