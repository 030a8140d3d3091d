"""How many quad edges each edge of a coarse quad layout is cut into, so that neighbouring grids meet.

A coarse quad becomes an n × m grid, so its opposite sides take the same count: the edges linked through opposite
sides of quads (a strip of quads, a "chord") form one class, whose count is its edges' mean length over the quad
size, rounded, at least one, and enough that none of its edges is cut into pieces over 1.5 quad sizes.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["quantize_edge_counts"]

# No edge of a class is cut into pieces longer than this many quad sizes (a strip of quads whose sides differ in
# length would otherwise leave long quad edges that cut across a curved face).
_LONGEST = 3.0


def quantize_edge_counts(edges: np.ndarray, lengths_mm: np.ndarray, quads: np.ndarray, *, edge_mm: float,
                         min_counts: np.ndarray | None = None) -> np.ndarray:
    """Quad edges per coarse edge.

    Parameters
    ----------
    edges : (e, 2) int64
        The coarse edges as sorted vertex pairs.
    lengths_mm : (e,) float64
        Each one's length, mm (along its crease for an edge on one).
    quads : (q, 4) int64
        The coarse quads; their sides are among ``edges``.
    edge_mm : float
        The quad edge length aimed for, mm (> 0).
    min_counts : (e,) int64 or None
        The fewest pieces each edge may be cut into (a curved crease's, so that its chords stay near it).

    Returns
    -------
    (e,) int64
        Counts, each at least 1, equal on opposite sides of every quad.
    """
    n = int(max(edges.max(), quads.max())) + 1
    key = edges[:, 0] * n + edges[:, 1]
    order = np.argsort(key)
    sides = np.sort(np.stack([quads, np.roll(quads, -1, axis=1)], axis=2), axis=2)
    row = order[np.searchsorted(key[order], sides[..., 0] * n + sides[..., 1])]
    a = np.concatenate([row[:, 0], row[:, 1]])
    b = np.concatenate([row[:, 2], row[:, 3]])
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(edges), len(edges)))
    cls = connected_components(graph, directed=False)[1]
    mean = np.bincount(cls, weights=lengths_mm) / np.bincount(cls)
    longest = np.zeros(len(mean))
    np.maximum.at(longest, cls, lengths_mm)
    count = np.maximum(np.rint(mean / edge_mm), np.ceil(longest / (_LONGEST * edge_mm)))
    if min_counts is not None:
        np.maximum.at(count, cls, min_counts)
    return np.maximum(1, count).astype(np.int64)[cls]
