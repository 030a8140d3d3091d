"""Straight lines of a quad grid: from a vertex, keep going through regular vertices along the opposite edge.

At a regular interior vertex (4 edges, 4 faces) the edge opposite the one a
line arrives on is two steps around the vertex: for arriving half-edge ``h``
it is ``next(twin(next(h)))``. At any other vertex (extraordinary, on a
boundary) "straight on" is undefined and a line ends there.

Every trace ends: it stops where the caller's stop rule says, at a vertex
where straight-on is undefined, at the first vertex already on its own track
(a closed grid line, e.g. around a torus, comes back to where it started), and
after ``max_steps`` edges in any case.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cam.mesh.quads import QuadTopology

__all__ = ["Trace", "straight_continuation", "trace_line"]


@dataclass(frozen=True)
class Trace:
    """One traced grid line.

    Attributes
    ----------
    half_edges
        The half-edges walked, in order (the first leaves the start vertex).
    vertices
        Start vertex, then the end vertex of each half-edge.
    reason
        Why it ended: ``"stop"`` (the stop rule), ``"irregular"`` (extraordinary
        or boundary vertex), ``"self"`` (met its own track), ``"steps"`` (the cap).
    """

    half_edges: tuple[int, ...]
    vertices: tuple[int, ...]
    reason: str

    @property
    def end(self) -> int:
        return self.vertices[-1]


def straight_continuation(topo: QuadTopology) -> np.ndarray:
    """The half-edge that continues each half-edge straight on past its end vertex.

    Parameters
    ----------
    topo
        Connectivity of the quad mesh.

    Returns
    -------
    ndarray
        int64 (4m,) half-edge id per half-edge, -1 where the end vertex is not a regular interior vertex.
    """
    n_he = len(topo.twin)
    h = np.arange(n_he)
    nxt = h - h % 4 + (h + 1) % 4
    t = topo.twin[nxt]
    cont = np.where(t >= 0, np.maximum(t, 0) - np.maximum(t, 0) % 4 + (np.maximum(t, 0) + 1) % 4, -1)
    regular = topo.regular_interior()
    cont[~regular[topo.dest]] = -1
    return cont.astype(np.int64)


def trace_line(
    topo: QuadTopology,
    straight: np.ndarray,
    start_he: int,
    *,
    stop: Callable[[int], bool],
    max_steps: int | None = None,
) -> Trace:
    """Walk straight from ``origin(start_he)`` along ``start_he``.

    Parameters
    ----------
    topo
        The connectivity.
    straight
        int64 (4m,): its :func:`straight_continuation`.
    start_he
        First half-edge of the line.
    stop
        Called with each half-edge just walked; True ends the line at its end vertex.
    max_steps
        Cap on the edges walked (default: the number of vertices, which no
        line can exceed without meeting its own track).

    Returns
    -------
    Trace
        The half-edges walked, the vertices passed and why the line ended.
    """
    cap = topo.n_vertices if max_steps is None else max_steps
    origin = topo.faces.reshape(-1)
    dest = topo.dest
    start = int(origin[start_he])
    hes = [int(start_he)]
    verts = [start]
    seen = {start}
    h = int(start_he)
    while True:
        v = int(dest[h])
        verts.append(v)
        if v in seen:
            return Trace(tuple(hes), tuple(verts), "self")
        seen.add(v)
        if stop(h):
            return Trace(tuple(hes), tuple(verts), "stop")
        nxt = int(straight[h])
        if nxt < 0:
            return Trace(tuple(hes), tuple(verts), "irregular")
        if len(hes) >= cap:
            return Trace(tuple(hes), tuple(verts), "steps")
        hes.append(nxt)
        h = nxt
