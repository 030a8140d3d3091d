"""Crease chains of a triangle mesh: its creases cut at their corners into polylines (`cam.remesh.snap`'s input).

A crease is an edge whose faces' normals differ by more than a threshold; gentle ones, over a lower threshold,
count where they run on for at least two quads. The crease graph is walked into chains between its corners
(three or more creases, an end) and each is cut again where it turns by more than a threshold within a quad's
length (a pocket's rim at the pocket's corners). A closed crease with fewer than two corners is cut in two at
opposite points, so that every chain has two ends.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from cam.remesh.creases import crease_graph

__all__ = ["Chain", "chain_from_points", "chains_from_edges", "closest_arc", "crease_chains", "distance_to_polyline",
           "points_at"]

# Gentle creases count from this many quad lengths on.
_MIN_GENTLE = 2.0


@dataclass(frozen=True, eq=False)
class Chain:
    """A crease polyline between two ends."""

    points: np.ndarray  # (k, 3) float64, the crease polyline end to end, mm
    arc: np.ndarray  # (k,) float64, arc length from the first point, mm
    ends: tuple  # keys of its two ends: a triangle-mesh vertex id, or the key of the piece a split point cut
    ids: np.ndarray | None = None  # (k,) int64: the triangle-mesh vertex of each point, where the chain is made of them

    @property
    def length(self) -> float:
        return float(self.arc[-1])


def crease_chains(tv: np.ndarray, tf: np.ndarray, *, crease_angle_deg: float, gentle_angle_deg: float,
                  corner_turn_deg: float, quad_mm: float) -> tuple[list[Chain], np.ndarray]:
    """The creases of a triangle mesh cut into chains at their corners, longest first, and its crease-bounded regions.

    Parameters
    ----------
    tv : (p, 3) float64
        The triangle mesh's vertices, mm.
    tf : (q, 3) int64
        Its triangles.
    crease_angle_deg : float
        Edges whose faces' normals differ by more than this are creases.
    gentle_angle_deg : float
        Edges over this (and at most ``crease_angle_deg``) are creases where their chain is at least two quads long.
    corner_turn_deg : float
        A chain that turns by more than this within half a quad on either side of a point is cut there.
    quad_mm : float
        The quad length the chains are measured in, mm.

    Returns
    -------
    chains : list of Chain
        Each chain's ends are the triangle-mesh vertex ids where it starts and stops.
    region : (q,) int64
        Each triangle's region: triangles joined across edges that are not creases.
    """
    graph = crease_graph(tv, tf, gentle_angle_deg)
    sharp = set(map(tuple, graph.edges[graph.edge_angle_deg > crease_angle_deg].tolist()))
    chains = [chain for chain in chains_from_edges(tv, graph.edges, corner_turn_deg=corner_turn_deg, quad_mm=quad_mm)
              if chain.length >= _MIN_GENTLE * quad_mm or any((min(a, b), max(a, b)) in sharp
                                                              for a, b in itertools.pairwise(chain.ids.tolist()))]
    return chains, graph.face_region


def chains_from_edges(tv: np.ndarray, edges: np.ndarray, *, corner_turn_deg: float, quad_mm: float) -> list[Chain]:
    """Crease edges (int (k, 2) vertex pairs of the mesh whose vertices are ``tv``, mm) walked into chains
    between the vertices where other than two of them meet, each cut where it turns by more than
    ``corner_turn_deg`` within half of ``quad_mm`` on either side (a closed one in at least two); longest first."""
    chains = [_make_chain(piece, tv) for walk in _walks(np.asarray(edges, dtype=np.int64))
              for piece in _cut_at_turns(walk, tv, corner_turn_deg, quad_mm)]
    chains.sort(key=lambda c: -c.length)
    return chains


def _make_chain(ids: list[int], tv: np.ndarray) -> Chain:
    return chain_from_points(tv[ids], (ids[0], ids[-1]), ids=np.asarray(ids, dtype=np.int64))


def chain_from_points(points: np.ndarray, ends: tuple, *, ids: np.ndarray | None = None) -> Chain:
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return Chain(points=points, arc=arc, ends=ends, ids=ids)


def _walks(edges: np.ndarray) -> list[list[int]]:
    """The crease graph's edges as walks between vertices of degree other than two; closed loops start and end
    at one vertex."""
    adjacent: dict[int, list[int]] = {}
    for a, b in edges.tolist():
        adjacent.setdefault(a, []).append(b)
        adjacent.setdefault(b, []).append(a)
    used: set[tuple[int, int]] = set()
    walks = []

    def walk_from(a: int, b: int) -> list[int]:
        path = [a, b]
        used.add((min(a, b), max(a, b)))
        while len(adjacent[path[-1]]) == 2 and path[-1] != path[0]:
            nxt = next((n for n in adjacent[path[-1]] if (min(n, path[-1]), max(n, path[-1])) not in used), None)
            if nxt is None:
                break
            used.add((min(nxt, path[-1]), max(nxt, path[-1])))
            path.append(nxt)
        return path

    for v in sorted(adjacent):
        if len(adjacent[v]) != 2:
            for n in adjacent[v]:
                if (min(v, n), max(v, n)) not in used:
                    walks.append(walk_from(v, n))
    for v in sorted(adjacent):  # what is left are loops of degree-two vertices
        for n in adjacent[v]:
            if (min(v, n), max(v, n)) not in used:
                walks.append(walk_from(v, n))
    return walks


def _cut_at_turns(walk: list[int], tv: np.ndarray, turn_deg: float, side: float) -> list[list[int]]:
    """The walk cut where it turns by more than ``turn_deg`` over half a quad on either side (the sharpest point
    of each turn); a closed walk without a turn is cut in two halves."""
    closed = walk[0] == walk[-1] and len(walk) > 2
    chain = _make_chain(walk, tv)
    turn = _turning(chain, 0.5 * side, closed)
    window = 0.5 * side
    cuts = []
    for i in np.flatnonzero(turn > np.radians(turn_deg)).tolist():
        near = np.abs(chain.arc - chain.arc[i]) <= window
        if closed:
            near |= chain.length - np.abs(chain.arc - chain.arc[i]) <= window
        if turn[i] >= turn[near].max() and not any(abs(chain.arc[j] - chain.arc[i]) <= window for j in cuts):
            cuts.append(i)
    if closed:
        if len(cuts) < 2:  # a loop needs two ends: the point opposite its one corner, or two opposite points
            first = cuts[0] if cuts else 0
            cuts = [first, int(np.searchsorted(chain.arc, (chain.arc[first] + 0.5 * chain.length) % chain.length))]
        cuts = sorted({c % (len(walk) - 1) for c in cuts})
        ring = walk[:-1]
        pieces = []
        for a, b in zip(cuts, cuts[1:] + [cuts[0] + len(ring)], strict=True):
            pieces.append([ring[k % len(ring)] for k in range(a, b + 1)])
        return [p for p in pieces if len(p) >= 2]
    bounds = [0, *sorted(c for c in cuts if 0 < c < len(walk) - 1), len(walk) - 1]
    return [walk[a:b + 1] for a, b in itertools.pairwise(bounds)]


def _turning(chain: Chain, reach: float, closed: bool) -> np.ndarray:
    """Angle (rad) between the chain's directions over ``reach`` mm before and after each point; 0 at open ends."""
    s = chain.arc
    if closed:
        length = chain.length
        before = points_at(chain, (s - reach) % length)
        after = points_at(chain, (s + reach) % length)
    else:
        before = points_at(chain, np.maximum(s - reach, 0.0))
        after = points_at(chain, np.minimum(s + reach, chain.length))
    d0, d1 = chain.points - before, after - chain.points
    n0, n1 = np.linalg.norm(d0, axis=1), np.linalg.norm(d1, axis=1)
    ok = (n0 > 1e-12) & (n1 > 1e-12)
    cos = np.einsum("ij,ij->i", d0, d1) / np.where(ok, n0 * n1, 1.0)
    return np.where(ok, np.arccos(np.clip(cos, -1.0, 1.0)), 0.0)


def points_at(chain: Chain, s: np.ndarray) -> np.ndarray:
    """Points of the chain at arc lengths ``s`` (mm), (k, 3)."""
    return np.stack([np.interp(s, chain.arc, chain.points[:, k]) for k in range(3)], axis=1)


def closest_arc(points: np.ndarray, chain: Chain) -> np.ndarray:
    """Arc length (mm) of the closest chain point to each point (n, 3)."""
    k, along, _ = _closest_on_segments(points, chain.points)
    return chain.arc[k] + along


def distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance (mm) of each point (n, 3) to the polyline (k, 3)."""
    return _closest_on_segments(points, line)[2]


def _closest_on_segments(points: np.ndarray, line: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each point (n, 3), the polyline (k, 3) segment it is closest to (int (n,)), how far along that segment
    its closest point lies (mm, (n,)) and how far the point is from it (mm, (n,))."""
    a, b = line[:-1], line[1:]
    ab = b - a
    ab2 = np.maximum(np.einsum("kd,kd->k", ab, ab), 1e-300)
    t = np.clip(np.einsum("nkd,kd->nk", points[:, None, :] - a[None], ab) / ab2, 0.0, 1.0)
    d = np.linalg.norm(a[None] + t[..., None] * ab[None] - points[:, None, :], axis=2)
    k = np.argmin(d, axis=1)
    rows = np.arange(len(points))
    return k, t[rows, k] * np.sqrt(ab2[k]), d[rows, k]
