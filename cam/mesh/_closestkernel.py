"""Compiled closest-point search of `closest.closest_points`: one query at a time down a bounding-volume tree.

The pieces (triangles, or the parts a large one is cut into) sit in the leaves of a tree of axis-aligned
boxes, split at the median centroid along the longest side. A query descends nearer child first and skips
every box farther than the best distance found so far (plus TIE_MM, so that equally near triangles are all
seen), so the answer is exact. Equally near triangles (within TIE_MM) go to the one with the nearer
centroid, then the lower triangle index (then piece index): the answer does not depend on the order the
tree visits them.

The arithmetic is `closest.closest_on_triangles` written operation for operation as its numpy code runs
(three-term dot products summed as numpy's einsum sums them, norms as np.linalg.norm sums them, no fused
multiply-add), so a triangle's closest point, barycentrics and distance are bit for bit those of the
vectorised function.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from cam.mesh._compiled import KERNEL_LOCK, dot3, norm3

__all__ = ["closest_queries", "make_tree"]

_BLOCK = 1024  # queries per parallel task
_LEAF = 4  # pieces per leaf at most
_STACK = 128  # deeper than any tree of median splits over 2^63 pieces


@njit(cache=True, inline="always")
def _ratio(num, den):
    return num / den if den != 0 else 0.0


@njit(cache=True)
def _on_edges(px, py, pz, t, out):
    """The degenerate-triangle case: closest point of the three edges; out = (x, y, z, b0, b1, b2)."""
    best = np.inf
    for k in range(3):
        e = (k + 1) % 3
        sx, sy, sz = t[k, 0], t[k, 1], t[k, 2]
        ex, ey, ez = t[e, 0] - sx, t[e, 1] - sy, t[e, 2] - sz
        s = _ratio(dot3(px - sx, py - sy, pz - sz, ex, ey, ez), dot3(ex, ey, ez, ex, ey, ez))
        s = min(max(s, 0.0), 1.0)
        qx, qy, qz = sx + s * ex, sy + s * ey, sz + s * ez
        d = norm3(qx - px, qy - py, qz - pz)
        if d < best:
            best = d
            out[0], out[1], out[2] = qx, qy, qz
            out[3], out[4], out[5] = 0.0, 0.0, 0.0
            out[3 + k], out[3 + e] = 1.0 - s, s


@njit(cache=True)
def _on_triangle(px, py, pz, t, out):
    """Closest point of triangle t (3, 3) to p; out = (x, y, z, b0, b1, b2)."""
    ax, ay, az = t[0, 0], t[0, 1], t[0, 2]
    abx, aby, abz = t[1, 0] - ax, t[1, 1] - ay, t[1, 2] - az
    acx, acy, acz = t[2, 0] - ax, t[2, 1] - ay, t[2, 2] - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = dot3(abx, aby, abz, apx, apy, apz)
    d2 = dot3(acx, acy, acz, apx, apy, apz)
    bpx, bpy, bpz = px - t[1, 0], py - t[1, 1], pz - t[1, 2]
    d3 = dot3(abx, aby, abz, bpx, bpy, bpz)
    d4 = dot3(acx, acy, acz, bpx, bpy, bpz)
    cpx, cpy, cpz = px - t[2, 0], py - t[2, 1], pz - t[2, 2]
    d5 = dot3(abx, aby, abz, cpx, cpy, cpz)
    d6 = dot3(acx, acy, acz, cpx, cpy, cpz)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    if d1 <= 0 and d2 <= 0:
        bv, bw = 0.0, 0.0
    elif d3 >= 0 and d4 <= d3:
        bv, bw = 1.0, 0.0
    elif vc <= 0 and d1 >= 0 and d3 <= 0:
        bv, bw = _ratio(d1, d1 - d3), 0.0
    elif d6 >= 0 and d5 <= d6:
        bv, bw = 0.0, 1.0
    elif vb <= 0 and d2 >= 0 and d6 <= 0:
        bv, bw = 0.0, _ratio(d2, d2 - d6)
    elif va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        t_bc = _ratio(d4 - d3, (d4 - d3) + (d5 - d6))
        bv, bw = 1 - t_bc, t_bc
    else:
        total = va + vb + vc
        bv, bw = _ratio(vb, total), _ratio(vc, total)
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    if norm3(nx, ny, nz) == 0:
        _on_edges(px, py, pz, t, out)
        return
    out[0] = (ax + bv * abx) + bw * acx
    out[1] = (ay + bv * aby) + bw * acy
    out[2] = (az + bv * abz) + bw * acz
    out[3], out[4], out[5] = 1.0 - bv - bw, bv, bw


@njit(cache=True, inline="always")
def _box_distance2(px, py, pz, lo, hi):
    gx = max(lo[0] - px, px - hi[0], 0.0)
    gy = max(lo[1] - py, py - hi[1], 0.0)
    gz = max(lo[2] - pz, pz - hi[2], 0.0)
    return (gx * gx + gy * gy) + gz * gz


@njit(cache=True)
def _test(piece, px, py, pz, corners, piece_bary, piece_face, face_centroids, tie, out, held, state):
    """Piece against the best so far; held = (x, y, z, distance, face, b0, b1, b2), state = (best distance, the
    held one's centroid distance, the held piece)."""
    _on_triangle(px, py, pz, corners[piece], out)
    d = norm3(out[0] - px, out[1] - py, out[2] - pz)
    face = piece_face[piece]
    centre = norm3(face_centroids[face, 0] - px, face_centroids[face, 1] - py, face_centroids[face, 2] - pz)
    if d < held[3] - tie or (d <= held[3] + tie and (centre < state[1] or (centre == state[1] and (
            face < held[4] or (face == held[4] and piece < state[2]))))):
        m = piece_bary[piece]
        held[0], held[1], held[2], held[3], held[4] = out[0], out[1], out[2], d, face
        for k in range(3):
            held[5 + k] = (out[3] * m[0, k] + out[4] * m[1, k]) + out[5] * m[2, k]
        state[1], state[2] = centre, piece
    state[0] = min(state[0], d)


@njit(cache=True)
def _query(px, py, pz, corners, piece_bary, piece_face, face_centroids, node_lo, node_hi, node_child, node_first,
           node_count, order, tie, out, held, stack):
    """The closest point of the mesh to p into held."""
    state = np.array([np.inf, np.inf, np.inf])
    held[3], held[4] = np.inf, np.inf
    stack[0], top = 0, 1
    while top:
        top -= 1
        node = stack[top]
        reach = state[0] + tie
        if _box_distance2(px, py, pz, node_lo[node], node_hi[node]) > reach * reach:
            continue
        if node_count[node]:
            for j in range(node_first[node], node_first[node] + node_count[node]):
                _test(order[j], px, py, pz, corners, piece_bary, piece_face, face_centroids, tie, out, held, state)
            continue
        a, b = node_child[node], node_child[node] + 1
        if _box_distance2(px, py, pz, node_lo[a], node_hi[a]) > _box_distance2(px, py, pz, node_lo[b], node_hi[b]):
            a, b = b, a
        stack[top], stack[top + 1] = b, a  # the nearer child on top
        top += 2


@njit(cache=True, parallel=True)
def _closest_queries(points, corners, piece_bary, piece_face, face_centroids, node_lo, node_hi, node_child,
                     node_first, node_count, order, tie, closest, distance, face, bary):
    n = points.shape[0]
    for b in prange((n + _BLOCK - 1) // _BLOCK):
        out, held, stack = np.empty(6), np.empty(8), np.empty(_STACK, dtype=np.int64)
        for i in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            _query(points[i, 0], points[i, 1], points[i, 2], corners, piece_bary, piece_face, face_centroids,
                   node_lo, node_hi, node_child, node_first, node_count, order, tie, out, held, stack)
            closest[i, 0], closest[i, 1], closest[i, 2] = held[0], held[1], held[2]
            distance[i], face[i] = held[3], int(held[4])
            bary[i, 0], bary[i, 1], bary[i, 2] = held[5], held[6], held[7]


def closest_queries(*args) -> None:
    """`_closest_queries` under the kernels' lock (arguments as there)."""
    with KERNEL_LOCK:
        _closest_queries(*args)


@njit(cache=True)
def _build(lo, hi, centroids, order, node_lo, node_hi, node_child, node_first, node_count):
    """Fill the node arrays top-down; returns the number of nodes."""
    nodes = 1
    todo = np.empty((_STACK, 3), dtype=np.int64)
    todo[0, 0], todo[0, 1], todo[0, 2] = 0, 0, order.shape[0]
    top = 1
    while top:
        top -= 1
        node, start, end = todo[top, 0], todo[top, 1], todo[top, 2]
        for a in range(3):
            node_lo[node, a], node_hi[node, a] = np.inf, -np.inf
        c_lo, c_hi = np.full(3, np.inf), np.full(3, -np.inf)
        for j in range(start, end):
            piece = order[j]
            for a in range(3):
                node_lo[node, a] = min(node_lo[node, a], lo[piece, a])
                node_hi[node, a] = max(node_hi[node, a], hi[piece, a])
                c_lo[a] = min(c_lo[a], centroids[piece, a])
                c_hi[a] = max(c_hi[a], centroids[piece, a])
        if end - start <= _LEAF:
            node_first[node], node_count[node] = start, end - start
            continue
        axis = int(np.argmax(c_hi - c_lo))
        part = order[start:end]
        order[start:end] = part[np.argsort(centroids[part, axis], kind="mergesort")]
        middle = (start + end) // 2
        node_child[node], node_count[node] = nodes, 0
        todo[top, 0], todo[top, 1], todo[top, 2] = nodes, start, middle
        todo[top + 1, 0], todo[top + 1, 1], todo[top + 1, 2] = nodes + 1, middle, end
        top += 2
        nodes += 2
    return nodes


def make_tree(corners: np.ndarray) -> tuple[np.ndarray, ...]:
    """The bounding-volume tree of the pieces.

    Parameters
    ----------
    corners : (p, 3, 3) float64
        The pieces' corners, mm.

    Returns
    -------
    node_lo, node_hi : (k, 3) float64
        Each node's box, mm (node 0 is the root).
    node_child : (k,) int64
        An inner node's first child (the second is the next one).
    node_first, node_count : (k,) int64
        A leaf's pieces: order[node_first:node_first + node_count] (count 0: an inner node).
    order : (p,) int64
        Piece indices, leaf by leaf.
    """
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    centroids = corners.mean(axis=1)
    p = len(corners)
    size = 2 * p + 1
    node_lo, node_hi = np.empty((size, 3)), np.empty((size, 3))
    node_child, node_first, node_count = (np.zeros(size, dtype=np.int64) for _ in range(3))
    order = np.arange(p, dtype=np.int64)
    k = _build(lo, hi, centroids, order, node_lo, node_hi, node_child, node_first, node_count)
    return node_lo[:k], node_hi[:k], node_child[:k], node_first[:k], node_count[:k], order
