"""Repair what is small and safe in a quad mesh; leave the rest to :func:`cam.remesh.check.inspect_quad_mesh`.

A repair is safe when it changes no geometry beyond the quads it touches:
collapsing a folded quad (two corners at one point) along its short diagonal,
merging the two ends of a quad edge of no length (the quad is a triangle in fact, left as a hole to close)
or moving them apart between two quads,
merging the two quads around an interior valence-2 vertex into one, closing
holes of 3, 5 or 7 edges in pairs (:mod:`cam.remesh.holes`) and closing a hole bounded
by exactly four edges with one quad, six with two or eight with three. Anything else is reported, not
guessed at.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cam.mesh.quads import quad_topology
from cam.remesh.check import boundary_loops, count_pinched_vertices
from cam.remesh.holes import pair_odd_holes, split_into_quads

__all__ = ["drop_unused_vertices", "repair_quad_mesh"]


def repair_quad_mesh(
    vertices: np.ndarray, faces: np.ndarray, *, expected_boundary_loops: int = 0, fold_ratio: float = 0.01,
    split_unpaired: bool = False,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Apply the safe repairs: collapse folded quads, merge or open quad edges of no length
    (`_resolve_zero_edges`), merge quads at interior valence-2 vertices,
    close holes of 3, 5 and 7 edges in pairs, 4-edge holes with a quad, 6-edge holes with two and 8-edge
    holes with three, merge again the quads around valence-2 vertices the filling left, drop unused
    vertices.

    Holes are closed only while the mesh has more boundary loops than
    ``expected_boundary_loops``, smallest first.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    faces
        int (m, 4) vertex indices, counter-clockwise seen from outside.
    expected_boundary_loops
        Boundary loops the source surface has (0 for a closed part).
    fold_ratio
        A quad whose shorter diagonal is below this fraction of the median
        edge length is folded (QuadriFlow leaves a few at sharp corners, with
        two corners at the same point) and is collapsed along that diagonal;
        a quad edge shorter than this fraction has no length (merged or opened).
    split_unpaired
        When the odd holes cannot be paired, fill each with a face and
        split every face into quads (:func:`cam.remesh.holes.split_into_quads`,
        four times the faces) instead of raising.

    Returns
    -------
    vertices : ndarray
        float64 (n', 3), mm.
    faces : ndarray
        int64 (m', 4) vertex indices.
    repairs : list of str
        The repairs done, as sentences.

    Raises
    ------
    ValueError
        When the connectivity cannot be built (see :func:`cam.mesh.quads.quad_topology`),
        a valence-2 vertex sits between quads that do not merge into one, or the
        odd holes cannot be paired and ``split_unpaired`` is off.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    quads = np.asarray(faces, dtype=np.int64)
    repairs: list[str] = []
    verts, quads, folded = _collapse_folded(verts, quads, fold_ratio)
    if folded:
        repairs.append(f"collapsed {folded} folded quad(s) (a diagonal shorter than {fold_ratio:g} × the median edge)")
    verts, quads, done = _close_holes_after_zero_edges(verts, quads, fold_ratio, expected_boundary_loops,
                                                      split_unpaired=split_unpaired)
    repairs += done
    verts2, quads2 = drop_unused_vertices(verts, quads)
    if len(verts2) != len(verts):
        repairs.append(f"dropped {len(verts) - len(verts2)} unused vertices")
    return verts2, quads2, repairs


def _close_holes_after_zero_edges(verts: np.ndarray, quads: np.ndarray, ratio: float, expected_boundary_loops: int,
                                  *, split_unpaired: bool) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """`_resolve_zero_edges`, then `_close_holes`; where the holes a merge leaves cannot be paired, the same
    without merges (the hole a merge leaves can lie where no short strip of quads joins it to the other odd
    hole, where the hole it closed could be paired: those edges of no length then stay, and the repairs say
    so), and only then, with ``split_unpaired``, the odd holes filled and every face split."""
    merged = _resolve_zero_edges(verts, quads, ratio, merge=True)
    why_left = "merging their ends would pinch the mesh and opening them would fold a quad"
    if not merged.merged:  # nothing to take back: one try, split or not
        v, q, done = _close_holes(merged.verts, merged.quads, expected_boundary_loops, split_unpaired=split_unpaired)
        return v, q, merged.sentences(why_left) + done
    kept = _resolve_zero_edges(verts, quads, ratio, merge=False)
    why_kept = "merged, their ends left odd holes that could not be paired (or would pinch the mesh)"
    tries = [(merged, why_left), (kept, why_kept)]
    first_error = None
    for zero, why in tries:
        try:
            v, q, done = _close_holes(zero.verts, zero.quads, expected_boundary_loops, split_unpaired=False)
            return v, q, zero.sentences(why) + done
        except ValueError as exc:
            first_error = first_error or exc
    if not split_unpaired:
        raise first_error
    v, q, done = _close_holes(merged.verts, merged.quads, expected_boundary_loops, split_unpaired=True)
    return v, q, merged.sentences(why_left) + done


def _close_holes(verts: np.ndarray, quads: np.ndarray, expected_boundary_loops: int, *,
                 split_unpaired: bool) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Merge the quads around valence-2 vertices and close the extra holes (`repair_quad_mesh`)."""
    done: list[str] = []
    quads, merges = _merge_valence2(quads, len(verts))
    if merges:
        done.append(_merged(merges))
    verts, quads, closed = _close_odd_holes(verts, quads, expected_boundary_loops, split_unpaired=split_unpaired)
    done += closed
    quads, closed = _close_small_even_holes(verts, quads, expected_boundary_loops)
    done += closed
    quads, more = _merge_valence2(quads, len(verts))  # a closed hole can leave a valence-2 vertex beside it
    if more:
        done.append(_merged(more))
    return verts, quads, done


def drop_unused_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove the vertices no face uses.

    Parameters
    ----------
    vertices
        (n, 3), mm.
    faces
        int (m, k) vertex indices.

    Returns
    -------
    vertices : ndarray
        (n', 3), mm, same dtype: the used ones, in their order.
    faces : ndarray
        int (m, k), re-indexed into them.
    """
    used = np.zeros(len(vertices), dtype=bool)
    used[np.asarray(faces).reshape(-1)] = True
    new_index = np.cumsum(used) - 1
    return np.asarray(vertices)[used], new_index[faces]


def _merged(merges: int) -> str:
    return f"merged the quads around {merges} interior valence-2 vertices"


def _merge_valence2(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, int]:
    """Replace the two quads around each interior valence-2 vertex by one quad; returns faces and merges done."""
    merges = 0
    # Each merge lowers the valence of two neighbours, which can make another valence-2 vertex: repeat.
    for _ in range(len(faces)):
        topo = quad_topology(faces, n_vertices)
        candidates = np.flatnonzero((topo.valence == 2) & (topo.face_count == 2) & ~topo.boundary_vertex)
        if not len(candidates):
            break
        v = int(candidates[0])
        h1, h2 = (int(h) for h in topo.outgoing(v))
        f1, f2 = h1 // 4, h2 // 4
        # f1 = v->a->b->c, f2 = v->c->d->a: the merged quad is a->b->c->d.
        q1 = np.roll(faces[f1], -(h1 % 4))
        q2 = np.roll(faces[f2], -(h2 % 4))
        a, b, c = q1[1], q1[2], q1[3]
        d = q2[2]
        if q2[1] != c or q2[3] != a or len({a, b, c, d}) < 4:
            raise ValueError(f"cannot merge the quads around valence-2 vertex {v}: they do not form a quad")
        keep = np.ones(len(faces), dtype=bool)
        keep[[f1, f2]] = False
        faces = np.vstack([faces[keep], [[a, b, c, d]]])
        merges += 1
    return faces, merges


def _collapse_folded(verts: np.ndarray, faces: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Collapse quads whose diagonal is shorter than ``ratio`` × the median edge (a fold: two corners coincide).

    The diagonal's ends merge at their midpoint and the quad disappears; its
    two pairs of sides are glued, which keeps the mesh manifold and oriented
    unless the two ends share another neighbour (then the topology check fails).
    """
    p = verts[faces]
    median_edge = float(np.median(np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2)))
    diag = np.stack([np.linalg.norm(p[:, 2] - p[:, 0], axis=1), np.linalg.norm(p[:, 3] - p[:, 1], axis=1)], axis=1)
    folded = np.flatnonzero(diag.min(axis=1) < ratio * median_edge)
    if not len(folded):
        return verts, faces, 0
    verts = verts.copy()
    target = np.arange(len(verts))

    def find(v: int) -> int:
        while target[v] != v:
            v = int(target[v])
        return v

    keep = np.ones(len(faces), dtype=bool)
    for f in folded.tolist():
        k = int(np.argmin(diag[f]))
        a, b = find(int(faces[f, k])), find(int(faces[f, k + 2]))
        if a != b:
            verts[a] = 0.5 * (verts[a] + verts[b])
            target[b] = a
        keep[f] = False
    roots = np.fromiter((find(v) for v in range(len(verts))), dtype=np.int64, count=len(verts))
    return verts, roots[faces[keep]], len(folded)


@dataclass(frozen=True)
class _ZeroEdges:
    """A quad mesh after `_resolve_zero_edges`, and how many quad edges of no length it merged, opened and left."""

    verts: np.ndarray
    quads: np.ndarray
    merged: int
    opened: int
    left: int

    def sentences(self, why_left: str) -> list[str]:
        done = []
        if self.merged:
            done.append(f"merged the ends of {self.merged} quad edge(s) of no length, dropping the quads left with "
                        "three corners")
        if self.opened:
            done.append(f"opened {self.opened} quad edge(s) of no length between two quads to half the median edge")
        if self.left:
            done.append(f"left {self.left} quad edge(s) of no length: {why_left}")
        return done


def _resolve_zero_edges(verts: np.ndarray, quads: np.ndarray, ratio: float, *, merge: bool) -> _ZeroEdges:
    """Merge (where ``merge``) or else open the two ends of each quad edge shorter than ``ratio`` × the median
    edge, one edge at a time.

    QuadriFlow leaves a few such edges at sharp corners: the quad is a triangle with a corner doubled, often
    beside a triangular hole whose third edge is the same edge of no length. Merged, the hole's other two
    edges close up as one and the quad, now three corners, is dropped: what is left is a triangular hole
    of real edges, which `_close_odd_holes` pairs like any other. Where a merge would pinch the mesh (the
    edge lies between two such quads, which would become two triangles touching at a point) or break its
    connectivity, the ends are moved apart instead (`_opened`), unless that folds a quad.
    """
    p = verts[quads]
    lengths = np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2)
    median_edge = float(np.median(lengths))
    rows, cols = np.nonzero(lengths < ratio * median_edge)
    pinched = _pinched_vertices(quads, len(verts)) if len(rows) else None
    if pinched is None:
        return _ZeroEdges(verts, quads, 0, 0, 0)
    ends = quads[rows, cols], quads[rows, (cols + 1) % 4]
    edges = sorted({(min(a, b), max(a, b)) for a, b in zip(*(e.tolist() for e in ends), strict=True)})
    alias: dict[int, int] = {}
    merged = opened = left = 0
    for first, second in edges:
        a, b = _root(alias, first), _root(alias, second)
        if a == b:
            continue
        renamed = np.where(quads == b, a, quads)
        keep = np.array([len(set(q)) == 4 for q in renamed.tolist()])
        after = _pinched_vertices(renamed[keep], len(verts)) if merge else None
        if after is not None and after <= pinched:
            quads, alias[b] = renamed[keep], a
            merged += 1
            continue
        moved = _opened(verts, quads, a, b, half_mm=0.25 * median_edge)
        if moved is None:
            left += 1
        else:
            verts, opened = moved, opened + 1
    return _ZeroEdges(verts, quads, merged, opened, left)


def _opened(verts: np.ndarray, quads: np.ndarray, a: int, b: int, *, half_mm: float) -> np.ndarray | None:
    """The vertices with ``a`` and ``b`` (at one point, joined by an edge between two quads) moved ``half_mm``
    apart each way, across the line between those two quads' other corners, so that each quad keeps its
    side; None where the edge is not between exactly two quads or a quad at ``a`` or ``b`` would fold."""
    at = np.flatnonzero(((quads == a) | (quads == b)).any(axis=1))
    pair = [f for f in at.tolist() if a in quads[f] and b in quads[f]]
    if len(pair) != 2:
        return None
    normal = _quad_normals(verts, quads[at]).sum(axis=0)
    first = quads[pair[0]].tolist()
    others = [[v for v in quads[f].tolist() if v not in (a, b)] for f in pair]
    across = verts[others[0]].mean(axis=0) - verts[others[1]].mean(axis=0)
    along = np.cross(across, normal)
    if not np.linalg.norm(along) > 0:
        return None
    along /= np.linalg.norm(along)
    # the first quad is on the left of its edge a -> b (or b -> a), as a counter-clockwise face
    if first[(first.index(a) + 1) % 4] != b:
        along = -along
    middle = 0.5 * (verts[a] + verts[b])
    moved = verts.copy()
    moved[a], moved[b] = middle - half_mm * along, middle + half_mm * along
    if (np.einsum("ij,j->i", _quad_normals(moved, quads[at]), normal) <= 0).any():
        return None
    return moved


def _quad_normals(verts: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(m, 3) the cross products of each quad's diagonals: normal to it, as long as twice its area."""
    p = verts[quads]
    return np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])


def _root(alias: dict[int, int], v: int) -> int:
    while v in alias:
        v = alias[v]
    return v


def _pinched_vertices(quads: np.ndarray, n_vertices: int) -> int | None:
    """Vertices where faces touch only at a corner; None when the connectivity cannot be built."""
    try:
        return count_pinched_vertices(quad_topology(quads, n_vertices))
    except ValueError:
        return None


def _close_odd_holes(verts: np.ndarray, quads: np.ndarray, expected_boundary_loops: int, *,
                     split_unpaired: bool) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Pair the holes of 3, 5 and 7 edges (or split every face, see :func:`repair_quad_mesh`) when they are all
    extra holes; returns the vertices, the quads and what was done (holes of 5 and 7 edges are left with 6
    and 8, for `_close_small_even_holes`)."""
    topo = quad_topology(quads, len(verts))
    loops = sorted(boundary_loops(topo), key=len)
    excess = len(loops) - expected_boundary_loops
    # Boundary half-edges run with the existing faces on their left; the filling face runs the other way.
    rings = [[int(topo.origin[h]) for h in loop][::-1] for loop in loops if len(loop) in (3, 5, 7)]
    holes = [ring for ring in rings if len(set(ring)) == len(ring)]
    if not (excess > 0 and holes and len(holes) <= excess):
        return verts, quads, []
    try:
        # A strip that wanders over much of the part leaves a long band of half-width quads there: past an
        # eighth more faces, another layout is better (pairing two holes added 297 to 4,792 faces to the
        # README example's 2,800-quad layouts of five seeds).
        verts, quads, pairs = pair_odd_holes(verts, quads, holes, max_added_faces=max(len(quads) // 8, 16))
        sizes = ", ".join(f"{sum(len(h) == k for h in holes)} of {k} edges" for k in (3, 5, 7)
                          if any(len(h) == k for h in holes))
        done = f"closed {2 * pairs} odd hole(s) in pairs ({sizes}), splitting the strip of quads between each two"
        return verts, quads, [done]
    except ValueError as exc:
        if not split_unpaired:
            raise
        verts, quads = split_into_quads(verts, quads, holes)
        return verts, quads, [f"{exc}: filled {len(holes)} odd hole(s) and split every face into quads"]


def _close_small_even_holes(verts: np.ndarray, quads: np.ndarray,
                            expected_boundary_loops: int) -> tuple[np.ndarray, list[str]]:
    """Close the extra holes of 4 edges with a quad, of 6 edges with two (split along the shortest of the
    three diagonals) and of 8 edges with three, smallest loops first; returns the quads and what was done."""
    topo = quad_topology(quads, len(verts))
    loops = sorted(boundary_loops(topo), key=len)
    excess = len(loops) - expected_boundary_loops
    new_faces, closed = [], {4: 0, 6: 0, 8: 0}
    for loop in loops:
        if sum(closed.values()) >= excess or len(loop) not in closed:
            continue
        # Boundary half-edges run with the existing faces on their left; the patch runs the other way.
        ring = [int(topo.origin[h]) for h in loop][::-1]
        if len(set(ring)) != len(ring):
            continue  # a loop that passes a vertex twice is not a disc's rim
        if len(ring) == 6:
            k = min(range(3), key=lambda i: float(np.linalg.norm(verts[ring[i]] - verts[ring[i + 3]])))
            ring = ring[k:] + ring[:k]
            new_faces += [ring[0:4], [ring[3], ring[4], ring[5], ring[0]]]
        elif len(ring) == 8:
            # Three quads: two at the rim, one between their inner sides, the two diagonals the shortest pair.
            k = min(range(8), key=lambda i: sum(float(np.linalg.norm(verts[ring[(i + a) % 8]] - verts[ring[(i + b) % 8]]))
                                                 for a, b in ((0, 3), (3, 6))))
            ring = ring[k:] + ring[:k]
            new_faces += [ring[0:4], ring[3:7], [ring[6], ring[7], ring[0], ring[3]]]
        else:
            new_faces.append(ring)
        closed[len(ring)] += 1
    if not new_faces:
        return quads, []
    quads = np.vstack([quads, np.asarray(new_faces, dtype=np.int64)])
    done = [f"closed {n} hole(s) of {edges} edges with {edges // 2 - 1} quad(s) each"
            for edges, n in closed.items() if n]
    return quads, done
