"""Structured quad meshes of simple solids, with known structure, for tests and benchmarks.

Each returns ``(vertices float64 (n, 3) mm, faces int64 (m, 4))`` with faces
counter-clockwise seen from outside.
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["quad_box", "quad_capped_cylinder", "quad_grid", "quad_torus", "quads_from_triangles"]


def quad_grid(nu: int, nv: int, *, size: tuple[float, float] = (1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """An open planar ``nu`` × ``nv`` grid of quads in the z = 0 plane, normals +z."""
    if nu < 1 or nv < 1:
        raise ValueError(f"need nu, nv ≥ 1, got {nu}, {nv}")
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
    verts = np.stack([i * size[0] / nu, j * size[1] / nv, np.zeros_like(i, dtype=float)], axis=-1).reshape(-1, 3)
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    faces = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    return verts.astype(np.float64), faces.astype(np.int64)


def quad_box(n: tuple[int, int, int], *, size: tuple[float, float, float] = (1.0, 1.0, 1.0),
             origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A closed box of ``n[0]`` × ``n[1]`` × ``n[2]`` quads per side, from ``origin`` to ``origin + size``.

    Its 8 corners are the only extraordinary vertices (valence 3), its 12
    edges the only sharp ones.
    """
    if min(n) < 1:
        raise ValueError(f"need at least one quad per side, got {n}")
    index: dict[tuple[int, int, int], int] = {}
    faces: list[list[int]] = []

    def vid(p: tuple[int, int, int]) -> int:
        return index.setdefault(p, len(index))

    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        for side in (0, n[axis]):
            for a in range(n[u]):
                for b in range(n[v]):
                    corners = []
                    for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = [0, 0, 0]
                        p[axis], p[u], p[v] = side, a + du, b + dv
                        corners.append(vid(tuple(p)))
                    # (u, v, axis) is right-handed, so this order faces +axis; flip it on the low side.
                    faces.append(corners if side else corners[::-1])
    lattice = np.array(sorted(index, key=index.get), dtype=np.float64)
    verts = np.asarray(origin) + lattice / np.asarray(n, dtype=np.float64) * np.asarray(size)
    return verts, np.asarray(faces, dtype=np.int64)


def quad_capped_cylinder(k: int, rings: int, layers: int, *, radius: float = 1.0,
                         height: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder around +z with flat caps: ``4k`` quads around, ``layers`` along z.

    Each cap is a k × k grid in its middle plus ``rings`` rings of quads out to
    the rim, so it has four valence-3 vertices (the grid's corners); the rims
    are sharp (90°) and all their vertices regular.
    """
    if k < 1 or rings < 1 or layers < 1:
        raise ValueError(f"need k, rings, layers ≥ 1, got {k}, {rings}, {layers}")
    m = 4 * k
    theta = 2 * np.pi * (np.arange(m) / m) + np.pi / 4 + np.pi  # rim index 0 at the grid corner (-,-)
    verts: list[np.ndarray] = []
    faces: list[list[int]] = []
    count = 0

    def add(points: np.ndarray) -> np.ndarray:
        nonlocal count
        ids = np.arange(count, count + len(points))
        verts.append(points)
        count += len(points)
        return ids

    # The side: layers + 1 rings of m vertices.
    side = np.stack([add(np.stack([radius * np.cos(theta), radius * np.sin(theta), np.full(m, z)], axis=1))
                     for z in np.linspace(0, height, layers + 1)])
    for a in range(layers):
        for i in range(m):
            j = (i + 1) % m
            faces.append([side[a, i], side[a, j], side[a + 1, j], side[a + 1, i]])

    def square_ring(s: float, z: float) -> np.ndarray:
        """The 4k boundary points of the inner square of half-size s, starting at its (-,-) corner, CCW."""
        t = np.linspace(-s, s, k + 1)[:-1]
        pts = [np.stack([t, np.full(k, -s)], 1), np.stack([np.full(k, s), t], 1),
               np.stack([-t, np.full(k, s)], 1), np.stack([np.full(k, -s), -t], 1)]
        xy = np.vstack(pts)
        return np.column_stack([xy, np.full(len(xy), z)])

    half = 0.35 * radius
    for z, rim, up in ((0.0, side[0], False), (height, side[layers], True)):
        # Rings between the inner square (r = 0) and the rim (r = 1), blending square to circle.
        ring_ids = [rim]
        circle = np.column_stack([radius * np.cos(theta), radius * np.sin(theta), np.full(m, z)])
        square = square_ring(half, z)
        for r in range(rings - 1, 0, -1):
            w = r / rings
            ring_ids.append(add((1 - w) * circle + w * square))
        ring_ids.append(None)
        grid = np.empty((k + 1, k + 1), dtype=np.int64)
        t = np.linspace(-half, half, k + 1)
        for a in range(k + 1):
            for b in range(k + 1):
                grid[a, b] = add(np.array([[t[a], t[b], z]]))[0]
        # The grid's boundary in the same order as square_ring.
        border = [grid[a, 0] for a in range(k)] + [grid[k, b] for b in range(k)] + \
                 [grid[k - a, k] for a in range(k)] + [grid[0, k - b] for b in range(k)]
        ring_ids[-1] = np.asarray(border)
        cap_faces = []
        for outer, inner in itertools.pairwise(ring_ids):
            for i in range(m):
                j = (i + 1) % m
                cap_faces.append([outer[i], outer[j], inner[j], inner[i]])  # faces +z as built
        for a in range(k):
            for b in range(k):
                cap_faces.append([grid[a, b], grid[a + 1, b], grid[a + 1, b + 1], grid[a, b + 1]])
        for q in cap_faces:
            faces.append(q if up else q[::-1])
    return np.vstack(verts).astype(np.float64), np.asarray(faces, dtype=np.int64)


def quad_torus(nu: int, nv: int, *, major: float = 2.0, minor: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """A torus around +z as an ``nu`` × ``nv`` periodic grid: all vertices regular, no boundary."""
    if nu < 3 or nv < 3:
        raise ValueError(f"need nu, nv ≥ 3, got {nu}, {nv}")
    u = 2 * np.pi * np.arange(nu) / nu
    v = 2 * np.pi * np.arange(nv) / nv
    uu, vv = np.meshgrid(u, v, indexing="ij")
    verts = np.stack([(major + minor * np.cos(vv)) * np.cos(uu), (major + minor * np.cos(vv)) * np.sin(uu),
                      minor * np.sin(vv)], axis=-1).reshape(-1, 3)
    idx = np.arange(nu * nv).reshape(nu, nv)
    i0, j0 = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i1, j1 = (i0 + 1) % nu, (j0 + 1) % nv
    faces = np.stack([idx[i0, j0], idx[i1, j0], idx[i1, j1], idx[i0, j1]], axis=-1).reshape(-1, 4)
    return verts, faces.astype(np.int64)


def quads_from_triangles(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into three quads (its centroid, its corners and its edge midpoints).

    The result keeps the triangles' orientation and boundary; triangle
    centroids become valence-3 vertices and each original vertex keeps its
    degree, so any triangle mesh gives a quad mesh rich in extraordinary points.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    tris = np.asarray(triangles, dtype=np.int64)
    n, m = len(verts), len(tris)
    e = np.stack([tris, np.roll(tris, -1, axis=1)], axis=2).reshape(-1, 2)  # edge i of each triangle: i -> i+1
    keys = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])
    uniq, inv = np.unique(keys, return_inverse=True)
    mids = 0.5 * (verts[uniq // n] + verts[uniq % n])
    mid_id = (n + inv).reshape(m, 3)
    centre_id = n + len(uniq) + np.arange(m)
    out = []
    for i in range(3):
        # Quad at corner i: corner, midpoint of edge i, centroid, midpoint of edge i-1.
        out.append(np.stack([tris[:, i], mid_id[:, i], centre_id, mid_id[:, (i + 2) % 3]], axis=1))
    faces = np.stack(out, axis=1).reshape(-1, 4)
    return np.vstack([verts, mids, verts[tris].mean(axis=1)]), faces
