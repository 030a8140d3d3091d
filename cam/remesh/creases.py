"""How much of a triangle mesh's creases a quad mesh's edges follow.

Segment puts patch borders on sharp quad edges, and a bicubic patch cannot bend
round a crease that runs through it: a crease of the input that no quad edge
follows ends up inside a patch, and the fit misses it there by up to the quad
size times the crease's turn. QuadriFlow's ``-sharp`` follows most creases, but
how many depends on its seed (on Fandisk ×10 at 3,000 quads, seeds 0, 1 and 2
miss 193, 27 and 110 mm of its 669 mm), so :func:`cam.remesh.quadriflow.remesh_quads` measures each layout
with :func:`measure_crease_following` and keeps the one that misses least.

:func:`measure_crease_conformity` gives the kept layout the measures of issue 35, independent of the quad
size: crease recall (the share of crease length that quad edges follow, within a fixed fraction of the part's
diagonal) and the quads that straddle a crease. They are reported, not used to choose.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from cam.mesh.closest import closest_points, mesh_index
from cam.mesh.creases import mesh_creases

__all__ = ["CreaseConformity", "CreaseFollowing", "CreaseGraph", "crease_graph", "measure_crease_conformity",
           "measure_crease_following"]

# Points per crease edge: each stands for a quarter of the edge, so a crease half followed counts half.
_SAMPLES = 4
# Quad edges searched around a crease point; a vertex of a quad mesh has about four edges, so
# sixteen midpoints reach well past the ones that can pass near it.
_NEIGHBOURS = 16


@dataclass(frozen=True)
class CreaseFollowing:
    """Crease length of the input and how much of it no quad edge follows, mm; `tolerance_mm` is the
    distance within which a quad edge counts as following."""

    crease_length_mm: float
    missed_length_mm: float
    tolerance_mm: float

    def as_dict(self) -> dict:
        return {"crease_length_mm": self.crease_length_mm, "missed_crease_mm": self.missed_length_mm,
                "crease_tolerance_mm": self.tolerance_mm}


def measure_crease_following(
    quad_vertices: np.ndarray,
    quads: np.ndarray,
    vertices: np.ndarray,
    triangles: np.ndarray,
    *,
    crease_angle_deg: float = 60.0,
    tolerance_ratio: float = 0.1,
    max_turn_deg: float = 30.0,
) -> CreaseFollowing:
    """Length of the triangle mesh's creases that no quad edge follows.

    Parameters
    ----------
    quad_vertices, quads
        float (n, 3) mm and int (m, 4): the quad mesh.
    vertices, triangles
        float (p, 3) mm and int (q, 3): the triangle mesh it was made from.
    crease_angle_deg
        A triangle-mesh edge is a crease when its two faces' normals differ by
        more than this; 60° is the angle QuadriFlow's ``-sharp`` looks for.
    tolerance_ratio
        A point of a crease is followed when a quad edge passes within this
        fraction of the median quad edge length of it...
    max_turn_deg
        ...and runs within this angle of the crease's direction (a quad edge
        that crosses a crease does not follow it).

    Returns
    -------
    CreaseFollowing
        Lengths in mm, measured at four points per crease edge.
    """
    qv, qf, tv, tf = _check_meshes(quad_vertices, quads, vertices, triangles)
    if not 0 < crease_angle_deg < 180 or not 0 < max_turn_deg < 90 or tolerance_ratio <= 0:
        raise ValueError(f"need 0 < crease_angle_deg < 180, 0 < max_turn_deg < 90 and tolerance_ratio > 0; got "
                         f"{crease_angle_deg}, {max_turn_deg}, {tolerance_ratio}")
    creases = mesh_creases(tv, tf, angle_deg=crease_angle_deg)
    a, b = creases.a, creases.b
    qe = np.sort(np.stack([qf, np.roll(qf, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1)
    qe = np.unique(qe, axis=0)
    p, q = qv[qe[:, 0]], qv[qe[:, 1]]
    lengths = np.linalg.norm(q - p, axis=1)
    tolerance = float(tolerance_ratio * np.median(lengths))
    if not len(a):
        return CreaseFollowing(0.0, 0.0, tolerance)
    seg = np.linalg.norm(b - a, axis=1)
    t = (np.arange(_SAMPLES) + 0.5) / _SAMPLES
    points = (a[:, None] + t[None, :, None] * (b - a)[:, None]).reshape(-1, 3)
    weight = np.repeat(seg / _SAMPLES, _SAMPLES)
    crease_dir = np.repeat((b - a) / np.maximum(seg, 1e-300)[:, None], _SAMPLES, axis=0)
    quad_dir = (q - p) / np.maximum(lengths, 1e-300)[:, None]
    k = min(_NEIGHBOURS, len(qe))
    _, near = cKDTree(0.5 * (p + q)).query(points, k=k)
    near = near.reshape(len(points), k)
    # Distance from each crease point to each nearby quad edge (a segment, not its line).
    pp, dd, ll = p[near], quad_dir[near], lengths[near]
    s = np.clip(np.einsum("nkj,nkj->nk", points[:, None] - pp, dd), 0.0, ll)
    dist = np.linalg.norm(points[:, None] - (pp + s[..., None] * dd), axis=2)
    aligned = np.abs(np.einsum("nkj,nj->nk", dd, crease_dir)) >= np.cos(np.radians(max_turn_deg))
    followed = ((dist <= tolerance) & aligned).any(axis=1)
    return CreaseFollowing(float(seg.sum()), float(weight[~followed].sum()), tolerance)



@dataclass(frozen=True, eq=False)
class CreaseConformity:
    """How a quad mesh conforms to a triangle mesh's creases (see :func:`measure_crease_conformity`).

    Attributes
    ----------
    crease_angle_deg
        A triangle-mesh edge is a crease when its two faces' normals differ by more than this, degrees.
    tolerance_mm
        Distance within which a quad edge follows a crease and a quad vertex lies on one, mm.
    crease_length_mm
        Length of the creases, mm.
    followed_length_mm
        Length of them that quad edges follow, mm.
    straddling
        int64 (s,): indices of the quads that straddle a crease, ascending.
    """

    crease_angle_deg: float
    tolerance_mm: float
    crease_length_mm: float
    followed_length_mm: float
    straddling: np.ndarray

    @property
    def recall(self) -> float | None:
        """Share of the crease length that quad edges follow; None when the mesh has no creases."""
        if self.crease_length_mm == 0.0:
            return None
        return self.followed_length_mm / self.crease_length_mm

    def as_dict(self) -> dict:
        """The measures as JSON-ready fields of ``remesh.json``."""
        return {"crease_recall": self.recall, "crease_recall_length_mm": self.crease_length_mm,
                "crease_recall_followed_mm": self.followed_length_mm,
                "crease_recall_tolerance_mm": self.tolerance_mm, "crease_recall_angle_deg": self.crease_angle_deg,
                "straddling_quads": len(self.straddling)}


class CreaseGraph(NamedTuple):
    """The creases of a triangle mesh and the regions they bound."""

    edges: np.ndarray  # int64 (k, 2): crease edges as sorted vertex pairs, each once
    pair_edge: np.ndarray  # int64 (r,): the crease edge of each sharp face pair
    pair_faces: np.ndarray  # int64 (r, 2): the two triangles of each sharp face pair
    face_region: np.ndarray  # int64 (q,): crease-bounded region of each triangle
    edge_angle_deg: np.ndarray  # float64 (k,): each crease edge's angle between its faces' normals (the largest)


def measure_crease_conformity(
    quad_vertices: np.ndarray,
    quads: np.ndarray,
    vertices: np.ndarray,
    triangles: np.ndarray,
    *,
    crease_angle_deg: float = 50.0,
    tolerance_ratio: float = 0.002,
    max_turn_deg: float = 30.0,
) -> CreaseConformity:
    """Crease recall of a quad mesh and the quads that straddle a crease, at a tolerance set by the part's size.

    A crease is an edge of the triangle mesh whose two faces' normals differ by more than
    ``crease_angle_deg``. With ``tol = tolerance_ratio`` × the triangle mesh's bounding-box diagonal:

    - A point of a crease is followed when a quad edge that runs within ``max_turn_deg`` of the crease's
      direction passes within ``tol`` of it (a quad edge that crosses a crease does not follow it). The
      followed length is exact: each crease edge meets the ``tol``-capsule round each such quad edge in an
      interval, found in closed form, and the union of the intervals is measured.
    - The creases cut the triangles into crease-bounded regions (triangles joined across non-crease edges).
      A quad vertex lies in the region of its closest triangle and, when it is within ``tol`` of a crease
      edge, in the regions on both sides of that edge too. A quad straddles a crease when no region holds
      all its vertices: it has corners on both sides of a crease. A crease that does not cut its region in
      two (one that ends inside a face of the part) has the same region on both sides, so a quad over it is
      not counted; its length still counts as not followed.

    Parameters
    ----------
    quad_vertices, quads
        float (n, 3) mm and int (m, 4): the quad mesh.
    vertices, triangles
        float (p, 3) mm and int (q, 3): the triangle mesh it was made from.
    crease_angle_deg
        Crease threshold, degrees in (0, 180); the default is ``segment.sharp_angle_deg``'s.
    tolerance_ratio
        ``tol`` as a fraction of the triangle mesh's bounding-box diagonal, > 0 (issue 35's 0.2 %).
    max_turn_deg
        Largest angle between a following quad edge and the crease, degrees in (0, 90).

    Returns
    -------
    CreaseConformity
        Crease and followed lengths (mm), ``tol`` (mm) and the straddling quads.

    Raises
    ------
    ValueError
        For arrays of the wrong shape, indices out of range, parameters out of range or a triangle mesh
        of zero extent, naming what was seen.
    """
    qv, qf, tv, tf = _check_meshes(quad_vertices, quads, vertices, triangles)
    if not 0 < crease_angle_deg < 180 or not 0 < max_turn_deg < 90 or not tolerance_ratio > 0:
        raise ValueError(f"need 0 < crease_angle_deg < 180, 0 < max_turn_deg < 90 and tolerance_ratio > 0; got "
                         f"{crease_angle_deg}, {max_turn_deg}, {tolerance_ratio}")
    qf, tf = qf.astype(np.int64), tf.astype(np.int64)
    if qf.min() < 0 or qf.max() >= len(qv) or tf.min() < 0 or tf.max() >= len(tv):
        raise ValueError(f"quads index vertices {qf.min()}..{qf.max()} of {len(qv)} and triangles {tf.min()}.."
                         f"{tf.max()} of {len(tv)}")
    diagonal = float(np.linalg.norm(np.ptp(tv[np.unique(tf)], axis=0)))
    if not diagonal > 0:
        raise ValueError(f"the triangle mesh has zero extent (bounding-box diagonal {diagonal} mm)")
    tol = tolerance_ratio * diagonal
    graph = crease_graph(tv, tf, crease_angle_deg)
    qe = np.unique(np.sort(np.stack([qf, np.roll(qf, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1), axis=0)
    qe = qe[qe[:, 0] != qe[:, 1]]
    p, q = qv[qe[:, 0]], qv[qe[:, 1]]
    # Long crease edges (a CAD mesh's) are cut into pieces about a quad long, so that each piece meets few quad
    # edges in the neighbour searches below.
    piece = max(float(np.median(np.linalg.norm(q - p, axis=1))), tol) if len(qe) else tol
    starts, vecs, parent = _split_segments(tv[graph.edges[:, 0]], tv[graph.edges[:, 1]], piece)
    lengths = np.linalg.norm(vecs, axis=1)
    followed = _followed_fractions(starts, vecs, p, q, tol, max_turn_deg)
    straddling = _straddling_quads(qv, qf, tv, tf, graph, starts, vecs, parent, tol)
    return CreaseConformity(float(crease_angle_deg), tol, float(lengths.sum()), float((lengths * followed).sum()),
                            straddling)


def _check_meshes(quad_vertices, quads, vertices, triangles) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The four arrays as numpy arrays (coordinates float64); ValueError naming the shapes when they are wrong."""
    qv = np.asarray(quad_vertices, dtype=np.float64)
    qf = np.asarray(quads)
    tv = np.asarray(vertices, dtype=np.float64)
    tf = np.asarray(triangles)
    if qv.ndim != 2 or qv.shape[1] != 3 or qf.ndim != 2 or qf.shape[1] != 4 or len(qf) == 0:
        raise ValueError(f"need quad vertices (n, 3) and quads (m, 4), got {qv.shape} and {qf.shape}")
    if tv.ndim != 2 or tv.shape[1] != 3 or tf.ndim != 2 or tf.shape[1] != 3 or len(tf) == 0:
        raise ValueError(f"need vertices (p, 3) and triangles (q, 3), got {tv.shape} and {tf.shape}")
    return qv, qf, tv, tf


def crease_graph(vertices: np.ndarray, triangles: np.ndarray, angle_deg: float) -> CreaseGraph:
    """Crease edges (normals over ``angle_deg`` apart, as :func:`cam.mesh.creases.mesh_creases` finds them) and the
    regions of triangles joined across the other edges.

    ``vertices`` float (p, 3) mm and ``triangles`` int (q, 3) are the triangle mesh; see `CreaseGraph` for what
    is returned.
    """
    import trimesh

    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    pairs = np.asarray(mesh.face_adjacency, dtype=np.int64).reshape(-1, 2)
    angles = np.degrees(np.asarray(mesh.face_adjacency_angles, dtype=np.float64))
    sharp = mesh.face_adjacency_angles > np.radians(angle_deg)
    # An edge of more than two triangles gives several face pairs; its length counts once.
    edges, pair_edge = np.unique(np.sort(np.asarray(mesh.face_adjacency_edges)[sharp], axis=1).reshape(-1, 2),
                                 axis=0, return_inverse=True)
    smooth = pairs[~sharp]
    n = len(triangles)
    joined = coo_matrix((np.ones(len(smooth)), (smooth[:, 0], smooth[:, 1])), shape=(n, n))
    _, region = connected_components(joined, directed=False)
    pair_edge = pair_edge.reshape(-1).astype(np.int64)
    edge_angle = np.zeros(len(edges))
    np.maximum.at(edge_angle, pair_edge, angles[sharp])
    return CreaseGraph(edges.astype(np.int64), pair_edge, pairs[sharp], region.astype(np.int64), edge_angle)


def _split_segments(a: np.ndarray, b: np.ndarray, piece: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segments a→b (float (k, 3) mm) cut into equal pieces no longer than ``piece`` mm.

    Returns each piece's start and vector (float (s, 3) mm) and the segment it is part of (int64 (s,)).
    """
    seg = b - a
    count = np.maximum(1, np.ceil(np.linalg.norm(seg, axis=1) / piece)).astype(np.int64)
    parent = np.repeat(np.arange(len(seg)), count)
    step = np.arange(len(parent)) - np.repeat(np.cumsum(count) - count, count)
    vecs = seg[parent] / count[parent, None]
    return a[parent] + step[:, None] * vecs, vecs, parent


def _pairs_within(tree: cKDTree, points: np.ndarray, reach: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """(point, tree item) index pairs whose distance is at most ``reach`` (per point or one value), int64 each."""
    found = tree.query_ball_point(points, reach) if len(points) else []
    counts = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
    items = np.fromiter(itertools.chain.from_iterable(found), dtype=np.int64, count=int(counts.sum()))
    return np.repeat(np.arange(len(found)), counts), items


def _followed_fractions(starts: np.ndarray, vecs: np.ndarray, p: np.ndarray, q: np.ndarray, tol: float,
                        max_turn_deg: float) -> np.ndarray:
    """Share of each crease piece (start, vector: float (s, 3) mm) within ``tol`` mm of a quad edge p→q
    (float (e, 3) mm) that runs within ``max_turn_deg`` of it; float (s,) in [0, 1], exact."""
    fraction = np.zeros(len(starts))
    edge_vec = q - p
    edge_len = np.linalg.norm(edge_vec, axis=1)
    if not len(starts) or not len(p):
        return fraction
    reach = 0.5 * np.linalg.norm(vecs, axis=1) + 0.5 * edge_len.max() + tol
    piece, edge = _pairs_within(cKDTree(0.5 * (p + q)), starts + 0.5 * vecs, reach)
    d, e = vecs[piece], edge_vec[edge]
    cos = np.abs(np.einsum("ij,ij->i", d, e)) / np.maximum(np.linalg.norm(d, axis=1) * edge_len[edge], 1e-300)
    along = cos >= np.cos(np.radians(max_turn_deg))
    piece, edge = piece[along], edge[along]
    lo, hi = _capsule_interval(starts[piece], vecs[piece], p[edge], q[edge], tol)
    lo, hi = np.maximum(lo, 0.0), np.minimum(hi, 1.0)
    hit = lo <= hi
    piece, lo, hi = piece[hit], lo[hit], hi[hit]
    # The uncovered share of a piece is the sum of the gaps between its intervals taken in order of their
    # starts: 1 - gaps is exactly 1 where the intervals leave none (a sum of covered lengths would not be).
    order = np.lexsort((lo, piece))
    piece, lo, hi = piece[order], lo[order], hi[order]
    counts = np.bincount(piece, minlength=len(starts))
    width = int(counts.max(initial=0))
    rank = np.arange(len(piece)) - np.repeat(np.cumsum(counts) - counts, counts)
    LO = np.full((len(starts), max(width, 1)), -np.inf)
    HI = LO.copy()
    LO[piece, rank], HI[piece, rank] = lo, hi
    reached = np.maximum.accumulate(HI, axis=1)
    before = np.maximum(np.hstack([np.zeros((len(starts), 1)), reached[:, :-1]]), 0.0)
    gaps = np.maximum(LO - before, 0.0).sum(axis=1) + (1.0 - np.maximum(reached[:, -1], 0.0))
    return 1.0 - gaps


def _capsule_interval(start: np.ndarray, vec: np.ndarray, p: np.ndarray, q: np.ndarray,
                      radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Parameters t where start + t·vec lies within ``radius`` mm of the segment p→q, row by row.

    The capsule round a segment is convex, so a line meets it in one interval: the hull of where it meets
    the two end balls and the cylinder between them. Inputs float (k, 3) mm; returns lo, hi float (k,),
    lo = +inf and hi = -inf where the line misses.
    """
    lo1, hi1 = _ball_interval(start, vec, p, radius)
    lo2, hi2 = _ball_interval(start, vec, q, radius)
    axis = q - p
    length = np.linalg.norm(axis, axis=1)
    u = axis / np.maximum(length, 1e-300)[:, None]
    w = start - p
    s0 = np.einsum("ij,ij->i", w, u)
    ds = np.einsum("ij,ij->i", vec, u)
    inside = (s0 >= 0) & (s0 <= length)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = -s0 / ds, (length - s0) / ds
    moving = ds != 0
    slab_lo = np.where(moving, np.minimum(t1, t2), np.where(inside, -np.inf, np.inf))
    slab_hi = np.where(moving, np.maximum(t1, t2), np.where(inside, np.inf, -np.inf))
    w_perp = w - s0[:, None] * u
    v_perp = vec - ds[:, None] * u
    lo3, hi3 = _quadratic_at_most_zero(np.einsum("ij,ij->i", v_perp, v_perp),
                                       2.0 * np.einsum("ij,ij->i", v_perp, w_perp),
                                       np.einsum("ij,ij->i", w_perp, w_perp) - radius**2,
                                       np.einsum("ij,ij->i", vec, vec))
    lo3, hi3 = np.maximum(lo3, slab_lo), np.minimum(hi3, slab_hi)
    missed = lo3 > hi3
    lo3, hi3 = np.where(missed, np.inf, lo3), np.where(missed, -np.inf, hi3)
    return np.minimum(np.minimum(lo1, lo2), lo3), np.maximum(np.maximum(hi1, hi2), hi3)


def _ball_interval(start: np.ndarray, vec: np.ndarray, centre: np.ndarray,
                   radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Parameters t where start + t·vec lies within ``radius`` mm of ``centre`` (float (k, 3) mm each);
    lo = +inf and hi = -inf where the line misses."""
    w = start - centre
    a = np.einsum("ij,ij->i", vec, vec)
    return _quadratic_at_most_zero(a, 2.0 * np.einsum("ij,ij->i", vec, w), np.einsum("ij,ij->i", w, w) - radius**2, a)


def _quadratic_at_most_zero(a: np.ndarray, b: np.ndarray, c: np.ndarray,
                            scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where a·t² + b·t + c ≤ 0 with a ≥ 0, row by row (float (k,) each): lo, hi, or +inf, -inf where nowhere.

    Where a is below 1e-20 × ``scale`` (the line runs parallel to the cylinder's axis to 1e-10) the
    quadratic is taken as the constant c: over t in [0, 1] it changes by under 1e-10 of the line's length.
    """
    flat = a <= 1e-20 * scale
    disc = b * b - 4.0 * a * c
    real = ~flat & (disc >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # The stable pair of roots: q / a and c / q, q = -(b + sign(b)·√disc) / 2.
        half = -0.5 * (b + np.copysign(np.sqrt(np.maximum(disc, 0.0)), b))
        r1 = half / a
        r2 = np.where(half != 0, c / half, r1)
    lo = np.where(real, np.minimum(r1, r2), np.where(flat & (c <= 0), -np.inf, np.inf))
    hi = np.where(real, np.maximum(r1, r2), np.where(flat & (c <= 0), np.inf, -np.inf))
    return lo, hi


def _straddling_quads(qv: np.ndarray, qf: np.ndarray, tv: np.ndarray, tf: np.ndarray, graph: CreaseGraph,
                      starts: np.ndarray, vecs: np.ndarray, parent: np.ndarray, tol: float) -> np.ndarray:
    """Quads (int64 indices, ascending) whose vertices share no crease-bounded region; see
    :func:`measure_crease_conformity` for which regions a vertex lies in."""
    if not len(graph.edges):
        return np.zeros(0, dtype=np.int64)
    nearest = closest_points(mesh_index(tv, tf), qv)[2]
    vertex, region = [np.arange(len(qv))], [graph.face_region[nearest]]
    # Vertices within tol of a crease lie on both its sides, whatever triangle is the closest.
    reach = 0.5 * float(np.linalg.norm(vecs, axis=1).max()) + tol
    v, k = _pairs_within(cKDTree(starts + 0.5 * vecs), qv, reach)
    dd = np.maximum(np.einsum("ij,ij->i", vecs[k], vecs[k]), 1e-300)
    t = np.clip(np.einsum("ij,ij->i", qv[v] - starts[k], vecs[k]) / dd, 0.0, 1.0)
    near = np.linalg.norm(qv[v] - (starts[k] + t[:, None] * vecs[k]), axis=1) <= tol
    v, edge = v[near], parent[k[near]]
    # Each crease edge's face pairs (several where more than two triangles share the edge).
    order = np.argsort(graph.pair_edge, kind="stable")
    per_edge = np.bincount(graph.pair_edge, minlength=len(graph.edges))
    rows = order[_ranges(np.cumsum(per_edge)[edge] - per_edge[edge], per_edge[edge])]
    v = np.repeat(v, per_edge[edge])
    for side in (0, 1):
        vertex.append(v)
        region.append(graph.face_region[graph.pair_faces[rows, side]])
    n_regions = int(graph.face_region.max()) + 1
    member = np.unique(np.concatenate(vertex) * n_regions + np.concatenate(region))
    member_vertex, member_region = member // n_regions, member % n_regions
    # For each quad and region, count the quad's vertices in the region (each vertex once, even one a quad
    # repeats): a region that holds all of them keeps the quad whole.
    corner = np.unique(np.repeat(np.arange(len(qf)), 4) * len(qv) + qf.reshape(-1))
    quad, corner = corner // len(qv), corner % len(qv)
    distinct = np.bincount(quad, minlength=len(qf))
    per_vertex = np.bincount(member_vertex, minlength=len(qv))
    idx = _ranges(np.cumsum(per_vertex)[corner] - per_vertex[corner], per_vertex[corner])
    keys, shared = np.unique(np.repeat(quad, per_vertex[corner]) * n_regions + member_region[idx],
                             return_counts=True)
    owner = keys // n_regions
    whole = np.zeros(len(qf), dtype=bool)
    whole[owner[shared == distinct[owner]]] = True
    return np.flatnonzero(~whole)


def _ranges(first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """first[0], first[0] + 1, ... (count[0] of them), then the same for each following row; int64."""
    total = int(count.sum())
    return np.repeat(first - (np.cumsum(count) - count), count) + np.arange(total)
