"""Restore the sharp edges that marching cubes bevels off (feature-sensitive extraction).

Marching cubes puts its vertices on lattice edges, and a field sampled on a
lattice of cell h is smooth across a crease over about one cell; so where two
faces of the part meet at an angle, the extracted mesh carries a bevel about h
wide whose normals lie between the two faces'. This module replaces the bevel
by the crease the two faces define, in the spirit of Kobbelt et al. 2001
("Feature sensitive surface extraction from volume data") and Attene et al.
2005 ("Sharpen & bend"): a face plane is fitted on each side from the flat
faces around the bevel, bevel vertices are moved to the nearest face plane, and
mesh edges that then cross from one plane to the other are split at the
crease, or, where one end lies next to the crease, that end is moved onto it.
Vertex moves keep the topology and edge splits are conforming, so a
watertight mesh stays watertight; the crease becomes a chain of mesh edges.

Smooth curvature is left alone: a vertex is only moved when exactly two
clusters of flat faces surround it, their planes meet at more than
``crease_deg`` and the vertex lies within one feature size of them. Where a
third face is in reach (an edge running into a corner), the two planes are
fitted from the faces nearer than the third's nearest, if they are flat, so an
edge is sharp up to a few cells from its corner; the corner itself (three
clusters among the nearest faces) keeps its bevel.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from cam import CheckCancel

__all__ = ["sharpen_creases"]

# Planes are fitted from the NEIGHBOURS flat faces nearest a vertex, one face per voxel of
# VOXEL feature sizes: thinning by space (not by the order marching cubes emits faces) keeps both
# sides of a crease represented and reaches about four feature sizes for the cost of 64 faces.
VOXEL = 0.75
NEIGHBOURS = 64
# An edge end closer to the crease than this share of the edge is moved onto it (not split next to it).
SNAP = 0.3
# A split's crease point lies within this share of the edge's length of its midpoint (see `_crease_points`).
NEAR = 0.6


def sharpen_creases(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    feature_size: float,
    flat_deg: float = 10.0,
    cluster_deg: float = 20.0,
    crease_deg: float = 30.0,
    reach: float = 8.0,
    workers: int = 1,
    check_cancel: CheckCancel | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Move bevel vertices onto the crease's face planes and split edges at the crease.

    Parameters
    ----------
    vertices : ndarray, shape (v, 3), float64
        Positions, any unit.
    faces : ndarray, shape (f, 3), int64
        Triangles, consistently wound.
    feature_size : float
        Width of the bevel to undo, in the vertices' units (the reconstruction
        passes the larger of the field's finest cell and two marching-cubes cells).
    flat_deg : float
        A face is flat when every face within ``feature_size`` of it has a
        normal within this angle (degrees) of its own; only flat faces fit planes.
    cluster_deg : float
        Flat faces around a vertex whose normals lie within this angle (degrees) form one plane.
    crease_deg : float
        Two planes meeting at less than this angle (degrees) are not a crease (the
        bench's sharp edges are those over 30 degrees).
    reach : float
        Flat faces up to this many feature sizes from a vertex may fit its planes:
        far enough that the field's rounding next to the crease does not tilt them.
    workers : int
        Threads for the k-NN queries.
    check_cancel : callable, optional
        Called between the phases (a few seconds apart on a million faces); it
        stops the work by raising.

    Returns
    -------
    vertices : ndarray, shape (v', 3), float64
        v' >= v: the first v vertices are the input's (some moved), the rest are
        crease points; the vertices' units.
    faces : ndarray, shape (f', 3), int64
        The triangles, split edges re-triangulated, same winding.
    report : dict
        ``moved`` vertices (onto a plane), ``split`` edges and vertices ``snapped`` onto a crease
        (ints).

    Raises
    ------
    ValueError
        When ``feature_size`` is not positive.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if not feature_size > 0:
        raise ValueError(f"feature_size must be positive, got {feature_size}")
    if len(faces) == 0:
        return verts.copy(), faces.copy(), {"moved": 0, "split": 0, "snapped": 0}
    check_cancel = check_cancel or (lambda: None)
    cross, area, normal, centre = _face_geometry(verts, faces)
    cos_flat = np.cos(np.radians(flat_deg))
    flat = _flat_faces(centre, normal, area, feature_size, cos_flat, workers)
    check_cancel()
    planes, on_a = _vertex_planes(verts, faces, centre, normal, area, flat, feature_size, reach * feature_size,
                                  np.cos(np.radians(cluster_deg)), np.cos(np.radians(crease_deg)), cos_flat, workers)
    check_cancel()
    new_verts, moved, moved_normal = _move_onto_planes(verts, faces, cross, planes)
    pn, pd = _carried_planes(faces, cross, new_verts, planes, on_a, moved)
    check_cancel()
    out_verts, out_faces, n_split, n_snapped = _split_crossing_edges(new_verts, faces, moved_normal, pn, pd, moved,
                                                                     np.cos(np.radians(crease_deg)))
    return out_verts, out_faces, {"moved": int(moved.sum()), "split": int(n_split), "snapped": int(n_snapped)}


def _face_geometry(verts, faces):
    """Per face: the edge cross product (f, 3), area (f,), unit normal (f, 3) and centroid (f, 3)."""
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(2.0 * area, 1e-300)[:, None]
    return cross, area, normal, tri.mean(axis=1)


def _flat_faces(centre, normal, area, radius, cos_flat, workers, k=32, chunk=100_000):
    """bool (f,): every face whose centroid is within ``radius`` has a normal within the flat angle."""
    tree = cKDTree(centre)
    flat = np.empty(len(centre), dtype=bool)
    # Chunks bound the (chunk, k, 3) neighbour normals (a million faces at once would take 800 MB).
    for start in range(0, len(centre), chunk):
        sl = slice(start, start + chunk)
        dist, idx = tree.query(centre[sl], k=min(k, len(centre)), distance_upper_bound=radius, workers=workers)
        valid = np.isfinite(dist)
        idx = np.where(valid, idx, 0)
        dots = np.einsum("fkc,fc->fk", normal[idx], normal[sl])
        flat[sl] = np.where(valid, dots >= cos_flat, True).all(axis=1)
    return flat & (area > 0)


def _vertex_planes(verts, faces, centre, normal, area, flat, size, reach, cos_cluster, cos_crease, cos_flat,
                   workers):
    """Per vertex: the two face planes around it and the nearest point of the sharp surface they bound.

    Returns a dict of arrays (na, da, nb, db, foot, ok) and bool (v,) ``on_a`` (the foot is on plane a).
    Only vertices of non-flat faces are examined; ``ok`` marks those that get moved.
    """
    nv = len(verts)
    out = {"na": np.zeros((nv, 3)), "nb": np.zeros((nv, 3)), "da": np.zeros(nv), "db": np.zeros(nv),
           "foot": verts.copy(), "ok": np.zeros(nv, dtype=bool)}
    on_a = np.zeros(nv, dtype=bool)
    cand_ids, flat_ids = _plane_candidates(nv, faces, centre, flat, size)
    if len(cand_ids) == 0 or len(flat_ids) < 2:
        return out, on_a
    valid, nbr = _flat_neighbours(verts[cand_ids], centre, flat_ids, reach, workers)
    n = normal[nbr]  # (m, k, 3), nearest first
    w = np.where(valid, area[nbr], 0.0)
    c = centre[nbr]
    in1, in2, good = _two_clusters(n, valid, cos_cluster, cos_crease, cos_flat)
    na, da, _ = _fit_plane(n, w, c, in1)
    nb, db, cb = _fit_plane(n, w, c, in2)
    good &= (na * nb).sum(1) <= cos_crease
    foot, choose_a, dmin = _crease_feet(verts[cand_ids], na, da, nb, db, cb)
    # A vertex farther than a feature size from both planes is on curvature, not on a bevel.
    good &= dmin <= size
    out["na"][cand_ids], out["da"][cand_ids] = na, da
    out["nb"][cand_ids], out["db"][cand_ids] = nb, db
    out["foot"][cand_ids] = foot  # read only where ok
    out["ok"][cand_ids] = good
    on_a[cand_ids] = choose_a
    return out, on_a


def _plane_candidates(n_verts, faces, centre, flat, size):
    """int ids of the vertices of non-flat faces, and of the flat faces that may fit planes."""
    cand = np.zeros(n_verts, dtype=bool)
    cand[faces[~flat].ravel()] = True
    flat_ids = np.flatnonzero(flat)
    _, one_per_voxel = np.unique(np.floor(centre[flat_ids] / (VOXEL * size)).astype(np.int64), axis=0,
                                 return_index=True)
    return np.flatnonzero(cand), flat_ids[np.sort(one_per_voxel)]


def _flat_neighbours(points, centre, flat_ids, reach, workers):
    """bool (m, k) found and int (m, k) face ids of the flat faces nearest each point, nearest first."""
    tree = cKDTree(centre[flat_ids])
    dist, j = tree.query(points, k=min(NEIGHBOURS, len(flat_ids)), distance_upper_bound=reach, workers=workers)
    valid = np.isfinite(dist)
    j = np.where(valid, j, 0)
    return valid, flat_ids[j]


def _two_clusters(n, valid, cos_cluster, cos_crease, cos_flat):
    """The neighbours (m, k) around the nearest one's normal and around the nearest other one's, and
    bool (m,): exactly these two clusters, with at least three faces each.

    Where a third cluster is among the neighbours and is one face at a crease to both (a corner a few
    feature sizes off), the clusters are taken again from the neighbours nearer than its first face alone,
    if both are flat: along a crease up to a corner, the two faces' planes are the nearest ones. A third
    cluster that is not one face (curvature the flat test let through) leaves the vertex alone."""
    in1, in2, good = _clusters_of(n, valid, cos_cluster)
    third = valid & ~in1 & ~in2
    first_third = np.where(third.any(1), third.argmax(1), valid.shape[1])  # neighbours are nearest first
    nearer = valid & (np.arange(valid.shape[1])[None, :] < first_third[:, None])
    near1, near2, near_good = _clusters_of(n, nearer, cos_cluster)
    # Only at a third face, not on curvature (a cylinder beside a plane, whose nearest facets would pass for a
    # second plane): the rest of the neighbours are one cluster of their own, at a crease to both planes.
    rows = np.arange(len(n))
    first = n[rows, np.minimum(first_third, valid.shape[1] - 1)]
    one_face = (~third | (np.einsum("mkc,mc->mk", n, first) >= cos_cluster)).all(1) & (third.sum(1) >= 3)
    for cluster in (near1, near2):
        mean = (n * cluster[:, :, None]).sum(1)
        mean /= np.maximum(np.linalg.norm(mean, axis=1), 1e-300)[:, None]
        one_face &= (mean * first).sum(1) <= cos_crease
        # Fewer faces fit these planes: each must be flat (a rounded edge's facets, 20 degrees apart, are not).
        one_face &= (~cluster | (np.einsum("mkc,mc->mk", n, mean) >= cos_flat)).all(1)
    retry = ~good & near_good & one_face
    return (np.where(retry[:, None], near1, in1), np.where(retry[:, None], near2, in2), good | retry)


def _clusters_of(n, valid, cos_cluster):
    """`_two_clusters` on the neighbours `valid` (m, k) as they are."""
    rows = np.arange(len(n))

    def first(mask):
        return mask.any(axis=1), mask.argmax(axis=1)

    has1, s1 = first(valid)
    in1 = valid & (np.einsum("mkc,mc->mk", n, n[rows, s1]) >= cos_cluster)
    has2, s2 = first(valid & ~in1)
    in2 = valid & ~in1 & (np.einsum("mkc,mc->mk", n, n[rows, s2]) >= cos_cluster)
    rest = valid & ~in1 & ~in2
    good = has1 & has2 & (in1.sum(1) >= 3) & (in2.sum(1) >= 3) & (rest.sum(1) <= 0.05 * valid.sum(1))
    return in1, in2, good


def _fit_plane(n, w, c, mask):
    """Area-weighted plane of the masked neighbours: unit normal (m, 3), offset (m,), centroid (m, 3)."""
    ww = w * mask
    nn = (n * ww[:, :, None]).sum(1)
    nn /= np.maximum(np.linalg.norm(nn, axis=1), 1e-300)[:, None]
    dd = (np.einsum("mkc,mc->mk", c, nn) * ww).sum(1) / np.maximum(ww.sum(1), 1e-300)
    cc = (c * ww[:, :, None]).sum(1) / np.maximum(ww.sum(1), 1e-300)[:, None]
    return nn, dd, cc


def _crease_feet(p, na, da, nb, db, cb):
    """The nearest point (m, 3) of the sharp surface two planes bound, bool (m,) it is on plane a, and
    its distance (m,)."""
    # Convex crease: each side's faces lie inside the other side's half-space (outward normals).
    convex = ((na * cb).sum(1) - da) < 0
    ga = (na * p).sum(1) - da
    gb = (nb * p).sum(1) - db
    foot_a = p - ga[:, None] * na
    foot_b = p - gb[:, None] * nb
    gb_at_a = (nb * foot_a).sum(1) - db
    ga_at_b = (na * foot_b).sum(1) - da
    sign = np.where(convex, 1.0, -1.0)
    valid_a = sign * gb_at_a <= 0
    valid_b = sign * ga_at_b <= 0
    da_dist = np.where(valid_a, np.abs(ga), np.inf)
    db_dist = np.where(valid_b, np.abs(gb), np.inf)
    choose_a = da_dist <= db_dist
    foot = np.where(choose_a[:, None], foot_a, foot_b)
    return foot, choose_a, np.minimum(da_dist, db_dist)


def _move_onto_planes(verts, faces, cross, planes):
    """Vertices moved to their feet, bool (v,) moved, and the moved faces' cross products (f, 3)."""
    moved = planes["ok"].copy()
    new_verts = verts.copy()
    new_verts[moved] = planes["foot"][moved]
    # (Several bevel vertices landing on the same plane out of order turn faces over.)
    return _undo_turning_moves(verts, new_verts, faces, cross, moved)


def _undo_turning_moves(verts, new_verts, faces, cross, moved):
    """The moves of the vertices `moved` (v,) from `verts` to `new_verts` (v, 3), less those that turn a
    face over against its cross product `cross` (f, 3) or squash it to under a hundredth of its area (two
    ends landing together); returns the vertices, bool (v,) still moved and the faces' new cross products.
    Undoing can turn a neighbour, hence the rounds (each undoes at least one move, so they end)."""
    moved = moved.copy()
    while True:
        t = new_verts[faces]
        moved_normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        flipped = (moved_normal * cross).sum(1) <= 0.01 * (cross * cross).sum(1)
        back = np.zeros(len(verts), dtype=bool)
        back[faces[flipped].ravel()] = True
        back &= moved
        if not back.any():
            return new_verts, moved, moved_normal
        moved &= ~back
        new_verts[back] = verts[back]


def _carried_planes(faces, cross, new_verts, planes, on_a, moved):
    """The plane each vertex now lies on: unit normal (v, 3) and offset (v,).

    The chosen crease side for moved vertices, the vertex's own tangent plane (area-weighted
    normal) for the rest.
    """
    vnormal = np.zeros_like(new_verts)
    for k in range(3):
        np.add.at(vnormal, faces[:, k], cross)
    vnormal /= np.maximum(np.linalg.norm(vnormal, axis=1), 1e-300)[:, None]
    pn = vnormal
    pd = (vnormal * new_verts).sum(axis=1)
    side_n = np.where(on_a[:, None], planes["na"], planes["nb"])
    side_d = np.where(on_a, planes["da"], planes["db"])
    pn[moved] = side_n[moved]
    pd[moved] = side_d[moved]
    return pn, pd


def _split_crossing_edges(verts, faces, face_normal, pn, pd, moved, cos_crease):
    """Split every edge whose ends lie on planes meeting at a crease, at the crease; re-triangulate.

    An edge is a candidate when at least one end was moved and the ends' planes meet at more than
    the crease angle. Where an end lies next to their crease line, that end is moved onto the line
    (`_snap_near_ends`) and the edge stays whole: a split there would leave a sliver, and an end
    left where it was keeps the crease off its vertex, a notch that turns the crease's edge chain
    aside (on a 50k-point Fandisk cloud, hundreds of spurs and branches that QuadriFlow's sharp
    edges then followed). The other candidates are split at the point of the crease line nearest
    their midpoint, where that point lies within `NEAR` of the edge's length of it (`_crease_points`)
    and between a tenth and nine tenths along. Faces whose children would turn against the parent's
    normal keep their edges whole (and so do their neighbours across those edges).

    Returns the vertices (the input's, some snapped, then the split points), the faces, the number
    of edges split and of vertices snapped.
    """
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(e, axis=1)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(3, -1).T  # (f, 3): edge id of (v0v1, v1v2, v2v0)
    a, b = uniq[:, 0], uniq[:, 1]
    cand = (moved[a] | moved[b]) & ((pn[a] * pn[b]).sum(1) <= cos_crease)
    snapped = np.zeros(len(verts), dtype=bool)
    todo, reach = cand, SNAP
    # First the ends within SNAP of an edge's length of the crease; then, once more, an end of each split
    # refused for a child left flat or turned over, wherever along the edge: the crease point lies on
    # the line through that end and a neighbour (a lattice line parallel to the face, where a box's
    # edge passes a quarter of a cell from the lattice), so the end itself belongs on the crease.
    for last in (False, True):
        length = np.linalg.norm(verts[b[todo]] - verts[a[todo]], axis=1)
        verts, more, face_normal = _snap_near_ends(verts, faces, face_normal, a[todo], b[todo], pn, pd,
                                                   moved & ~snapped, reach * length)
        snapped |= more
        # An edge with a snapped end needs no split: the crease already runs through that end.
        cand &= ~(snapped[a] | snapped[b])
        point, along, near = _crease_points(verts, a, b, pn, pd)
        tried = cand & near & (along > 0.1) & (along < 0.9)
        split, new_faces, all_verts = _split_whole_faces(verts, faces, inverse, face_normal, tried, point)
        todo, reach = tried & ~split, 1.0
        if last or not todo.any():
            return all_verts, new_faces, int(split.sum()), int(snapped.sum())


def _split_whole_faces(verts, faces, inverse, face_normal, split, point):
    """The edges `split` (e,) that can be split at `point` (e, 3) without turning a child face over, the
    faces (f', 3) and vertices (v', 3) with them split."""
    split = split.copy()
    while True:  # each round removes at least one split, so the rounds end
        new_faces, parent = _triangulate(faces, inverse, split, len(verts))
        all_verts = np.concatenate([verts, point[split]])
        t = all_verts[new_faces]
        child = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        # A child turned over, or one under a thousandth of its parent (the split point landed on
        # the line through an end that already sat on the crease), keeps its parent's edges whole.
        bad = (child * face_normal[parent]).sum(1) <= 1e-3 * (face_normal[parent] ** 2).sum(1)
        bad &= split[inverse].any(axis=1)[parent]  # an unsplit face is as the moves left it
        if not bad.any():
            return split, new_faces, all_verts
        split[inverse[np.unique(parent[bad])].ravel()] = False


def _crease_points(verts, a, b, pn, pd):
    """Per edge (a, b) (k,): the point (k, 3) of its ends' planes' crease line nearest its midpoint, where
    that point falls along the edge (k,) (0 at a, 1 at b) and bool (k,) it lies near enough to the
    edge to split it there (within `NEAR` of its length of the midpoint)."""
    mid = 0.5 * (verts[a] + verts[b])
    point = _nearest_on_line(mid, pn[a], pd[a], pn[b], pd[b])
    length = np.linalg.norm(verts[b] - verts[a], axis=1)
    along = ((point - verts[a]) * (verts[b] - verts[a])).sum(1) / np.maximum(length**2, 1e-300)
    # The crease point sees the edge at the crease's inside angle: within the circle over the edge (half
    # its length from the midpoint) for 90 degrees or more, on it for a right angle, the commonest
    # crease, where a bound of half the length kept or refused the split by rounding alone. Six tenths
    # pass inside angles down to about 80 degrees, room for the planes' error at a right angle (on the
    # Fandisk cloud's mesh, half the length left 648 loose ends in its sharp-edge graph, six tenths 280).
    # Wider bounds let splits through farther from the edge: abc3's Hausdorff distance grew with them
    # (0.0088 of the diagonal at 0.6, 0.0092 at 0.75, 0.0096 at 1).
    return point, along, np.linalg.norm(point - mid, axis=1) <= NEAR * length


def _nearest_on_line(p, na, da, nb, db):
    """Nearest point (k, 3) to each p (k, 3) on the line {na.x = da, nb.x = db}: p - [na nb] G^-1 [ga gb],
    G the Gram matrix of the unit normals."""
    cosab = (na * nb).sum(1)
    ga = (na * p).sum(1) - da
    gb = (nb * p).sum(1) - db
    det = np.maximum(1.0 - cosab**2, 1e-12)
    ca = (ga - cosab * gb) / det
    cb = (gb - cosab * ga) / det
    return p - ca[:, None] * na - cb[:, None] * nb


def _snap_near_ends(verts, faces, face_normal, a, b, pn, pd, moved, reach):
    """Move an end of each edge (a, b) (k,) that lies next to its ends' crease line onto that line.

    A moved end (on a crease side's plane, not a tangent plane of its own) within `reach` (k,) of the
    line of its own plane and the other end's goes to its nearest point there (within its own plane,
    so the faces it shares with that plane stay on it); of an edge's two ends the nearer, and a
    vertex next to several lines takes its shortest move. A move that turns a face over or squashes
    it is undone (`_undo_turning_moves`). Returns the vertices, bool (v,) snapped and the faces' cross
    products (f, 3) after the moves.
    """
    snapped = np.zeros(len(verts), dtype=bool)
    to_a = _nearest_on_line(verts[a], pn[a], pd[a], pn[b], pd[b])
    to_b = _nearest_on_line(verts[b], pn[b], pd[b], pn[a], pd[a])
    da = np.where(moved[a], np.linalg.norm(to_a - verts[a], axis=1), np.inf)
    db = np.where(moved[b], np.linalg.norm(to_b - verts[b], axis=1), np.inf)
    # Ends as near as each other (vertices of a lattice as far from both faces) go by their planes, so
    # that along one crease the same side moves: alternating sides would leave faces across it.
    tie = np.abs(da - db) <= 1e-9 * np.maximum(reach, 1e-300)
    side = np.array([1.0, 0.618, 0.382])
    pick_a = np.where(tie, pn[a] @ side >= pn[b] @ side, da < db)
    end, target, dist = np.where(pick_a, a, b), np.where(pick_a[:, None], to_a, to_b), np.minimum(da, db)
    ok = dist <= reach
    end, target, dist = end[ok], target[ok], dist[ok]
    if not len(end):
        return verts, snapped, face_normal
    order = np.lexsort((dist, end))
    first = order[np.r_[True, end[order][1:] != end[order][:-1]]]  # each vertex's shortest move
    new_verts = verts.copy()
    new_verts[end[first]] = target[first]
    snapped[end[first]] = True
    return _undo_turning_moves(verts, new_verts, faces, face_normal, snapped)


def _triangulate(faces, inverse, split, n_verts):
    """Faces with their split edges' midpoints inserted; returns (faces, parent face of each)."""
    new_id = np.full(len(split), -1, dtype=np.int64)
    new_id[split] = n_verts + np.arange(int(split.sum()))
    m = new_id[inverse]  # (f, 3): new vertex on edge (v0v1, v1v2, v2v0) or -1
    s = m >= 0
    count = s.sum(1)
    out, parent = [], []
    fid = np.arange(len(faces))

    keep = count == 0
    out.append(faces[keep])
    parent.append(fid[keep])
    for r in range(3):
        # Rotate each face so that its split pattern starts at edge r.
        f = np.roll(faces, -r, axis=1)
        mm = np.roll(m, -r, axis=1)
        ss = np.roll(s, -r, axis=1)
        v0, v1, v2 = f[:, 0], f[:, 1], f[:, 2]
        m01, m12 = mm[:, 0], mm[:, 1]
        one = (count == 1) & ss[:, 0]
        out.append(np.stack([v0, m01, v2], 1)[one])
        out.append(np.stack([m01, v1, v2], 1)[one])
        parent += [fid[one]] * 2
        two = (count == 2) & ss[:, 0] & ss[:, 1]
        out.append(np.stack([m01, v1, m12], 1)[two])
        out.append(np.stack([v0, m01, m12], 1)[two])
        out.append(np.stack([v0, m12, v2], 1)[two])
        parent += [fid[two]] * 3
    three = count == 3
    f, mm = faces[three], m[three]
    out += [np.stack([f[:, 0], mm[:, 0], mm[:, 2]], 1), np.stack([mm[:, 0], f[:, 1], mm[:, 1]], 1),
            np.stack([mm[:, 2], mm[:, 1], f[:, 2]], 1), mm]
    parent += [fid[three]] * 4
    return np.concatenate(out), np.concatenate(parent)
