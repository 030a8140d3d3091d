"""Close the triangular holes QuadriFlow sometimes leaves, keeping every face a quad.

A hole bounded by three edges cannot take a quad. Two of them can be closed
together: each is filled with a triangle that gains a fourth corner at the
midpoint of one of its edges, and the strip of quads between the two is split
lengthwise so that no T-junction is left (:func:`pair_triangle_holes`). Where
no such pairing exists, :func:`split_into_quads` fills each hole with a
triangle and splits every face into quads instead, at four times the faces.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pair_triangle_holes", "split_into_quads"]

#: (kind, index): "q" for a quad of the mesh, "t" for a triangular hole.
_FaceRef = tuple[str, int]
#: The mesh quads along a strip, each as (quad, side through which the strip enters it).
_Path = list[tuple[int, int]]
#: (quads along it, first triangle, its edge, path, second triangle, its edge).
_Candidate = tuple[int, int, tuple[int, int], _Path, int, tuple[int, int]]


def _edge_key(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


def pair_triangle_holes(vertices: np.ndarray, quads: np.ndarray,
                        triangles: list[list[int]]) -> tuple[np.ndarray, np.ndarray, int]:
    """Close 3-edge holes two at a time, splitting the strip of quads between each pair.

    Pairs are chosen shortest strip first and strips may not share quads; strips that crossed one
    already split wait for the next round, which runs on the mesh that round left.

    Parameters
    ----------
    vertices
        float64 (n, 3), mm.
    quads
        int64 (m, 4) vertex indices.
    triangles
        The holes, each as three vertex indices in the orientation of the faces that will fill them.

    Returns
    -------
    vertices : ndarray
        float64 (n', 3), mm: the input's, then the midpoints of the split edges.
    quads : ndarray
        int64 (m', 4): the quads not split, then the filled holes and the split strips.
    pairs : int
        Pairs of holes closed.

    Raises
    ------
    ValueError
        When some triangle cannot be paired (odd count, no strip to another one).
    """
    left = [list(t) for t in triangles]
    pairs = 0
    while left:
        vertices, quads, rest = _pair_round(vertices, quads, left)
        if len(rest) == len(left):
            raise ValueError(f"{len(left)} of {len(triangles)} triangular holes could not be paired "
                             "along a strip of quads")
        pairs += (len(left) - len(rest)) // 2
        left = rest
    return vertices, quads, pairs


def _pair_round(verts: np.ndarray, quads: np.ndarray,
                triangles: list[list[int]]) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """One round of :func:`pair_triangle_holes`: returns the new vertices and quads, and the triangles left."""
    tris = [list(t) for t in triangles]
    faces_at = _faces_by_edge(quads, tris)
    candidates = _strip_candidates(faces_at, quads, tris)
    midpoints: dict[tuple[int, int], int] = {}
    paired, split, new_faces = _close_pairs(candidates, quads, tris, midpoints, len(verts))
    keep = np.ones(len(quads), dtype=bool)
    keep[list(split)] = False
    out = np.vstack([quads[keep], np.asarray(new_faces, dtype=np.int64).reshape(-1, 4)])
    ends = np.asarray(list(midpoints), dtype=np.int64).reshape(-1, 2)
    new_verts = np.vstack([verts, 0.5 * (verts[ends[:, 0]] + verts[ends[:, 1]])])
    left = [tri for t, tri in enumerate(tris) if t not in paired]
    return new_verts, out, left


def _faces_by_edge(quads: np.ndarray, tris: list[list[int]]) -> dict[tuple[int, int], list[_FaceRef]]:
    """The quads and triangles on each undirected edge, quads first, each in index order."""
    faces_at: dict[tuple[int, int], list[_FaceRef]] = {}
    for kind, faces in (("q", quads.tolist()), ("t", tris)):
        for idx, face in enumerate(faces):
            k = len(face)
            for i in range(k):
                faces_at.setdefault(_edge_key(face[i], face[(i + 1) % k]), []).append((kind, idx))
    return faces_at


def _find_strip(faces_at: dict[tuple[int, int], list[_FaceRef]], quads: np.ndarray, t: int,
                edge: tuple[int, int]) -> tuple[_Path, int, tuple[int, int]] | None:
    """The strip of quads from triangle ``t`` across ``edge`` to another triangle: path, that triangle, its edge.

    None when the strip reaches the boundary, a non-manifold edge, a quad twice or triangle ``t`` itself.
    """
    path: _Path = []
    came: _FaceRef = ("t", t)
    visited: set[int] = set()
    cur = edge
    for _ in range(len(quads) + 1):
        others = [r for r in faces_at.get(_edge_key(*cur), []) if r != came]
        if len(others) != 1:
            return None
        kind, idx = others[0]
        if kind == "t":
            return (path, idx, cur) if idx != t else None
        if idx in visited:
            return None
        visited.add(idx)
        q = quads[idx].tolist()
        i = next(j for j in range(4) if _edge_key(q[j], q[(j + 1) % 4]) == _edge_key(*cur))
        path.append((idx, i))
        cur = (q[(i + 2) % 4], q[(i + 3) % 4])
        came = ("q", idx)
    return None


def _strip_candidates(faces_at: dict[tuple[int, int], list[_FaceRef]], quads: np.ndarray,
                      tris: list[list[int]]) -> list[_Candidate]:
    """Every strip from each triangle's three edges to another triangle, shortest first (stable on ties)."""
    candidates: list[_Candidate] = []
    for t, tri in enumerate(tris):
        for i in range(3):
            found = _find_strip(faces_at, quads, t, (tri[i], tri[(i + 1) % 3]))
            if found is not None:
                path, other, last = found
                candidates.append((len(path), t, (tri[i], tri[(i + 1) % 3]), path, other, last))
    candidates.sort(key=lambda c: c[0])
    return candidates


def _close_pairs(candidates: list[_Candidate], quads: np.ndarray, tris: list[list[int]],
                 midpoints: dict[tuple[int, int], int], first_new: int) -> tuple[set[int], set[int], list[list[int]]]:
    """Take the candidates in order while their triangles and quads are free: the triangles paired, the quads
    split, and the faces that replace them. New midpoints are numbered from ``first_new`` in ``midpoints``."""
    paired: set[int] = set()
    split: set[int] = set()
    new_faces: list[list[int]] = []
    for _, t, first, path, other, last in candidates:
        if t in paired or other in paired or any(idx in split for idx, _ in path):
            continue
        paired |= {t, other}
        new_faces.append(_triangle_to_quad(tris[t], first, midpoints, first_new))
        for idx, i in path:
            split.add(idx)
            new_faces += _split_quad(quads[idx].tolist(), i, midpoints, first_new)
        new_faces.append(_triangle_to_quad(tris[other], last, midpoints, first_new))
    return paired, split, new_faces


def _midpoint(a: int, b: int, midpoints: dict[tuple[int, int], int], first_new: int) -> int:
    """Index of the midpoint of edge (a, b), numbered on first use so that both sides of an edge share it."""
    return midpoints.setdefault(_edge_key(a, b), first_new + len(midpoints))


def _triangle_to_quad(tri: list[int], edge: tuple[int, int], midpoints: dict[tuple[int, int], int],
                      first_new: int) -> list[int]:
    """The triangle as a quad whose extra corner is the midpoint of ``edge``."""
    i = next(j for j in range(3) if _edge_key(tri[j], tri[(j + 1) % 3]) == _edge_key(*edge))
    return [tri[i], _midpoint(*edge, midpoints, first_new), tri[(i + 1) % 3], tri[(i + 2) % 3]]


def _split_quad(q: list[int], i: int, midpoints: dict[tuple[int, int], int], first_new: int) -> list[list[int]]:
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
