"""Coarse quads from the paired coarse mesh: every face split into quads, then edges rotated towards valence four.

The paired mesh (:mod:`cam.remesh.pairing`) has quads and a few triangles. Splitting every face about its centre,
each side at its middle (one Catmull–Clark step: a crease edge's middle on its chain), makes it all quads, half
the size: a quad's corners keep their valence, its centre and side middles have four, and a triangle's centre
has three. Rotating a quad edge on no crease (the two quads beside it turned one step within their hexagon:
two vertices lose an edge, two gain one) then brings vertices nearer four edges where the new quads stay
convex; chain ends are left out of the count, since a corner of the part has the valence its creases give it.
"""

from __future__ import annotations

import numpy as np

from cam.remesh.coarse import EditableMesh, edge_table
from cam.remesh.features import CORNER, SMOOTH
from cam.remesh.pairing import quad_scores

__all__ = ["rotate_to_valence", "split_into_quads"]

# A rotation is taken only where both new quads score at least this (`quad_scores`: 1 square, 0 a 180° corner).
_MIN_SCORE = 0.15


def split_into_quads(mesh: EditableMesh, quads: np.ndarray, quad_region: np.ndarray, triangles: np.ndarray,
                     triangle_region: np.ndarray) -> None:
    """Replace the mesh's faces by the quads (q, 4) and triangles (t, 3) given, each split about its centre
    (in place: ``mesh.F`` becomes (4q + 3t, 4))."""
    faces = [f for f in quads.tolist()] + [f for f in triangles.tolist()]
    region = np.concatenate([quad_region, triangle_region]).astype(np.int64)
    sides = {}
    for face, r in zip(faces, region.tolist(), strict=True):
        for j in range(len(face)):
            a, b = face[j], face[(j + 1) % len(face)]
            sides.setdefault((min(a, b), max(a, b)), r)
    keys = np.array(list(sides), dtype=np.int64).reshape(-1, 2)
    points, kind, chain, arc, _ = mesh.edge_middles(keys, np.array(list(sides.values()), dtype=np.int64))
    middle_ids = mesh.add_vertices(points, kind, chain, arc, np.zeros((len(keys), 10)), np.zeros(len(keys)))
    middle = {key: int(i) for key, i in zip(map(tuple, keys.tolist()), middle_ids.tolist(), strict=True)}
    centres = np.array([mesh.V[f].mean(axis=0) for f in faces]).reshape(-1, 3)
    centres = mesh.features.project(centres, region)[0]
    centre_ids = mesh.add_vertices(centres, np.full(len(faces), SMOOTH), np.full(len(faces), -1, dtype=np.int64),
                                   np.zeros(len(faces)), np.zeros((len(faces), 10)), np.zeros(len(faces)))
    new_faces, new_region = [], []
    for face, r, c in zip(faces, region.tolist(), centre_ids.tolist(), strict=True):
        k = len(face)
        for i in range(k):
            prev, here, nxt = face[i - 1], face[i], face[(i + 1) % k]
            new_faces.append((here, middle[(min(here, nxt), max(here, nxt))], c,
                              middle[(min(prev, here), max(prev, here))]))
            new_region.append(r)
    mesh.F = np.array(new_faces, dtype=np.int64).reshape(-1, 4)
    mesh.region = np.array(new_region, dtype=np.int64)


def rotate_to_valence(mesh: EditableMesh, *, rounds: int = 16) -> int:
    """Rotate quad edges on no crease where that brings vertices nearer four quads (chain ends not counted) and
    both new quads are convex, in rounds of rotations with distinct vertices; returns the rotations made."""
    done = 0
    for _ in range(rounds):
        creases = mesh.result().crease_edges()
        edges, faces = edge_table(mesh.F)
        a, b = edges[:, 0], edges[:, 1]
        f1, f2 = mesh.F[faces[:, 0]], mesh.F[faces[:, 1]]
        rows = np.arange(len(edges))
        i = np.argmax(f1 == a[:, None], axis=1)  # f1 runs a, b, c, d
        j = np.argmax(f2 == b[:, None], axis=1)  # f2 runs b, a, e, f
        c, d = f1[rows, (i + 2) % 4], f1[rows, (i + 3) % 4]
        e, f = f2[rows, (j + 2) % 4], f2[rows, (j + 3) % 4]
        valence = np.bincount(mesh.F.ravel(), minlength=len(mesh.V))
        counted = mesh.kind != CORNER
        base = _gain(valence, counted, a, -1) + _gain(valence, counted, b, -1)
        gain_ce = base + _gain(valence, counted, c, 1) + _gain(valence, counted, e, 1)
        gain_df = base + _gain(valence, counted, d, 1) + _gain(valence, counted, f, 1)
        crease = np.array([(x, y) in creases for x, y in edges.tolist()], dtype=bool)
        open_edge = ~crease & (valence[a] > 3) & (valence[b] > 3)
        options = []
        for gain, p, q in ((gain_ce, c, e), (gain_df, d, f)):
            ok = np.flatnonzero(open_edge & (gain > 0) & (p != q))
            options += [(int(gain[k]), k, int(p[k]), int(q[k])) for k in ok.tolist()]
        if not options:
            break
        options.sort(key=lambda o: -o[0])
        existing = set(map(tuple, edges.tolist()))
        touched = np.zeros(len(mesh.V), dtype=bool)
        made = 0
        for _, k, p, q in options:
            corners = [int(a[k]), int(b[k]), int(c[k]), int(d[k]), int(e[k]), int(f[k])]
            if touched[corners].any() or (min(p, q), max(p, q)) in existing:
                continue
            ak, bk, ck, dk, ek, fk = corners
            if (p, q) == (ck, ek):
                new = np.array([[ck, dk, ak, ek], [ek, fk, bk, ck]])
            else:
                new = np.array([[dk, ak, ek, fk], [fk, bk, ck, dk]])
            if quad_scores(mesh.V, new).min() < _MIN_SCORE:
                continue
            mesh.F[faces[k, 0]], mesh.F[faces[k, 1]] = new
            touched[corners] = True
            existing.add((min(p, q), max(p, q)))
            made += 1
        done += made
        if not made:
            break
        mesh.relax(steps=1)
    return done


def _gain(valence: np.ndarray, counted: np.ndarray, x: np.ndarray, step: int) -> np.ndarray:
    """How much nearer four the valence of vertices ``x`` gets by ``step`` (squared distance before less after;
    0 for a chain end)."""
    return np.where(counted[x], (valence[x] - 4) ** 2 - (valence[x] + step - 4) ** 2, 0)
