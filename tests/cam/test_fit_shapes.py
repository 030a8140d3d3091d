"""Analytic test parts for the fit tests: a surface, its quad grid and a finer triangle mesh of it.

A shape is a map (s, t) -> xyz in mm. The quad grid is its image of a regular (s, t)
grid, patches are blocks of that grid (so neighbours share vertex ids), and the
triangle mesh is a finer tessellation whose vertices include the quad vertices, so
every quad vertex lies on the mesh exactly.
"""

from __future__ import annotations

import numpy as np


def poly(s, t):
    """A bicubic polynomial height field (degree 3 in each variable), slopes below 0.6."""
    z = 0.0005 * s**3 - 0.00025 * s * t**2 + 0.0025 * s * t + 0.005 * t**2 - 0.0000125 * s**2 * t**3
    return np.stack([s, t, z], axis=-1)


def cylinder(radius):
    return lambda s, t: np.stack([radius * np.sin(s / radius), t, radius * np.cos(s / radius)], axis=-1)


def paraboloid(a):
    return lambda s, t: np.stack([s, t, a * (s**2 + t**2)], axis=-1)


def bump(height, s0, t0, sigma):
    """A Gaussian bump of `height` mm and width `sigma` mm centred at (s0, t0) on the plane z = 0."""
    return lambda s, t: np.stack([s, t, height * np.exp(-((s - s0) ** 2 + (t - t0) ** 2) / (2 * sigma**2))], axis=-1)


def ridge(s0, slope):
    """Two planes meeting in a crease along s = s0 (a roof)."""
    return lambda s, t: np.stack([s, t, slope * (s0 - np.abs(s - s0))], axis=-1)


def triangle_mesh(fn, s, t):
    """Vertices float64 (n, 3) and triangles int64 (m, 3) of fn over the grid s x t."""
    S, T = np.meshgrid(s, t, indexing="ij")
    V = fn(S, T).reshape(-1, 3)
    idx = np.arange(S.size).reshape(S.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def quad_grid(fn, s, t):
    """Quad-mesh vertices float64 (n, 3) and the vertex-id grid int64 (len(s), len(t))."""
    S, T = np.meshgrid(s, t, indexing="ij")
    return fn(S, T).reshape(-1, 3), np.arange(S.size).reshape(S.shape)


def quads_of(ids):
    """The quads (int (m, 4), counter-clockwise seen from +z for a height field) of a vertex-id grid."""
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    return np.stack([a, b, c, d], axis=1)


def case(fn, extent, quads, refine=4):
    """(quad vertices, id grid, mesh vertices, mesh triangles) over [0, extent[0]] x [0, extent[1]]."""
    s = np.linspace(0, extent[0], quads[0] + 1)
    t = np.linspace(0, extent[1], quads[1] + 1)
    V, ids = quad_grid(fn, s, t)
    MV, MF = triangle_mesh(fn, np.linspace(0, extent[0], refine * quads[0] + 1),
                           np.linspace(0, extent[1], refine * quads[1] + 1))
    return V, ids, MV, MF


def test_mesh_contains_the_quad_vertices():
    V, ids, MV, MF = case(poly, (20, 10), (10, 5))
    d = np.min(np.linalg.norm(MV[None, :, :] - V[:, None, :], axis=2), axis=1)
    assert d.max() == 0.0
    assert MF.shape == (2 * 40 * 20, 3) and quads_of(ids).shape == (50, 4)
