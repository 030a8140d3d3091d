"""Repair what is small and safe in a quad mesh; leave the rest to :func:`cam.remesh.check.inspect_quad_mesh`.

A repair is safe when it changes no geometry beyond the quads it touches:
collapsing a folded quad (two corners at one point) along its short diagonal,
merging the two quads around an interior valence-2 vertex into one, closing
holes of 3, 5 or 7 edges in pairs (:mod:`cam.remesh.holes`) and closing a hole bounded
by exactly four edges with one quad, six with two or eight with three. Anything else is reported, not
guessed at.
"""

from __future__ import annotations

import numpy as np

from cam.mesh.quads import quad_topology
from cam.remesh.check import boundary_loops
from cam.remesh.holes import pair_odd_holes, split_into_quads

__all__ = ["drop_unused_vertices", "repair_quad_mesh"]


def repair_quad_mesh(
    vertices: np.ndarray, faces: np.ndarray, *, expected_boundary_loops: int = 0, fold_ratio: float = 0.01,
    split_unpaired: bool = False,
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Apply the safe repairs: collapse folded quads, merge quads at interior valence-2 vertices,
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
        two corners at the same point) and is collapsed along that diagonal.
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
    quads, merges = _merge_valence2(quads, len(verts))
    if merges:
        repairs.append(_merged(merges))
    verts, quads, done = _close_odd_holes(verts, quads, expected_boundary_loops, split_unpaired=split_unpaired)
    repairs += done
    quads, done = _close_small_even_holes(verts, quads, expected_boundary_loops)
    repairs += done
    quads, more = _merge_valence2(quads, len(verts))  # a closed hole can leave a valence-2 vertex beside it
    if more:
        repairs.append(_merged(more))
    verts2, quads2 = drop_unused_vertices(verts, quads)
    if len(verts2) != len(verts):
        repairs.append(f"dropped {len(verts) - len(verts2)} unused vertices")
    return verts2, quads2, repairs


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
