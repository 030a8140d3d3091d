"""Pair the triangles of a coarse mesh into quads, never across a crease.

Two triangles beside an edge on no crease chain make a quad when it is convex and not folded; its score is how
near its corners are to right angles. Pairs are taken greedily, best score first, and each triangle left over is
then paired along an alternating path (a chain of pairs re-paired one step along, so that it and another
unpaired triangle are both taken: an augmenting path of the matching). What is still unpaired stays a triangle;
the subdivision (:mod:`cam.remesh.subdivide`) turns a triangle into three quads.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from cam.remesh.coarse import edge_table

__all__ = ["pair_triangles", "quad_scores"]

# A quad with a corner over this angle, degrees, or with its two triangles' normals further apart, is not made.
_MAX_CORNER_DEG = 170.0
_MAX_FOLD_DEG = 60.0
# Longest alternating path searched from an unpaired triangle, in pairs.
_MAX_PATH = 40


def quad_scores(vertices: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """How square each quad's corners are: 1 − (largest |corner − 90°|) / 90°, float64 (k,) in [0, 1]; -1 for
    a quad that is not convex or has a corner over 170° (``vertices`` (n, 3) mm, ``quads`` (k, 4), ccw)."""
    p = vertices[quads]
    normal = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    worst = np.zeros(len(quads))
    convex = np.ones(len(quads), dtype=bool)
    for i in range(4):
        u = p[:, (i + 1) % 4] - p[:, i]
        w = p[:, (i - 1) % 4] - p[:, i]
        sin = np.einsum("ij,ij->i", np.cross(u, w), normal)
        cos = np.einsum("ij,ij->i", u, w)
        angle = np.degrees(np.arctan2(sin, cos))
        convex &= (angle > 0) & (angle < _MAX_CORNER_DEG)
        worst = np.maximum(worst, np.abs(angle - 90.0))
    return np.where(convex, 1.0 - worst / 90.0, -1.0)


def pair_triangles(vertices: np.ndarray, triangles: np.ndarray, crease_edges: set[tuple[int, int]]
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Pair triangles into quads across edges that are not creases.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertices, mm.
    triangles : (m, 3) int64
        A closed manifold triangle mesh, counter-clockwise seen from outside.
    crease_edges : set of (int, int)
        Edges (sorted vertex pairs) no quad may have as its diagonal.

    Returns
    -------
    quads : (q, 4) int64
        The pairs, counter-clockwise like their triangles.
    pairs : (q, 2) int64
        The two triangles of each quad; every other triangle is unpaired.
    """
    edges, faces = edge_table(triangles)
    a, b = edges[:, 0], edges[:, 1]
    c = triangles[faces[:, 0]].sum(axis=1) - a - b
    d = triangles[faces[:, 1]].sum(axis=1) - a - b
    # faces[:, 0] runs a -> b (third corner c), faces[:, 1] runs b -> a (third d): the quad runs a, d, b, c.
    quads = np.stack([a, d, b, c], axis=1)
    score = quad_scores(vertices, quads)
    n1 = np.cross(vertices[b] - vertices[a], vertices[c] - vertices[a])
    n2 = np.cross(vertices[a] - vertices[b], vertices[d] - vertices[b])
    cos = np.einsum("ij,ij->i", n1, n2) / np.maximum(np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1), 1e-300)
    crease = np.array([(x, y) in crease_edges for x, y in edges.tolist()], dtype=bool)
    usable = np.flatnonzero((score >= 0) & ~crease & (cos > np.cos(np.radians(_MAX_FOLD_DEG))))
    mate = _greedy(faces, score, usable, len(triangles))
    _augment(faces, score, usable, mate)
    pair_edge = {}
    for e in usable.tolist():
        f1, f2 = faces[e]
        pair_edge[(f1, f2)] = pair_edge[(f2, f1)] = e
    chosen = [pair_edge[(f, int(mate[f]))] for f in range(len(triangles)) if mate[f] > f]
    chosen = _keep_three_faces(edges, triangles, chosen, score)
    return quads[chosen], faces[chosen]


def _keep_three_faces(edges: np.ndarray, triangles: np.ndarray, chosen: list[int], score: np.ndarray) -> list[int]:
    """The pairs less those that leave a vertex with fewer than three faces (a pair whose diagonal ends at a
    vertex takes one face from it; with two it would be a valence-2 vertex of the quads): the worst pair at such
    a vertex is undone until none is left."""
    faces_at = np.bincount(triangles.ravel(), minlength=int(triangles.max()) + 1)
    chosen = sorted(chosen, key=lambda e: score[e])
    while True:
        count = faces_at.copy()
        for e in chosen:
            count[edges[e]] -= 1
        low = set(np.flatnonzero(count < 3).tolist())
        undo = next((e for e in chosen if low & set(edges[e].tolist())), None)
        if undo is None:
            return chosen
        chosen.remove(undo)


def _greedy(faces: np.ndarray, score: np.ndarray, usable: np.ndarray, n: int) -> np.ndarray:
    mate = np.full(n, -1, dtype=np.int64)
    for e in usable[np.argsort(-score[usable], kind="stable")].tolist():
        f1, f2 = faces[e]
        if mate[f1] < 0 and mate[f2] < 0:
            mate[f1], mate[f2] = f2, f1
    return mate


def _augment(faces: np.ndarray, score: np.ndarray, usable: np.ndarray, mate: np.ndarray) -> None:
    """Pair unpaired triangles along alternating paths (breadth first, best-scored steps first), in place."""
    neighbours: dict[int, list[int]] = {}
    for e in usable[np.argsort(-score[usable], kind="stable")].tolist():
        f1, f2 = (int(x) for x in faces[e])
        neighbours.setdefault(f1, []).append(f2)
        neighbours.setdefault(f2, []).append(f1)
    for start in np.flatnonzero(mate < 0).tolist():
        if mate[start] >= 0:
            continue
        parent = {start: -1}
        queue = deque([(start, 0)])
        end = -1
        while queue and end < 0:
            t, depth = queue.popleft()
            if depth >= _MAX_PATH:
                continue
            for u in neighbours.get(t, ()):
                if u in parent or u == start:
                    continue
                if mate[u] < 0:
                    parent[u] = t
                    end = u
                    break
                w = int(mate[u])
                if w in parent:
                    continue
                parent[u] = t
                parent[w] = u
                queue.append((w, depth + 1))
        if end < 0:
            continue
        # walk back: end - t - (mate pairs) ... - start, re-pairing every other step
        u = end
        while u >= 0:
            t = parent[u]
            nxt = parent[t] if t != start else -1
            mate[u], mate[t] = t, u
            u = nxt
