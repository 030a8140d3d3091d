"""Close the odd holes QuadriFlow sometimes leaves (of 3, 5 or 7 edges), keeping every face a quad.

A hole bounded by an odd number of edges cannot be closed with quads, and a closed quad mesh has an
even number of them. Two can be closed together: each gains a corner at the midpoint of one of its
edges, and the strip of quads between the two is split lengthwise so that no T-junction is left
(:func:`pair_odd_holes`); a quad the strip crosses twice, once each way, is split into four. A
triangle then is a quad; a hole of 5 or 7 edges is one of 6 or 8, which `cam.remesh.repair` closes.
Where no such pairing exists, :func:`split_into_quads` fills each hole and splits every face into
quads instead, at four times the faces.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pair_odd_holes", "split_into_quads"]

#: (kind, index): "q" for a quad of the mesh, "t" for an odd hole.
_FaceRef = tuple[str, int]
#: The mesh quads along a strip, each as (quad, side through which the strip enters it).
_Path = list[tuple[int, int]]
#: (quads along it, first hole, its edge, path, second hole, its edge).
_Candidate = tuple[int, int, tuple[int, int], _Path, int, tuple[int, int]]


def _edge_key(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


def pair_odd_holes(vertices: np.ndarray, quads: np.ndarray, holes: list[list[int]], *,
                   max_added_faces: int | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Close odd holes two at a time, splitting the strip of quads between each pair.

    Pairs are chosen shortest strip first and strips may not share quads; strips that crossed one
    already split wait for the next round, which runs on the mesh that round left. A strip may cross
    itself (on a closed part a row of quads can wrap round it).

    Parameters
    ----------
    vertices
        float64 (n, 3), mm.
    quads
        int64 (m, 4) vertex indices.
    holes
        The holes, each as its 3, 5 or 7 vertex indices in the orientation of the faces that will fill them.
    max_added_faces
        The most faces the pairing may add (a strip that wanders over much of the part leaves a long band of
        half-width quads); None: no limit.

    Returns
    -------
    vertices : ndarray
        float64 (n', 3), mm: the input's, then the midpoints of the split edges and the centres of quads
        split into four.
    quads : ndarray
        int64 (m', 4): the quads not split, then the triangles made quads and the split strips. A hole of 5
        or 7 edges is left open, with 6 or 8.
    pairs : int
        Pairs of holes closed.

    Raises
    ------
    ValueError
        When some hole cannot be paired (odd count, no strip to another one), or only by adding more than
        `max_added_faces`.
    """
    left = [list(t) for t in holes]
    pairs, start = 0, len(quads)
    while left:
        vertices, quads, rest = _pair_round(vertices, quads, left)
        if len(rest) == len(left):
            raise ValueError(f"{len(left)} of {len(holes)} odd holes could not be paired along a strip of quads")
        if max_added_faces is not None and len(quads) - start > max_added_faces:
            raise ValueError(f"{len(holes)} odd holes could be paired only along strips that add "
                             f"{len(quads) - start} faces (at most {max_added_faces})")
        pairs += (len(left) - len(rest)) // 2
        left = rest
    return vertices, quads, pairs


def _pair_round(verts: np.ndarray, quads: np.ndarray,
                holes: list[list[int]]) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """One round of :func:`pair_odd_holes`: returns the new vertices and quads, and the holes left."""
    holes = [list(t) for t in holes]
    faces_at = _faces_by_edge(quads, holes)
    candidates = _strip_candidates(faces_at, quads, holes)
    midpoints: dict[tuple[int, ...], int] = {}
    paired, split, new_faces = _close_pairs(candidates, quads, holes, midpoints, len(verts))
    keep = np.ones(len(quads), dtype=bool)
    keep[list(split)] = False
    out = np.vstack([quads[keep], np.asarray(new_faces, dtype=np.int64).reshape(-1, 4)])
    # Each new vertex is the mean of the corners it was made from: an edge's two, a quad's four.
    new_verts = np.vstack([verts, *(verts[list(key)].mean(axis=0, keepdims=True) for key in midpoints)])
    left = [hole for t, hole in enumerate(holes) if t not in paired]
    return new_verts, out, left


def _faces_by_edge(quads: np.ndarray, holes: list[list[int]]) -> dict[tuple[int, int], list[_FaceRef]]:
    """The quads and holes on each undirected edge, quads first, each in index order."""
    faces_at: dict[tuple[int, int], list[_FaceRef]] = {}
    for kind, faces in (("q", quads.tolist()), ("t", holes)):
        for idx, face in enumerate(faces):
            k = len(face)
            for i in range(k):
                faces_at.setdefault(_edge_key(face[i], face[(i + 1) % k]), []).append((kind, idx))
    return faces_at


def _find_strip(faces_at: dict[tuple[int, int], list[_FaceRef]], quads: np.ndarray, t: int,
                edge: tuple[int, int]) -> tuple[_Path, int, tuple[int, int]] | None:
    """The strip of quads from hole ``t`` across ``edge`` to another hole: path, that hole, its edge.

    None when the strip reaches the boundary, a non-manifold edge, a quad twice the same way or hole ``t``
    itself. A quad crossed once each way appears twice in the path.
    """
    path: _Path = []
    came: _FaceRef = ("t", t)
    visited: dict[int, int] = {}  # quad: the parity of the side the strip entered it through; 2: both
    cur = edge
    for _ in range(2 * len(quads) + 1):
        others = [r for r in faces_at.get(_edge_key(*cur), []) if r != came]
        if len(others) != 1:
            return None
        kind, idx = others[0]
        if kind == "t":
            return (path, idx, cur) if idx != t else None
        q = quads[idx].tolist()
        i = next(j for j in range(4) if _edge_key(q[j], q[(j + 1) % 4]) == _edge_key(*cur))
        if idx in visited and visited[idx] != 1 - i % 2:
            return None  # the same way again (a loop), or a third time
        visited[idx] = 2 if idx in visited else i % 2
        path.append((idx, i))
        cur = (q[(i + 2) % 4], q[(i + 3) % 4])
        came = ("q", idx)
    return None


def _strip_candidates(faces_at: dict[tuple[int, int], list[_FaceRef]], quads: np.ndarray,
                      holes: list[list[int]]) -> list[_Candidate]:
    """Every strip from each hole's edges to another hole, shortest first (stable on ties)."""
    candidates: list[_Candidate] = []
    for t, hole in enumerate(holes):
        for i in range(len(hole)):
            edge = (hole[i], hole[(i + 1) % len(hole)])
            found = _find_strip(faces_at, quads, t, edge)
            if found is not None:
                path, other, last = found
                candidates.append((len(path), t, edge, path, other, last))
    candidates.sort(key=lambda c: c[0])
    return candidates


def _close_pairs(candidates: list[_Candidate], quads: np.ndarray, holes: list[list[int]],
                 midpoints: dict[tuple[int, ...], int], first_new: int) -> tuple[set[int], set[int], list[list[int]]]:
    """Take the candidates in order while their holes and quads are free: the holes paired, the quads split,
    and the faces that replace them (a triangle's quad; a longer hole stays open, its edge split). New
    vertices are numbered from ``first_new`` in ``midpoints``."""
    paired: set[int] = set()
    split: set[int] = set()
    new_faces: list[list[int]] = []
    for _, t, first, path, other, last in candidates:
        if t in paired or other in paired or any(idx in split for idx, _ in path):
            continue
        paired |= {t, other}
        if len(holes[t]) == 3:
            new_faces.append(_triangle_to_quad(holes[t], first, midpoints, first_new))
        sides: dict[int, list[int]] = {}
        for idx, i in path:
            sides.setdefault(idx, []).append(i)
        split |= set(sides)
        for idx, entered in sides.items():
            q = quads[idx].tolist()
            new_faces += (_split_quad(q, entered[0], midpoints, first_new) if len(entered) == 1
                          else _split_quad_in_four(q, midpoints, first_new))
        if len(holes[other]) == 3:
            new_faces.append(_triangle_to_quad(holes[other], last, midpoints, first_new))
    return paired, split, new_faces


def _midpoint(a: int, b: int, midpoints: dict[tuple[int, ...], int], first_new: int) -> int:
    """Index of the midpoint of edge (a, b), numbered on first use so that both sides of an edge share it."""
    return midpoints.setdefault(_edge_key(a, b), first_new + len(midpoints))


def _split_quad_in_four(q: list[int], midpoints: dict[tuple[int, ...], int], first_new: int) -> list[list[int]]:
    """Quad ``q`` crossed by a strip both ways: four quads about its centre (a new vertex, keyed by the quad's
    corners in ``midpoints``)."""
    m = [_midpoint(q[i], q[(i + 1) % 4], midpoints, first_new) for i in range(4)]
    c = midpoints.setdefault(tuple(q), first_new + len(midpoints))
    return [[q[0], m[0], c, m[3]], [m[0], q[1], m[1], c], [c, m[1], q[2], m[2]], [m[3], c, m[2], q[3]]]


def _triangle_to_quad(tri: list[int], edge: tuple[int, int], midpoints: dict[tuple[int, ...], int],
                      first_new: int) -> list[int]:
    """The triangle as a quad whose extra corner is the midpoint of ``edge``."""
    i = next(j for j in range(3) if _edge_key(tri[j], tri[(j + 1) % 3]) == _edge_key(*edge))
    return [tri[i], _midpoint(*edge, midpoints, first_new), tri[(i + 1) % 3], tri[(i + 2) % 3]]


def _split_quad(q: list[int], i: int, midpoints: dict[tuple[int, ...], int], first_new: int) -> list[list[int]]:
    """Quad ``q`` entered through side ``i``, cut in two from that side's midpoint to the opposite side's."""
    q0, q1, q2, q3 = q[i], q[(i + 1) % 4], q[(i + 2) % 4], q[(i + 3) % 4]
    m_in, m_out = _midpoint(q0, q1, midpoints, first_new), _midpoint(q2, q3, midpoints, first_new)
    return [[q0, m_in, m_out, q3], [m_in, q1, q2, m_out]]


def split_into_quads(vertices: np.ndarray, quads: np.ndarray,
                     triangles: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Split every face into quads at its edge midpoints and centroid (a quad into 4, a triangle into 3).

    The result is pure quads whatever mix of triangles and quads came in, with
    the same orientation and boundary.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    quads
        int (m, 4) vertex indices.
    triangles
        Triangles to split with them (the holes to fill), each three vertex indices.

    Returns
    -------
    vertices : ndarray
        float64 (n', 3), mm: the input's, then each face's centroid and its new edge midpoints.
    quads : ndarray
        int64 (4m + 3t, 4) vertex indices, each input face's pieces in a row.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    count = len(verts)
    midpoint: dict[tuple[int, int], int] = {}
    points: list[np.ndarray] = []
    out: list[list[int]] = []

    def new_point(p: np.ndarray) -> int:
        nonlocal count
        points.append(p)
        count += 1
        return count - 1

    def mid(a: int, b: int) -> int:
        k = _edge_key(a, b)
        if k not in midpoint:
            midpoint[k] = new_point(0.5 * (verts[a] + verts[b]))
        return midpoint[k]

    for face in list(np.asarray(quads, dtype=np.int64).tolist()) + [list(t) for t in triangles]:
        k = len(face)
        c = new_point(verts[face].mean(axis=0))
        for i in range(k):
            out.append([face[i], mid(face[i], face[(i + 1) % k]), c, mid(face[i - 1], face[i])])
    allv = np.vstack([verts, np.asarray(points).reshape(-1, 3)])
    return allv, np.asarray(out, dtype=np.int64).reshape(-1, 4)
