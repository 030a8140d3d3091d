"""A closed-form signed distance estimate from oriented points, used to start the grid field.

Starting IGR from a sphere spends most of a CPU budget moving the surface to
the points; starting it from this estimate lets the IGR loss spend its
iterations on what it is good at (sharp, distance-like fields through the
points). The estimate is the distance to the nearest points' tangent planes,
blended with Gaussian weights of each point's distance beyond the nearest one's, so that
they never all underflow far from the cloud.

Two choices keep the sign right near a part's edges and corners, where the nearest points
lie on two or three faces whose planes disagree. The weights are Gaussian in the distance,
not in its square: in squared distance their width shrinks as spacing^2 / distance, so a
few spacings out one point's plane decides alone, and beside a convex edge that point is
as often on the other face (whose plane puts the query inside): the field grew lumps of
1-4 mm out of the corners of a bracket scanned at 0.1 % noise. And each point counts by how
squarely it faces the query (|plane distance| over distance, softened within the blending
width): a face seen edge-on from the query says little about which side of the part it is.

Where the nearest points lie on two faces that meet at a crease, no mean of their planes is right
on both faces: beside a hole in one face's samples (random sampling leaves holes of a few spacings)
the other face's planes are nearest and move the hole's face by up to a mm, out of a convex edge or
into a concave one (the lumps a CSG block at 0.1 % noise kept). Near a crease the estimate is
instead the faces' distances combined as the solid they bound, which is exact for planes: the larger
of two at a convex crease (the solid is where both say inside), the smaller at a concave one, and
at a corner of three what its creases say. Each face counts by its share of the neighbours, not by
how near its samples are, since the face with the hole is the one a query beside the hole needs.

A query farther from the cloud than a few spacings (across a gap in the scan: an unscanned band, the
sparse end of a scan) is where the nearest samples mislead most: all k can lie on one face, whose plane
extended past the face's end puts the query on the wrong side. Such a query blends more samples from
a cloud thinned in step with its distance, so that they reach as far round it at any distance, with a
width in step too, and combines their faces at creases also where normals estimated with a widened
fit keep the mean near the cloud (see ``creases``): the mean of two faces' planes across a gap leaves a
fin along their bisector. Seeing that far round, it also sees through thin walls: a sample that a nearer
one's tangent plane hides from it does not count, and faces are told apart by their planes as well as
their normals (a tray's floor and its walls' rims are parallel), the largest first.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter
from scipy.spatial import cKDTree

from cam import CheckCancel

__all__ = ["band_vertices", "plane_distance"]

# Neighbours whose normals are within 30 deg of a face's reference sample's are on that face.
_SAME_FACE_COS = float(np.cos(np.radians(30.0)))
# A face counts fully from a tenth of the neighbours' facing weight (ramped from a twentieth), so that a
# stray sample with a turned normal is not a face; the neighbours on none of three faces likewise.
_MIN_FACE_SHARE = 0.1
# A crease counts fully as convex (concave) where the faces' centres lean below (above) each other's
# planes by over 0.3 (see _lean; ramped from 0.15): samples of one face with scattered normals are
# blended as before.
_CREASE_MARGIN = 0.15
# The two sides of a crease contradict each other where the weaker says the opposite by over a tenth of
# the centres' distance (ramped from a twentieth).
_CONTRADICTION = 0.05
# A query farther than six spacings from the cloud (see the module's docstring) blends 4k samples, with
# a Gaussian width of half its distance: the nearest of the cloud thinned to one sample a voxel, the
# voxel doubling with each doubling of the distance (k nearest put a fin 4 mm out of a convex crease of
# Fandisk with a 3 mm band unscanned).
_FAR_SPACINGS = 6.0
_FAR_K = 4
_FAR_WIDTH = 0.5
_FAR_THINNING = 3.0  # the thinned spacing, about a third of the query's distance
_OCCLUDERS = 16  # the nearest neighbours that may hide the others from a far query


def plane_distance(
    queries: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    *,
    spacing: float,
    k: int = 8,
    workers: int = 1,
    tree: cKDTree | None = None,
    max_distance: float = np.inf,
    creases: bool = True,
    check_cancel: CheckCancel | None = None,
) -> np.ndarray:
    """Blended point-to-tangent-plane distance: a signed distance estimate from oriented points.

    Parameters
    ----------
    queries : ndarray, shape (m, 3), float64
        Where to evaluate, the points' units.
    points, normals : ndarray, shape (n, 3), float64
        Samples and their unit outward normals.
    spacing : float
        Typical sample spacing, the points' units; the blending width (in distance beyond the
        nearest sample) is twice this, and so is the softening of the facing weight.
    k : int
        Nearest samples blended (a query over six spacings from the cloud: 4k of a thinned cloud).
    workers : int
        Threads for the k-NN queries.
    tree : cKDTree, optional
        A tree over ``points``, to reuse one the caller has.
    max_distance : float
        Only queries with a sample this close are answered; the rest get NaN. The
        bound makes the k-d tree prune, which matters for the many grid
        vertices far from the cloud (unbounded queries there cost ten times more).
        An answered query blends its ``k`` nearest samples however far they are.
    creases : bool
        Combine the faces of neighbours at creases (see the module's docstring); False: the
        blended planes within six spacings of the cloud (for normals whose fit spans a crease, whose
        planes are tilted there); farther out the faces are combined either way.
    check_cancel : callable, optional
        Called before each chunk of queries; it stops the work by raising.

    Returns
    -------
    ndarray, shape (m,), float64
        Signed distance (negative inside), the points' units; NaN where no sample is within
        ``max_distance``.
    """
    tree = tree if tree is not None else cKDTree(points)
    k = int(min(k, len(points)))
    k_far = int(min(_FAR_K * k, len(points)))
    levels = None
    out = np.empty(len(queries))
    width = 2.0 * spacing
    step = 65_536  # about a second per chunk on a busy core, so a cancel is seen promptly
    for start in range(0, len(queries), step):
        if check_cancel is not None:
            check_cancel()
        q = queries[start:start + step]
        near = np.ones(len(q), dtype=bool)
        if np.isfinite(max_distance):
            near = np.isfinite(tree.query(q, k=1, workers=workers, distance_upper_bound=max_distance)[0])
        # A query near the cloud blends its k nearest samples however far they are: bounding them too
        # would keep one face's samples and drop the other's beside an edge, and the plane left puts the
        # query on the wrong side (a shell of the wrong sign at the band's rim, half a mm out of an edge).
        qn = q[near]
        dist, idx = _nearest(tree, qn, k, workers)
        value = _blend(qn, dist, points[idx], normals[idx], np.full((len(qn), 1), width), creases)
        far = np.flatnonzero(dist[:, 0] > _FAR_SPACINGS * spacing)
        if len(far) and k_far > k:
            levels = levels if levels is not None else _thinned_levels(tree, points, spacing, k_far)
            value[far] = _blend_far(qn[far], dist[far, 0], levels, points, normals, spacing, k_far, workers)
        part = np.full(len(q), np.nan)
        part[near] = value
        out[start:start + step] = part
    return out


def _thinned_levels(tree, points, spacing, k):
    """The cloud, then thinned to one sample a voxel of 2, 4, 8, ... spacings (the sample nearest the
    voxel's centre) while at least 4k samples are left: a list of (tree, indices into ``points``)."""
    levels = [(tree, np.arange(len(points)))]
    size = 2.0 * spacing
    while True:
        cell = np.floor(points / size)
        off = np.linalg.norm(points - (cell + 0.5) * size, axis=1)
        ijk = (cell - cell.min(axis=0)).astype(np.int64)
        key = np.ravel_multi_index(ijk.T, tuple(ijk.max(axis=0) + 1))
        order = np.lexsort((off, key))
        _, first = np.unique(key[order], return_index=True)
        keep = np.sort(order[first])
        if len(keep) < 4 * k:
            return levels
        levels.append((cKDTree(points[keep]), keep))
        size *= 2.0


def _blend_far(q, near_dist, levels, points, normals, spacing, k, workers):
    """The estimate at queries farther than _FAR_SPACINGS from the cloud (q (m, 3), near_dist (m,) their
    nearest sample's distance): each from the k nearest samples of the level of ``levels`` (the full
    cloud, then thinned ones) whose spacing is about a third of its distance, faces combined at creases."""
    level = np.clip(np.floor(np.log2(near_dist / (_FAR_THINNING * spacing))).astype(np.int64), 0, len(levels) - 1)
    out = np.empty(len(q))
    step = 2048  # the faces' and hiding's (step, k, k) arrays stay within some tens of MB
    for j in np.unique(level):
        tree, keep = levels[j]
        radius = 2.0 * spacing * 2.0 ** j
        on_level = np.flatnonzero(level == j)
        for start in range(0, len(on_level), step):
            at = on_level[start:start + step]
            dist, idx = _nearest(tree, q[at], k, workers)
            nb_points, nb_normals = points[keep[idx]], normals[keep[idx]]
            hidden = _hidden(q[at], dist, nb_points, nb_normals, radius)
            width = np.maximum(radius, _FAR_WIDTH * dist[:, :1])
            out[at] = _blend(q[at], np.where(hidden, np.inf, dist), nb_points, nb_normals, width, True,
                             plane_tol=radius)
    return out


def _hidden(q, dist, nb_points, nb_normals, radius):
    """(m, k) bool: the neighbours a nearer one hides from the query, the line of sight to them crossing the
    nearer one's tangent plane within ``radius`` of it (q (m, 3), dist (m, k), nb_points and nb_normals
    (m, k, 3)). A far query sees both faces of a thin wall among its neighbours, and the far face's planes
    put a query in front of the wall inside it (the cavity of a tray with 2 mm walls filled). Only queries
    whose neighbours' planes disagree in sign are looked at: elsewhere hiding cannot change the side."""
    out = np.zeros(dist.shape, dtype=bool)
    plane = np.einsum("mkd,mkd->mk", q[:, None, :] - nb_points, nb_normals)
    at = np.flatnonzero((plane > 0.0).any(axis=1) & (plane < 0.0).any(axis=1))
    near = min(_OCCLUDERS, dist.shape[1])
    x = q[at].astype(np.float32)
    p, n = nb_points[at].astype(np.float32), nb_normals[at].astype(np.float32)
    pj, nj, front = p[:, :near], n[:, :near], plane[at, :near].astype(np.float32)  # q against plane j
    behind = np.einsum("mijd,mjd->mij", p[:, :, None, :] - pj[:, None, :, :], nj)  # sample i against plane j
    crosses = (np.sign(behind) == -np.sign(front[:, None, :])) & (dist[at, None, :near] < dist[at, :, None])
    t = front[:, None, :] / np.where(crosses, front[:, None, :] - behind, 1.0)
    hit = x[:, None, None, :] + t[..., None] * (p[:, :, None, :] - x[:, None, None, :])
    out[at] = (crosses & (np.linalg.norm(hit - pj[:, None, :, :], axis=-1) < radius)).any(axis=2)
    return out


def _nearest(tree, q, k, workers):
    dist, idx = tree.query(q, k=k, workers=workers)
    return (dist[:, None], idx[:, None]) if k == 1 else (dist, idx)


def _blend(q, dist, nb_points, nb_normals, width, creases, plane_tol=None):
    """The estimate at queries q (m, 3) from their neighbours (dist (m, k); nb_points, nb_normals
    (m, k, 3)) with Gaussian widths ``width`` (m, 1): the weighted mean of the planes, or with
    ``creases`` their faces combined where they meet at creases."""
    plane = np.einsum("mkj,mkj->mk", q[:, None, :] - nb_points, nb_normals)
    facing = (np.abs(plane) + width) / (dist + width)
    if creases:
        return _blend_across_creases(plane, dist, facing, nb_points, nb_normals, width, plane_tol)
    return _weighted(plane, dist, facing, np.ones(plane.shape, dtype=bool), width)[0]


def _blend_across_creases(plane, dist, facing, nb_points, nb_normals, width, plane_tol=None):
    """The weighted mean of the planes' distances, or where the neighbours lie on two or three faces
    meeting at creases, the faces' distances combined as the solid they bound: the larger of two at a
    convex crease, the smaller at a concave one, and at a corner of three the combination its three
    creases say (see _three_faces). Neighbours on more faces, or a crease of the two main faces neither
    clearly convex nor concave, keep the mean; so does a third face whose creases are unclear, except at
    far queries (``plane_tol`` given), where it keeps the two main faces' combination.

    plane, dist, facing: (m, k) signed plane distances, distances and facing weights; nb_points,
    nb_normals: (m, k, 3); width: (m, 1) the Gaussian weights' widths. Returns (m,).

    Each face's distance is its own samples' mean, weighted from its own nearest one, and a face counts
    by its share of the neighbours (by facing weight) however far beyond the nearest sample they are:
    beside a hole in one face's samples, that face is the one a query off it needs.
    """
    seen = np.isfinite(dist)
    blend, _ = _weighted(plane, dist, facing, seen, width)
    faces, rest = _split_faces(dist, nb_normals, nb_points, plane_tol)
    total = facing.sum(axis=1)
    share_b, share_c, share_rest = ((facing * f).sum(axis=1) / total for f in (*faces[1:], rest))
    # Most queries see one face (the rest below a twentieth of the weight) and keep the mean: only the
    # others pay for the faces' statistics (three times the mean's cost where all would).
    mixed = np.flatnonzero((_ramp(share_b) > 0.0) | (_ramp(share_c) > 0.0))
    out = blend.copy()
    if len(mixed):
        out[mixed] = _combine_faces(*(a[mixed] for a in (plane, dist, facing, nb_points, nb_normals, blend,
                                                          *faces, share_b, share_c, share_rest)), width[mixed],
                                    plane_tol is not None)
    return out


def _combine_faces(plane, dist, facing, nb_points, nb_normals, blend, face_a, face_b, face_c, share_b, share_c,
                   share_rest, width, far):
    """_blend_across_creases on the queries that see more than one face (each array cut to them); ``far``:
    the queries are far ones (see _blend_across_creases)."""
    stats = [_face(plane, dist, facing, f, nb_points, nb_normals, width) for f in (face_a, face_b, face_c)]
    (s_a, c_a, n_a), (s_b, c_b, n_b), (s_c, c_c, n_c) = stats
    lean_ab, lean_ac, lean_bc = (_lean(*x, *y, width[:, 0]) for x, y in (((c_a, n_a), (c_b, n_b)),
                                                                        ((c_a, n_a), (c_c, n_c)),
                                                                        ((c_b, n_b), (c_c, n_c))))
    two = _two_faces(s_a, s_b, lean_ab)
    three = _three_faces((s_a, s_b, s_c), (lean_ab, lean_ac, lean_bc))
    out = _toward(blend, two, _ramp(share_b) * _clarity(lean_ab))
    clear = np.minimum.reduce([_clarity(lean_ab), _clarity(lean_ac), _clarity(lean_bc)])
    # An unclear third face: near the cloud the mean (the two faces' combination left a 2 mm bracket's base
    # bulging 0.7 mm beside an edge at 0.1 % noise); a far query keeps the two main faces' combination, as
    # the mean of planes across a gap leaves a fin (see the module's docstring).
    fallback = out if far else blend
    out = _toward(out, _toward(fallback, three, clear), _ramp(share_c))
    return _toward(out, blend, _ramp(share_rest))


def _weighted(plane, dist, facing, mask, width):
    """The mean of the masked planes' distances, Gaussian-weighted by distance beyond the nearest masked
    sample and by facing; 0 where the mask is empty."""
    near = np.where(mask, dist, np.inf).min(axis=1, keepdims=True)
    w = np.where(mask, np.exp(-(dist - np.where(np.isfinite(near), near, 0.0)) ** 2 / width ** 2) * facing, 0.0)
    total = w.sum(axis=1)
    return (w * plane).sum(axis=1) / np.where(total > 0.0, total, 1.0), w


def _split_faces(dist, nb_normals, nb_points=None, plane_tol=None):
    """Up to three faces among the neighbours: those within 30 deg of the nearest one's normal, then of
    the nearest neighbour left, twice; (m, k) bool masks, and the mask of the neighbours left over.

    With ``plane_tol`` (far queries, which see much of the part): a face is the neighbours within 30 deg
    of a reference's normal and within ``plane_tol`` of its plane (a tray's floor and its walls' rims are
    parallel, not one face), the reference the neighbour with the most others left on its face, so that a
    few samples with turned normals take no face's place."""
    left = np.isfinite(dist)
    same = None
    if plane_tol is not None:
        unit, at = nb_normals.astype(np.float32), nb_points.astype(np.float32)
        offset = np.einsum("mkd,mkd->mk", at, unit)
        across = np.matmul(unit, at.transpose(0, 2, 1)) - offset[:, :, None]  # sample l against plane k
        same = ((np.matmul(unit, unit.transpose(0, 2, 1)) > _SAME_FACE_COS)
                & (np.abs(across) < plane_tol)).astype(np.float32)
    faces = []
    for _ in range(3):
        if same is not None:
            count = np.matmul(same, left[:, :, None].astype(np.float32))[:, :, 0]
            ref = np.argmax(np.where(left, count, -1.0), axis=1)
            face = left & (np.take_along_axis(same, ref[:, None, None], axis=1)[:, 0] > 0.0)
        else:
            ref = np.argmin(np.where(left, dist, np.inf), axis=1)
            n_ref = np.take_along_axis(nb_normals, ref[:, None, None], axis=1)[:, 0]
            face = left & (np.einsum("mkj,mj->mk", nb_normals, n_ref) > _SAME_FACE_COS)
        faces.append(face)
        left &= ~face
    return faces, left


def _face(plane, dist, facing, mask, nb_points, nb_normals, width):
    """A face's distance (see _weighted), centre (m, 3) and unit normal (m, 3)."""
    value, w = _weighted(plane, dist, facing, mask, width)
    total = w.sum(axis=1)
    centre = np.einsum("mk,mkj->mj", w, nb_points) / np.where(total > 0.0, total, 1.0)[:, None]
    normal = np.einsum("mk,mkj->mj", w, nb_normals)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    return value, centre, normal


def _lean(c_x, n_x, c_y, n_y, floor):
    """How two faces meet, from their centres and normals: negative across a convex crease (each face's
    samples below the other's plane), positive across a concave one (above), 0 where the two sides
    say opposite things clearly (a face that wraps round a corner of the other: its samples lie on the
    two sides of the other's plane).

    The measure is gap . (n_x - n_y), gap = c_y - c_x, as a share of |gap| |n_x - n_y|: samples hugging
    the crease on one side (their centre on the other's plane) still count through the other side's.
    """
    gap = c_y - c_x
    size = np.maximum(np.linalg.norm(gap, axis=1), floor)
    below_x = (gap * n_x).sum(axis=1) / size    # y's centre against x's plane
    below_y = -(gap * n_y).sum(axis=1) / size   # x's centre against y's plane
    lean = (below_x + below_y) / np.maximum(np.linalg.norm(n_x - n_y, axis=1), 0.5)
    contradiction = np.where(np.sign(below_x) != np.sign(below_y), np.minimum(np.abs(below_x), np.abs(below_y)),
                             0.0)
    return lean * (1.0 - np.clip((contradiction - _CONTRADICTION) / _CONTRADICTION, 0.0, 1.0))


def _clarity(lean):
    """0 where a crease is neither clearly convex nor concave, 1 from twice the margin."""
    return np.clip((np.abs(lean) - _CREASE_MARGIN) / _CREASE_MARGIN, 0.0, 1.0)


def _ramp(share):
    """How fully a face (or the neighbours on none of three) counts, by its share of the weight."""
    return np.clip(2.0 * share / _MIN_FACE_SHARE - 1.0, 0.0, 1.0)


def _toward(base, target, amount):
    return base + amount * (target - base)


def _two_faces(s_x, s_y, lean):
    return np.where(lean < 0.0, np.maximum(s_x, s_y), np.minimum(s_x, s_y))


def _three_faces(s, leans):
    """The three faces' distances combined by their creases' kinds (pairs ab, ac, bc, lean < 0 convex):
    the largest at a convex corner, the smallest at a concave one; where one crease differs from the
    other two, the face opposite it (c for ab, b for ac, a for bc) cuts the solid of that crease."""
    s_a, s_b, s_c = s
    convex = [lean < 0.0 for lean in leans]
    count = sum(c.astype(np.int64) for c in convex)
    pairs = ((s_a, s_b, s_c), (s_a, s_c, s_b), (s_b, s_c, s_a))
    one_concave = np.select([~c for c in convex], [np.maximum(np.minimum(x, y), z) for x, y, z in pairs])
    one_convex = np.select(convex, [np.minimum(np.maximum(x, y), z) for x, y, z in pairs])
    return np.select([count == 3, count == 2, count == 1],
                     [np.maximum.reduce([s_a, s_b, s_c]), one_concave, one_convex],
                     np.minimum.reduce([s_a, s_b, s_c]))


def band_vertices(points: np.ndarray, lo: np.ndarray, cell: float, dims: np.ndarray, band: float) -> np.ndarray:
    """Flat x-major indices (z fastest) of the lattice vertices that may lie within `band` of a point.

    The lattice's vertex (i, j, k) is at ``lo + cell * (i, j, k)``, `dims` (3,) vertices per axis. Every
    vertex within `band` of a point is among them (a superset: the cube around each point's cell, one
    cell wider than the band each way). `plane_distance` bounded by `band` finds no sample for any other
    vertex, and a query far from the cloud costs as much as one near it, so on a fine lattice, whose band
    around the cloud is a few per cent of its vertices, only these are worth asking.

    Parameters
    ----------
    points : ndarray, shape (n, 3), float64
    lo : ndarray, shape (3,), float64
    cell : float
        The lattice's spacing, the points' units.
    dims : ndarray, shape (3,), int
    band : float
        Distance, the points' units.

    Returns
    -------
    ndarray, shape (m,), int64, ascending.
    """
    dims = np.asarray(dims, dtype=np.int64)
    ijk = np.clip(np.floor((np.asarray(points, dtype=np.float64) - lo) / cell).astype(np.int64), 0, dims - 1)
    occupied = np.zeros(tuple(int(d) for d in dims), dtype=np.uint8)
    occupied[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = 1
    reach = int(np.ceil(band / cell)) + 1
    near = maximum_filter(occupied, size=2 * reach + 1, mode="constant", cval=0)
    return np.flatnonzero(near)
