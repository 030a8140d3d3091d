"""Compiled half-edge collapses of a triangle mesh that keep its creases (`cam.remesh.coarse`'s coarsening).

A collapse u → v removes vertex u and re-attaches its triangles to v, which keeps its place: every vertex left is
a vertex of the input, on its surface. Creases are kept as edge paths: a vertex inside a crease chain collapses only
into one of its two chain neighbours (so the chain loses a vertex and stays a path), a chain's end never
collapses, and a vertex on no crease collapses into any neighbour. A collapse is taken only where the mesh stays
a manifold (the two vertices share exactly two neighbours), no triangle turns by more than a limit or
degenerates, no edge grows over a limit, and the quadric error of the planes that end at v stays under a limit.

Vertex u's triangles are listed in ``refs[start[u]:start[u] + count[u]]``; a collapse appends v's new list at
the end (the scheme of Sp4cerat's fast quadric simplification), and the lists are rebuilt when that runs out.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["collapse_short_edges", "plane_quadrics", "point_plane_quadrics"]

_ON_CHAIN, _CORNER = 1, 2


def plane_quadrics(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex's quadric of its triangles' planes (area-weighted) and the weight (area) summed into it.

    Returns float64 (n, 10) (the symmetric 4 × 4 matrix's upper triangle: aa ab ac ad bb bc bd cc cd dd) and
    float64 (n,), mm².
    """
    p = vertices[triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area2 = np.linalg.norm(n, axis=1)
    unit = n / np.maximum(area2, 1e-300)[:, None]
    q = point_plane_quadrics(p[:, 0], unit) * (0.5 * area2)[:, None]
    quadric = np.zeros((len(vertices), 10))
    weight = np.zeros(len(vertices))
    for k in range(3):
        np.add.at(quadric, triangles[:, k], q)
        np.add.at(weight, triangles[:, k], 0.5 * area2)
    return quadric, weight


def point_plane_quadrics(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The quadric (float64 (n, 10), unit weight) of the plane through each point (n, 3) with its unit normal."""
    a, b, c = normals.T
    d = -np.einsum("ij,ij->i", normals, points)
    return np.stack([a * a, a * b, a * c, a * d, b * b, b * c, b * d, c * c, c * d, d * d], axis=1)


@njit(cache=True)
def _build_refs(F, alive, n, spare):
    count = np.zeros(n, dtype=np.int64)
    for f in range(F.shape[0]):
        if alive[f]:
            for k in range(3):
                count[F[f, k]] += 1
    start = np.zeros(n, dtype=np.int64)
    total = 0
    for v in range(n):
        start[v] = total
        total += count[v]
    refs = np.empty(total + spare, dtype=np.int64)
    fill = np.zeros(n, dtype=np.int64)
    for f in range(F.shape[0]):
        if alive[f]:
            for k in range(3):
                v = F[f, k]
                refs[start[v] + fill[v]] = f
                fill[v] += 1
    return start, count, refs, total


@njit(cache=True, inline="always")
def _quadric_at(q, x, y, z):
    return (q[0] * x * x + 2.0 * q[1] * x * y + 2.0 * q[2] * x * z + 2.0 * q[3] * x + q[4] * y * y
            + 2.0 * q[5] * y * z + 2.0 * q[6] * y + q[7] * z * z + 2.0 * q[8] * z + q[9])


@njit(cache=True, inline="always")
def _normal(V, a, b, c):
    ux, uy, uz = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
    wx, wy, wz = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
    return uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx


@njit(cache=True)
def _collapse_cost(u, v, V, F, alive, kind, cn, Q, W, start, count, refs, mark, stamp, seen, size, high, err,
                   cos_turn, min_area2):
    """The quadric error of collapsing u into v, or -1 where that collapse is not allowed."""
    if kind[u] == _CORNER:
        return -1.0
    if kind[u] == _ON_CHAIN and cn[u, 0] != v and cn[u, 1] != v:
        return -1.0
    # u's neighbours marked, then v's counted once each: a manifold collapse shares exactly two
    for i in range(start[u], start[u] + count[u]):
        f = refs[i]
        if alive[f]:
            for k in range(3):
                mark[F[f, k]] = stamp
    common = 0
    for i in range(start[v], start[v] + count[v]):
        f = refs[i]
        if alive[f]:
            for k in range(3):
                w = F[f, k]
                if w != u and w != v and mark[w] == stamp and seen[w] != stamp:
                    seen[w] = stamp
                    common += 1
    if common != 2:
        return -1.0
    for i in range(start[u], start[u] + count[u]):
        f = refs[i]
        if not alive[f]:
            continue
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        if a == v or b == v or c == v:
            continue
        n0x, n0y, n0z = _normal(V, a, b, c)
        a1 = v if a == u else a
        b1 = v if b == u else b
        c1 = v if c == u else c
        n1x, n1y, n1z = _normal(V, a1, b1, c1)
        l0 = n0x * n0x + n0y * n0y + n0z * n0z
        l1 = n1x * n1x + n1y * n1y + n1z * n1z
        if l1 <= min_area2:
            return -1.0
        if n0x * n1x + n0y * n1y + n0z * n1z < cos_turn * math.sqrt(l0 * l1):
            return -1.0
        for w in (a1, b1, c1):
            if w != v:
                dx, dy, dz = V[w, 0] - V[v, 0], V[w, 1] - V[v, 1], V[w, 2] - V[v, 2]
                limit = high * min(size[v], size[w])
                if dx * dx + dy * dy + dz * dz > limit * limit:
                    return -1.0
    q = Q[u] + Q[v]
    cost = max(_quadric_at(q, V[v, 0], V[v, 1], V[v, 2]), 0.0) / max(W[u] + W[v], 1e-300)
    if cost > (err * size[v]) ** 2:
        return -1.0
    return cost


@njit(cache=True)
def collapse_short_edges(V, F, alive, kind, cn, Q, W, size, low, high, err, max_turn_deg, passes):
    """Collapse the edges shorter than ``low`` times their ends' size, shorter ones first, where the rules allow.

    Parameters
    ----------
    V : (n, 3) float64
        Vertices, mm (not moved).
    F : (m, 3) int64
        Triangles; changed in place (u replaced by v).
    alive : (m,) bool
        Triangles still in the mesh; the two beside a collapsed edge are cleared.
    kind : (n,) int8
        0 on no crease, 1 inside a chain, 2 a chain's end.
    cn : (n, 2) int64
        The two chain neighbours of each vertex inside a chain (-1 for the others); kept up to date.
    Q, W : (n, 10) float64, (n,) float64
        Plane quadrics and their weights (`plane_quadrics`); v takes u's.
    size : (n,) float64
        The edge length each vertex aims for, mm.
    low, high, err : float
        An edge under ``low`` times the smaller size of its ends is collapsed unless an edge would grow over
        ``high`` times the smaller size of its ends, or the quadric error (root mean square distance of the
        planes merged, mm) would exceed ``err`` times the size of the vertex kept.
    max_turn_deg : float
        Largest turn of a triangle's normal in one collapse, degrees.
    passes : int
        The length threshold grows to ``low`` times the sizes in this many sweeps.

    Returns
    -------
    int
        Collapses made.
    """
    n = V.shape[0]
    m = F.shape[0]
    mark = np.full(n, -1, dtype=np.int64)
    seen = np.full(n, -1, dtype=np.int64)
    stamp = 0
    cos_turn = math.cos(math.radians(max_turn_deg))
    min_area2 = (1e-9 * size.min() * size.min()) ** 2
    spare = 4 * m + 64
    done = 0
    for p in range(passes):
        share = low * (p + 1) / passes
        start, count, refs, used = _build_refs(F, alive, n, spare)
        for f in range(m):
            if not alive[f]:
                continue
            for j in range(3):
                a = F[f, j]
                b = F[f, (j + 1) % 3]
                dx, dy, dz = V[a, 0] - V[b, 0], V[a, 1] - V[b, 1], V[a, 2] - V[b, 2]
                threshold = share * min(size[a], size[b])
                if dx * dx + dy * dy + dz * dz >= threshold * threshold:
                    continue
                stamp += 1
                cost_ab = _collapse_cost(a, b, V, F, alive, kind, cn, Q, W, start, count, refs, mark, stamp, seen,
                                         size, high, err, cos_turn, min_area2)
                stamp += 1
                cost_ba = _collapse_cost(b, a, V, F, alive, kind, cn, Q, W, start, count, refs, mark, stamp, seen,
                                         size, high, err, cos_turn, min_area2)
                if cost_ab < 0 and cost_ba < 0:
                    continue
                if cost_ba < 0 or (0 <= cost_ab <= cost_ba):
                    u, v = a, b
                else:
                    u, v = b, a
                if used + count[u] + count[v] > refs.shape[0]:
                    start, count, refs, used = _build_refs(F, alive, n, spare)
                new_start = used
                for i in range(start[v], start[v] + count[v]):
                    g = refs[i]
                    if alive[g]:
                        refs[used] = g
                        used += 1
                for i in range(start[u], start[u] + count[u]):
                    g = refs[i]
                    if not alive[g]:
                        continue
                    if F[g, 0] == v or F[g, 1] == v or F[g, 2] == v:
                        alive[g] = False
                        continue
                    for k in range(3):
                        if F[g, k] == u:
                            F[g, k] = v
                    refs[used] = g
                    used += 1
                start[v] = new_start
                count[v] = used - new_start
                count[u] = 0
                for k in range(10):
                    Q[v, k] += Q[u, k]
                W[v] += W[u]
                if kind[u] == _ON_CHAIN:
                    other = cn[u, 0] if cn[u, 1] == v else cn[u, 1]
                    if kind[other] == _ON_CHAIN:
                        for k in range(2):
                            if cn[other, k] == u:
                                cn[other, k] = v
                    if kind[v] == _ON_CHAIN:
                        for k in range(2):
                            if cn[v, k] == u:
                                cn[v, k] = other
                kind[u] = -1
                done += 1
                break
    return done
