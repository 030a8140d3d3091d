"""Quad edges moved onto the creases of the triangle mesh the layout was made from.

QuadriFlow's sharp-feature mode turns its field along the creases but leaves its vertices beside them:
the quad edges run near a crease, a tenth of a quad off it, and near a crease's corners a quad folds
over it. Segment puts patch borders on sharp quad edges and the fit cannot bend a bicubic patch round a
crease inside it, so each such quad costs the fit its tolerance there.

`snap_to_creases` makes every crease it can a chain of quad edges (the chains: `cam.remesh.chains`):

1. The creases of the triangle mesh (dihedral over ``crease_angle_deg``, and gentle ones over
   ``gentle_angle_deg`` that run on for at least two quads) are cut into chains at their corners: where
   three or more meet, where one ends, and where one turns by more than ``corner_turn_deg`` within a
   quad's length (a pocket's rim at the pocket's corners). A closed crease with fewer than two corners is cut
   in two at opposite points.
2. Every chain end gets its nearest free quad vertex. Longest chains first, Dijkstra's search over
   directed quad edges finds the path between a chain's two end vertices that keeps nearest the chain
   (edge length weighted by the squared distance in quarter quads), that does not turn inside a quad
   (two sides of one quad in a row would put three of its corners on one line; allowed where the quad's
   corner is nearly straight already, as QuadriFlow leaves some beside creases) and that uses no vertex
   of another chain. A chain without such a path gets one that turns inside quads where it must (a crease
   that runs across a quad from corner to corner), each such quad then collapsed: its other two corners
   merge into one vertex on the chain (`cam.remesh.collapse`), where that keeps every vertex at three edges
   or more and joins no two edges or quads, never at two vertices in a row, and first only where the merge
   leaves no quad beside it with three corners on the chain. A chain with no path even so is cut in two at
   its middle, where the nearest free quad vertex becomes the halves' shared end, and the halves are tried
   after the chains (down to halves of a quad and a half); a piece that still has none is not snapped.
3. The path's vertices move onto the chain: each to its closest point where those run on in order a tenth
   of a quad apart, else spaced along the chain as they were along the path (a collapsed quad's merged
   vertex goes where the quad's middle is nearest the chain). The vertices within two
   rings of them follow by half their neighbours' moves, back on the triangle mesh in the crease-bounded
   region they were in (but those that lie on a crease already, snapped or not).
4. A quad that would fold (a corner turned against the quad's normal or the surface's) or collapse
   takes back the collapses of the chains that moved it (their looser paths first, then all), or, where
   none collapsed, undoes those chains, and the rest are snapped again; so does a collapse that leaves a
   defect in the mesh (`cam.remesh.check`). Nine rounds of undoing at most.

Chains that are not snapped are reported with where they run and why; a quad left across one is not
hidden (`cam.remesh.creases.measure_crease_conformity` counts them).
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from cam.mesh.closest import MeshIndex, closest_points, mesh_index
from cam.remesh.chains import (
    Chain,
    chain_from_points,
    closest_arc,
    crease_chains,
    distance_to_polyline,
    points_at,
)
from cam.remesh.check import QuadMeshReport, inspect_quad_mesh
from cam.remesh.collapse import collapse_diagonals

__all__ = ["Snapped", "snap_to_creases"]

# A path's vertices this far from their chain (in quad lengths) cost (1 + (d / _SPREAD)²) times the edge length.
_SPREAD = 0.25
# A path may run along two sides of one quad only where the quad's corner between them is this straight already,
# or, for a chain with no such path, where that quad is then collapsed (its other two corners merged on the
# chain); each such turn costs as much as this many quad lengths of path.
_STRAIGHT_DEG = 150.0
_COLLAPSE_COST = 1.0
# Quad vertices searched around a chain: within this many quad lengths of it.
_CORRIDOR = 1.0
# A chain shorter than this many quad lengths is too short for a quad edge of its own.
_MIN_CHAIN = 0.5
# A chain with no path along it is cut in halves no shorter than this many quad lengths.
_MIN_SPLIT = 1.5
# A quad vertex this near a crease (in quad lengths) follows it already: relaxing does not move it.
_ON_CREASE = 0.05
# Rings of vertices round the moved ones that are relaxed, and the rounds of relaxation.
_RELAX_RINGS = 2
_RELAX_ROUNDS = 4
# A quad with a corner this near straight (degrees) before snapping may turn inside out; it was a dart already.
_STRAIGHT_FOLDED_DEG = 1.0
# A quad collapses when its area falls under this share of what it was.
_MIN_AREA = 0.2
# Rounds of undoing what folds quads or breaks the mesh: a piece's looser collapses, its collapses, the piece.
_ROUNDS = 9
# Why a piece whose snapping folds or collapses a quad is not snapped, or whose quad collapses break the mesh.
_FOLDS = "snapping it folds a quad"
_BREAKS = "collapsing the quads it crosses breaks the mesh"
# Chains listed in the report at most (the counts cover all).
_REPORTED = 20


@dataclass(frozen=True, eq=False)
class Snapped:
    """A layout with its quad edges on the creases.

    Attributes
    ----------
    vertices : (n', 3) float64
        The quad mesh's vertices, mm: those of snapped chains on the creases, their neighbours relaxed,
        the rest as given; without the corners merged away by collapsed quads (n' = n - collapsed quads).
    quads : (m', 4) int64
        Its quads: the given ones less the collapsed ones, renumbered.
    report : dict
        JSON-ready: crease chains found and snapped, their lengths (mm), vertices moved, the largest move
        (mm), quads collapsed, and the chains not snapped (where they run, how long, why).
    """

    vertices: np.ndarray
    quads: np.ndarray
    report: dict = field(default_factory=dict)


class _Layout:
    """The quad mesh as the search and the checks see it."""

    def __init__(self, vertices: np.ndarray, quads: np.ndarray) -> None:
        self.vertices, self.quads = vertices, quads
        sides = np.stack([quads, np.roll(quads, -1, axis=1)], axis=2).reshape(-1, 2)
        keys, counts = np.unique(np.sort(sides, axis=1), axis=0, return_counts=True)
        keys, counts = keys[keys[:, 0] != keys[:, 1]], counts[keys[:, 0] != keys[:, 1]]
        self.side = float(np.median(np.linalg.norm(vertices[keys[:, 0]] - vertices[keys[:, 1]], axis=1)))
        self.neighbours: list[list[int]] = [[] for _ in range(len(vertices))]
        for a, b in keys.tolist():
            self.neighbours[a].append(b)
            self.neighbours[b].append(a)
        self.border = set(keys[counts == 1].ravel().tolist())  # an open layout's border stays where it is
        # (u, v, w) where u-v and v-w are two sides of one quad, and the quad's angle at v (degrees): a path that
        # runs u, v, w turns inside the quad, which puts three of its corners on one line
        p = vertices[quads]
        e0, e1 = np.roll(p, 1, axis=1) - p, np.roll(p, -1, axis=1) - p
        cos = np.einsum("kcd,kcd->kc", e0, e1) / np.maximum(np.linalg.norm(e0, axis=2) * np.linalg.norm(e1, axis=2),
                                                            1e-300)
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).tolist()
        self.turns: dict[tuple[int, int, int], float] = {}
        self.across: dict[tuple[int, int, int], tuple[int, int]] = {}  # (u, v, w) -> (the quad, its fourth corner)
        for k, (f, a) in enumerate(zip(quads.tolist(), angle, strict=True)):
            for i in range(4):
                u, v, w, x = f[i - 1], f[i], f[(i + 1) % 4], f[(i + 2) % 4]
                self.turns[(u, v, w)] = self.turns[(w, v, u)] = a[i]
                self.across[(u, v, w)] = self.across[(w, v, u)] = (k, x)
        self.tree = cKDTree(vertices)


def snap_to_creases(quad_vertices: np.ndarray, quads: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, *,
                    crease_angle_deg: float = 50.0, gentle_angle_deg: float = 35.0,
                    corner_turn_deg: float = 40.0, index: MeshIndex | None = None) -> Snapped:
    """Move a quad layout's vertices so that its edges run along the triangle mesh's creases.

    Parameters
    ----------
    quad_vertices : (n, 3) array_like of float
        The layout's vertices, mm, on the triangle mesh.
    quads : (m, 4) array_like of int
        Its quads.
    vertices : (p, 3) array_like of float
        The triangle mesh the layout was made from, mm.
    triangles : (q, 3) array_like of int
        Its triangles.
    crease_angle_deg : float
        A triangle edge whose faces' normals differ by more than this is a crease, degrees in (0, 180).
    gentle_angle_deg : float
        Edges over this angle are a crease too where they form a chain at least two quads long, degrees
        in (0, ``crease_angle_deg``].
    corner_turn_deg : float
        A crease that turns by more than this within a quad's length has a corner there, degrees in (0, 180).
    index : MeshIndex or None
        The triangle mesh's closest-point index (`cam.mesh.closest.mesh_index`) where the caller has one built.

    Returns
    -------
    Snapped

    Raises
    ------
    ValueError
        For arrays of the wrong shape, indices out of range or angles out of range, naming what was seen.
    """
    qv, qf, tv, tf = _check(quad_vertices, quads, vertices, triangles)
    if not (0 < gentle_angle_deg <= crease_angle_deg < 180 and 0 < corner_turn_deg < 180):
        raise ValueError(f"need 0 < gentle_angle_deg <= crease_angle_deg < 180 and 0 < corner_turn_deg < 180, got "
                         f"{gentle_angle_deg}, {crease_angle_deg} and {corner_turn_deg}")
    layout = _Layout(qv, qf)
    chains, region = crease_chains(tv, tf, crease_angle_deg=crease_angle_deg, gentle_angle_deg=gentle_angle_deg,
                                   corner_turn_deg=corner_turn_deg, quad_mm=layout.side)
    on_crease = _on_creases(layout, chains)
    index = mesh_index(tv, tf) if index is None else index
    home = region[closest_points(index, qv)[2]]
    failed: dict[tuple, str] = {}
    # pieces whose collapses folded or broke the mesh: -> 1 (strict paths only, `_path`), then 2 (no collapse)
    retreat: dict[tuple, int] = {}
    before = inspect_quad_mesh(qv, qf)
    for _ in range(_ROUNDS + 1):
        new, moved_by, pieces, collapses = _snap(layout, chains, failed, retreat, index, region, home, on_crease)
        folded = _folded(new, layout, index, collapsed={q for _, (q, _, _) in collapses})
        movers = {key for k in folded.tolist() for v in qf[k].tolist() for key in moved_by.get(v, ())}
        collapsing = {key for key, _ in collapses}
        if movers & collapsing:
            retreat.update({key: retreat.get(key, 0) + 1 for key in movers & collapsing})
            continue
        if movers:
            failed.update(dict.fromkeys(movers, _FOLDS))
            continue
        out_v, out_q, broken = _collapse(new, qf, collapses, before)
        if broken:
            retreat.update({key: retreat.get(key, 0) + 1 for key in broken})
            continue
        return Snapped(vertices=out_v, quads=out_q,
                       report={**_report(chains, pieces, failed, qv, new), "collapsed_quads": len(collapses)})
    whole = {(c,): chain for c, chain in enumerate(chains)}
    return Snapped(vertices=qv.copy(), quads=qf.copy(),
                   report={**_report(chains, whole, dict.fromkeys(whole, _FOLDS), qv, qv), "collapsed_quads": 0})


def _collapse(new: np.ndarray, quads: np.ndarray, collapses: list[tuple[tuple, tuple[int, int, int]]],
              before: QuadMeshReport) -> tuple[np.ndarray, np.ndarray, set[tuple]]:
    """The layout with the pieces' quads collapsed (`cam.remesh.collapse`), piece by piece in order, and the
    pieces whose collapses give the mesh a defect it did not have (``before``: the layout's inspection) or
    change its genus; those are left out."""
    keys = list(dict.fromkeys(key for key, _ in collapses))
    kept: list[tuple[int, int, int]] = []
    broken: set[tuple] = set()
    out_v, out_q = new, quads
    for key in keys:
        trial = kept + [c for k, c in collapses if k == key]
        v, q = collapse_diagonals(new, quads, trial)
        after = inspect_quad_mesh(v, q)
        if set(after.problems) - set(before.problems) or after.euler_characteristic != before.euler_characteristic:
            broken.add(key)
            continue
        kept, out_v, out_q = trial, v, q
    return out_v, out_q, broken


def _check(quad_vertices, quads, vertices, triangles) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    qv = np.asarray(quad_vertices, dtype=np.float64)
    qf = np.asarray(quads)
    tv = np.asarray(vertices, dtype=np.float64)
    tf = np.asarray(triangles)
    if qv.ndim != 2 or qv.shape[1] != 3 or qf.ndim != 2 or qf.shape[1] != 4 or not len(qf) or qf.dtype.kind not in "iu":
        raise ValueError(f"need quad vertices (n, 3) and integer quads (m >= 1, 4), got {qv.shape} and {qf.shape}")
    if tv.ndim != 2 or tv.shape[1] != 3 or tf.ndim != 2 or tf.shape[1] != 3 or not len(tf) or tf.dtype.kind not in "iu":
        raise ValueError(f"need vertices (p, 3) and integer triangles (q >= 1, 3), got {tv.shape} and {tf.shape}")
    qf, tf = qf.astype(np.int64), tf.astype(np.int64)
    if qf.min() < 0 or qf.max() >= len(qv) or tf.min() < 0 or tf.max() >= len(tv):
        raise ValueError(f"quads index vertices {qf.min()}..{qf.max()} of {len(qv)} and triangles {tf.min()}.."
                         f"{tf.max()} of {len(tv)}")
    if not (np.isfinite(qv).all() and np.isfinite(tv).all()):
        raise ValueError("vertices must be finite")
    return qv, qf, tv, tf


def _on_creases(layout: _Layout, chains: list[Chain]) -> set[int]:
    """The quad vertices within `_ON_CREASE` quad lengths of a chain: they follow a crease already."""
    if not chains:
        return set()
    step = 0.125 * layout.side
    points = np.vstack([points_at(c, np.linspace(0.0, c.length, max(2, int(np.ceil(c.length / step)) + 1)))
                        for c in chains])
    dist, _ = cKDTree(points).query(layout.vertices, distance_upper_bound=_ON_CREASE * layout.side + step)
    return set(np.flatnonzero(dist <= _ON_CREASE * layout.side).tolist())


# --- snapping -----------------------------------------------------------------------------------------------

def _snap(layout: _Layout, chains: list[Chain], failed: dict[tuple, str], retreat: dict[tuple, int], index: MeshIndex,
          region: np.ndarray, home: np.ndarray, on_crease: set[int]
          ) -> tuple[np.ndarray, dict[int, set[tuple]], dict[tuple, Chain], list[tuple[tuple, tuple[int, int, int]]]]:
    """Snap the chains, longest first, but the pieces in ``failed`` (key -> why; keys: (chain,), and a split
    piece's its parent's with 0 or 1 added), and add why others fail. A chain with no path along it is given
    one that turns inside quads it collapses (strict paths only for a piece, or a half of a piece, whose
    ``retreat`` is 1, none where it is 2); failing that, it is cut in two at its middle, where a quad vertex
    of its own goes (down to `_MIN_SPLIT` quads), and its halves are tried after the chains; relaxing leaves
    the vertices `on_crease`. Returns the new vertices (a collapsed quad's dropped corner where its kept one
    went), the pieces that moved each vertex, every piece tried, and the collapses (piece, (quad, kept
    corner, dropped corner))."""
    new = layout.vertices.copy()
    corners = {e: chains[c].points[k] for c in range(len(chains)) if (c,) not in failed
               for e, k in zip(chains[c].ends, (0, -1), strict=True)}
    ends = _end_vertices(layout, corners, taken=set())
    owner: dict[int, tuple] = {}  # vertex -> the piece whose path runs through it (ends excluded)
    moved_by: dict[int, set[tuple]] = {}
    queue = [((c,), chain) for c, chain in enumerate(chains)]
    pieces: dict[tuple, Chain] = {}
    collapses: list[tuple[tuple, tuple[int, int, int]]] = []
    for key, piece in queue:  # grows while it is walked: the halves of cut pieces
        pieces[key] = piece
        if key in failed:
            continue
        va, vb = ends.get(piece.ends[0]), ends.get(piece.ends[1])
        if piece.length < _MIN_CHAIN * layout.side:
            failed[key] = "shorter than half a quad"
            continue
        if va is None or vb is None or va == vb:
            failed[key] = "no quad vertex of its own near an end"
            continue
        blocked = (set(owner) | set(ends.values())) - {va, vb}
        found = _path(layout, piece, va, vb, blocked=blocked)
        level = max(retreat.get(key[:k], 0) for k in range(1, len(key) + 1))
        if found is None and level < 2:
            taken = {q for _, (q, _, _) in collapses}
            found = _path(layout, piece, va, vb, blocked=blocked, collapsed=taken)
            if found is None and level == 0:
                found = _path(layout, piece, va, vb, blocked=blocked, collapsed=taken, strict=False)
        if found is None:
            halves = _halves(layout, key, piece, ends, owner)
            if halves:
                queue += halves
            else:
                failed[key] = "no quad-edge path runs along it"
            continue
        path, merged = found
        for v in path + [x for _, _, x in merged]:
            moved_by.setdefault(v, set()).add(key)
        owner.update({v: key for v in path[1:-1] + [x for _, _, x in merged]})
        # a collapsed quad's merged corner goes where the quad's middle is nearest the chain
        where = layout.vertices[path]
        at = {v: i for i, v in enumerate(path)}
        for _, v, x in merged:
            where[at[v]] = 0.5 * (layout.vertices[v] + layout.vertices[x])
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(where, axis=0), axis=1))])
        new[path] = points_at(piece, _placement(where, piece, along, layout.side))
        for q, v, x in merged:
            new[x] = new[v]
            collapses.append((key, (q, v, x)))
    _relax(new, layout, moved_by, set(owner) | set(ends.values()) | on_crease, index, region, home)
    return new, moved_by, pieces, collapses


def _halves(layout: _Layout, key: tuple, piece: Chain, ends: dict, owner: dict[int, tuple]
            ) -> list[tuple[tuple, Chain]]:
    """The two halves of a piece cut at its middle, where a free quad vertex near it becomes their shared end
    (added to ``ends``); none when the piece is shorter than 2 `_MIN_SPLIT` quads or no vertex is free there."""
    if piece.length < 2 * _MIN_SPLIT * layout.side:
        return []
    middle = points_at(piece, np.array([0.5 * piece.length]))
    got = _end_vertices(layout, {key: middle[0]}, taken=set(ends.values()) | set(owner))
    if key not in got:
        return []
    ends[key] = got[key]
    k = int(np.searchsorted(piece.arc, 0.5 * piece.length, side="right"))
    first, second = np.vstack([piece.points[:k], middle]), np.vstack([middle, piece.points[k:]])
    return [(key + (0,), chain_from_points(first, (piece.ends[0], key))), (key + (1,), chain_from_points(second, (key, piece.ends[1])))]


def _end_vertices(layout: _Layout, points: dict, *, taken: set[int]) -> dict:
    """A quad vertex of its own, within a quad of it, for each end point (key -> (3,) mm), nearest pairs first and
    none of ``taken``: key -> quad vertex; an end with none left out."""
    if not points:
        return {}
    keys = list(points)
    k = min(8, len(layout.vertices))
    dist, idx = layout.tree.query(np.array([points[e] for e in keys]), k=k)
    dist, idx = dist.reshape(len(keys), k), idx.reshape(len(keys), k)
    pairs = sorted((d, i, int(idx[i, j])) for i in range(len(keys)) for j, d in enumerate(dist[i].tolist())
                   if d <= layout.side)
    ends: dict = {}
    used = set(taken)
    for _, i, v in pairs:
        if keys[i] not in ends and v not in used:
            ends[keys[i]] = v
            used.add(v)
    return ends


def _path(layout: _Layout, chain: Chain, va: int, vb: int, *, blocked: set[int], collapsed: set[int] | None = None,
          strict: bool = True) -> tuple[list[int], list[tuple[int, int, int]]] | None:
    """The cheapest quad-edge path va -> vb along the chain (see the module docstring) and the quads it collapses,
    or None.

    With ``collapsed`` None the path turns inside a quad only where the quad's corner is `_STRAIGHT_DEG` or
    straighter; otherwise it may turn inside any other quad whose fourth corner can merge with the turning
    vertex (`_collapsible`), none of those in ``collapsed`` (quads collapsed by other paths), for
    `_COLLAPSE_COST` quad lengths each and never at two vertices in a row. ``strict``: nor where the merge would
    make the path turn inside a quad beside the collapsed one (the vertices before and after the turning one
    and the fourth corner are corners of one quad: three of its corners end up on the chain, which folds it
    where the chain runs straight). Returns the path's vertices and (quad, turning vertex, fourth corner) of
    each quad it collapses.
    """
    side = layout.side
    samples = points_at(chain, np.linspace(0.0, chain.length, max(2, int(np.ceil(4 * chain.length / side)) + 1)))
    near = sorted(set(itertools.chain.from_iterable(layout.tree.query_ball_point(samples, _CORRIDOR * side))))
    near = [v for v in near if v not in blocked] + [va, vb]
    dist = dict(zip(near, distance_to_polyline(layout.vertices[near], chain.points).tolist(), strict=True))
    weight = {v: 1.0 + (d / (_SPREAD * side)) ** 2 for v, d in dist.items()}
    V = layout.vertices
    forbidden = blocked | {va, vb}  # fourth corners that may not merge away
    # a state: (previous vertex, vertex, whether the path turned inside a quad it collapses at the previous one)
    start = (-1, va, False)
    best = {start: 0.0}
    parent: dict[tuple[int, int, bool], tuple[int, int, bool]] = {}
    heap = [(0.0, start)]
    while heap:
        cost, state = heapq.heappop(heap)
        if cost > best.get(state, np.inf):
            continue
        u_prev, u, turned = state
        if u == vb:
            return _walk_back(layout, state, parent)
        before = parent[state][0] if state in parent else -1  # the vertex before u_prev
        # after a collapse at u_prev its dropped corner sits on u_prev: the path may not go on along its quads
        dropped = layout.across[(before, u_prev, u)][1] if turned else -1
        for w in layout.neighbours[u]:
            if w not in weight or w == u_prev or (strict and (dropped, u, w) in layout.turns):
                continue
            step = float(np.linalg.norm(V[w] - V[u])) * 0.5 * (weight[u] + weight[w])
            turn = layout.turns.get((u_prev, u, w), 180.0) < _STRAIGHT_DEG
            if turn and (collapsed is None or turned
                         or not _collapsible(layout, (u_prev, u, w), forbidden, collapsed)
                         or (strict and (before, u_prev, layout.across[(u_prev, u, w)][1]) in layout.turns)):
                continue
            nxt = (u, w, turn)
            total = cost + step + (_COLLAPSE_COST * side if turn else 0.0)
            if total < best.get(nxt, np.inf):
                best[nxt] = total
                parent[nxt] = state
                heapq.heappush(heap, (total, nxt))
    return None


def _walk_back(layout: _Layout, state: tuple[int, int, bool], parent: dict
               ) -> tuple[list[int], list[tuple[int, int, int]]] | None:
    """The path that ends in ``state`` and its collapses; None when it collapses a quad and passes a vertex
    twice, when a quad it collapses would drop one of its own vertices, when two of its collapses share a
    corner to drop, or when a vertex would keep fewer than three edges (each collapse takes one from the
    vertices before and after the turn)."""
    states = [state]
    while state in parent:
        state = parent[state]
        states.append(state)
    states.reverse()
    path = [s[1] for s in states]
    turns = [k - 1 for k, s in enumerate(states) if s[2]]  # a state (a, b, True) turned at a: path[k - 1]
    if turns and len(set(path)) < len(path):
        return None
    merged = []
    losses: dict[int, int] = {}
    for i in turns:
        q, x = layout.across[(path[i - 1], path[i], path[i + 1])]
        merged.append((q, path[i], x))
        for u in (path[i - 1], path[i + 1]):
            losses[u] = losses.get(u, 0) + 1
    dropped = [x for _, _, x in merged]
    if (len(set(dropped)) < len(dropped) or set(dropped) & set(path)
            or any(len(layout.neighbours[u]) - n < 3 for u, n in losses.items())):
        return None
    return path, merged


def _collapsible(layout: _Layout, turn: tuple[int, int, int], blocked: set[int], collapsed: set[int]) -> bool:
    """Whether the quad in which a path turns u, v, w can collapse, v and its fourth corner x merging: x is free
    (not ``blocked``), neither v nor x is on the layout's border, the quad is not in ``collapsed``, v and x have
    no neighbours but u and w in common (else the merge joins two edges or quads), and u and w keep three edges."""
    u, v, w = turn
    q, x = layout.across[turn]
    if x in blocked or q in collapsed or v in layout.border or x in layout.border:
        return False
    if len(layout.neighbours[u]) < 4 or len(layout.neighbours[w]) < 4:
        return False
    return set(layout.neighbours[v]) & set(layout.neighbours[x]) == {u, w} and x not in layout.neighbours[v]


def _placement(points: np.ndarray, chain: Chain, along: np.ndarray, side: float) -> np.ndarray:
    """Arc lengths (mm) on the chain for a path's vertices (k, 3): each vertex's closest point where those run on
    in order, at least a tenth of a quad apart; otherwise spaced as the vertices are along the path (``along``)."""
    s = closest_arc(points, chain)
    s[0], s[-1] = 0.0, chain.length
    if np.all(np.diff(s) > 0.1 * side):
        return s
    return along / along[-1] * chain.length


def _relax(new: np.ndarray, layout: _Layout, moved_by: dict[int, set[tuple]], fixed: set[int], index: MeshIndex,
           region: np.ndarray, home: np.ndarray) -> None:
    """Carry the snapped vertices' moves into the `_RELAX_RINGS` rings round them, in place: each free vertex
    there moves by half the mean move of its neighbours (from `_RELAX_ROUNDS` rounds of that), back onto the
    triangle mesh in its own crease-bounded region, and takes the chains that moved its ring as its movers.
    Vertices nothing moved near stay exactly where they are."""
    ring = {v: set(cs) for v, cs in moved_by.items()}
    frontier = set(moved_by)
    for _ in range(_RELAX_RINGS):
        grown = set()
        for v in frontier:
            for w in layout.neighbours[v]:
                if w in fixed or w in layout.border or w in moved_by:
                    continue
                if w not in ring:
                    grown.add(w)
                ring.setdefault(w, set()).update(ring[v])
        frontier = grown
    free = np.array(sorted(v for v in ring if v not in moved_by), dtype=np.int64)
    if not len(free):
        return
    for v in free.tolist():
        moved_by[v] = ring[v]
    shift = new - layout.vertices
    nbrs = [layout.neighbours[v] for v in free.tolist()]
    for _ in range(_RELAX_ROUNDS):
        shift[free] = 0.5 * np.array([shift[n].mean(axis=0) for n in nbrs])
    on, _, tri, _ = closest_points(index, layout.vertices[free] + shift[free])
    keep = region[tri] == home[free]
    new[free[keep]] = on[keep]


def _folded(new: np.ndarray, layout: _Layout, index: MeshIndex, *, collapsed: set[int]) -> np.ndarray:
    """Quads with a moved corner that snapping folds or collapses: int64 (k,) quad ids.

    A quad folds when a corner turns inside out (against the quad's normal) or the quad turns against the
    surface's normal, and it did not before (QuadriFlow leaves a few quads folded over crease corners, and a few
    darts with a corner within `_STRAIGHT_FOLDED_DEG` of straight that any move can turn; those are not
    snapping's doing); it collapses when its area falls under `_MIN_AREA` of what it was. The quads in
    ``collapsed`` are removed on purpose and not counted.
    """
    moved = np.flatnonzero(np.any(new != layout.vertices, axis=1))
    if not len(moved):
        return np.zeros(0, dtype=np.int64)
    touched = np.flatnonzero(np.isin(layout.quads, moved).any(axis=1))
    touched = touched[~np.isin(touched, list(collapsed))]
    fold_new, area_new = _quad_shape(new[layout.quads[touched]], index)
    fold_old, area_old = _quad_shape(layout.vertices[layout.quads[touched]], index, straight_deg=_STRAIGHT_FOLDED_DEG)
    return touched[(fold_new & ~fold_old) | ~(area_new >= _MIN_AREA * area_old)]


def _quad_shape(p: np.ndarray, index: MeshIndex, *, straight_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Whether each quad (corners (k, 4, 3), mm) folds (bool (k,)), and its area (mm², float (k,)); a corner within
    ``straight_deg`` of straight counts as folded."""
    normal = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    length = np.linalg.norm(normal, axis=1)
    after, before = np.roll(p, -1, axis=1) - p, np.roll(p, 1, axis=1) - p
    corner = np.cross(after, before)  # (k, 4, 3), 2 x corner triangle
    # a straight corner (zero corner triangle) is not inside out; a reflex one is
    inside_out = (np.einsum("kcd,kd->kc", corner, normal)
                  < -1e-6 * np.linalg.norm(corner, axis=2) * length[:, None]).any(axis=1)
    if straight_deg > 0:
        sine = np.einsum("kcd,kd->kc", corner, normal) / np.maximum(
            np.linalg.norm(after, axis=2) * np.linalg.norm(before, axis=2) * length[:, None], 1e-300)
        obtuse = np.einsum("kcd,kcd->kc", after, before) < 0
        inside_out |= (obtuse & (sine < np.sin(np.radians(straight_deg)))).any(axis=1)
    _, _, tri, _ = closest_points(index, p.mean(axis=1))
    t = index.vertices[index.faces[tri]]
    against = np.einsum("kd,kd->k", normal, np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])) <= 0
    return inside_out | against | ~(length > 0), 0.5 * length


def _report(chains: list[Chain], pieces: dict[tuple, Chain], failed: dict[tuple, str], old: np.ndarray,
            new: np.ndarray) -> dict:
    move = np.linalg.norm(new - old, axis=1)
    cut = {key[:-1] for key in pieces if len(key) > 1}
    snapped = [key for key in pieces if key not in failed and key not in cut]
    missed = sorted((key for key in failed if key in pieces), key=lambda key: -pieces[key].length)
    done = {key[0] for key in snapped}
    whole = [c for c in range(len(chains)) if not any(key[0] == c for key in missed)]
    return {
        "crease_chains": len(chains),
        "snapped_chains": len(whole),
        "partly_snapped_chains": len(done - set(whole)),
        "crease_chain_length_mm": float(sum(c.length for c in chains)),
        "snapped_length_mm": float(sum(pieces[key].length for key in snapped)),
        "moved_vertices": int((move > 0).sum()),
        "largest_move_mm": float(move.max(initial=0.0)),
        "not_snapped": [{"from_mm": pieces[key].points[0].round(3).tolist(),
                         "to_mm": pieces[key].points[-1].round(3).tolist(),
                         "length_mm": round(pieces[key].length, 3), "why": failed[key]} for key in missed[:_REPORTED]],
    }
