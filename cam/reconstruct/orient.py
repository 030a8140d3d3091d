"""Which way out the normals of a cloud point: the space around the cloud, and a spanning tree along it.

The side of each point is first asked of the space the cloud leaves empty around it
(:mod:`cam.reconstruct.outside`): points whose side that decides seed a tree, and the rest take the side of
the seed the tree reaches them from. Where the scan has a gap the outside leaks into, the votes contradict
each other and the tree orients alone, as before them (:func:`orient_outward` says when).

The tree follows Hoppe et al. (1992): a minimum spanning tree over the k-NN graph whose edge weights are
small where neighbouring tangent planes agree, walked from a seed (the point farthest from its component's
centroid). Each step copies the parent's side. The walk is linear in the number of points whatever the
shape, so a perfectly planar sample (where all weights tie) costs no more than a curved one. Which side is
out is then settled for a component without votes by the divergence theorem: over a closed surface the
outward normals' flux of (p - centroid) is three times the enclosed volume, so positive (the seed's own
normal is no guide where the seed is a corner).

Copying the parent's side is only right between two samples of the same sheet of the surface. Across a thin
wall or a narrow gap (the two faces of a 2 mm web, a boss 2 mm above a floor) the neighbourhoods of a noisy
cloud reach the opposite face, whose tangent plane is parallel but whose outward side is the other one:
Hoppe's weight calls such a pair a perfect match, and a tree that takes it flips the whole face behind it
(half of a 2 mm-walled bracket at 0.25 % noise came out inside out). So an edge also pays for how far its
two points lie from each other's tangent plane, measured against the gap a sheet of this noise can show
(:func:`cam.reconstruct.normals.estimate_normals` measures it): the tree then crosses to the opposite face
only where no path along the surface exists. On walls thinner than a neighbourhood (0.7-1 mm at a 60 mm
diagonal) that was not enough: a tree copied round their rims, where plane fits are poor, turned half the
part inside out (abc8, abc9 of the bench corpus; MeshLab's orientation fails alike), which the votes mend.

A gap in the scan (an unscanned band) cuts the surface into pieces, and two rules keep a piece's side:
a pair of neighbours over three sheet gaps from each other's planes is no edge of the tree (across a band,
one such pair over a rib's two faces was the only link between a ribbed plate's halves, and half the plate
came out inside out); and a piece the votes do not settle takes the side of the surface it continues
across the gap, the divergence theorem only where it continues none (a blind hole's bottom, cut off by a
band, bounds no volume: its flux said inward).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import (
    breadth_first_order,
    connected_components,
    minimum_spanning_tree,
)
from scipy.spatial import cKDTree

from cam import GeometryError
from cam.reconstruct.outside import outside_votes

__all__ = ["NormalsError", "orient_normals", "orient_outward"]

# Above this share of confidently parallel neighbour pairs that still point opposite ways
# after orientation, the cloud has no consistent inside (or is too sparse for its shape).
_MAX_FLIPPED_SHARE = 0.02

# Below this share of points with an outside vote, or above this share of neighbour pairs on one sheet
# whose votes contradict each other, the outside has leaked in through a gap in the scan and the votes are
# not used (see orient_outward).
_MIN_VOTED_SHARE = 0.8
_MAX_VOTE_DISAGREEMENT = 0.05
# The tree's orientation, where the votes' failed its check, must agree with this share of the votes: a tree
# that turned the walls of a thin part agreed with 0.53 of them (abc8, abc9 at sigma 0.3 mm); otherwise the
# disagreement is the votes' own, at slots narrower than the barrier (abc1, abc5: 0.83-0.97).
_MIN_TREE_AGREEMENT = 0.75
# A component cut off by a gap takes its side from the settled points among each member's 8 nearest that
# continue its sheet (normals within 30 deg; see _side_across_gap).
_GAP_NEIGHBOURS = 8
# Neighbour pairs over three sheet gaps from each other's tangent planes are on two sheets and no edge of the
# tree, unless that would leave a piece of under 1 % of the points apart (see _sheet_edges).
_MAX_EDGE_GAPS = 3.0
_MIN_PIECE_SHARE = 0.01
_SAME_SHEET_COS = float(np.cos(np.radians(30.0)))


class NormalsError(GeometryError):
    """Given normals are broken or estimated ones cannot be oriented; the message says what to do."""


def orient_outward(points: np.ndarray, normals: np.ndarray, idx: np.ndarray, dist: np.ndarray,
                   sheet_gap: float) -> tuple[np.ndarray, dict]:
    """Turn unoriented normals outward: by the outside votes where they hold, else by the tree alone.

    Parameters
    ----------
    points, normals, idx, dist, sheet_gap
        As for :func:`orient_normals` (``sheet_gap`` finite: the offset from a tangent plane beyond which a
        neighbour is on another sheet, the points' units).

    Returns
    -------
    normals : ndarray, shape (n, 3), float64
        The input normals, some negated.
    report : dict
        ``components``, ``flipped_share``, ``orientation`` ("outside": by the votes of the space around
        the cloud; "tree": by the tree alone), ``outside_voted_share`` (the points that space gave a vote),
        ``outside_votes_disagree`` (the share of neighbour pairs on one sheet whose votes contradict), and
        ``outside_agreement`` where the tree's orientation was checked against the votes.

    Raises
    ------
    NormalsError
        When the orientation leaves more than 2 % of nearly parallel neighbour pairs on one sheet pointing
        opposite ways (a non-orientable or badly undersampled cloud; the two faces of a thin wall point
        opposite ways by right and are not counted), or when the votes are credible, their orientation
        fails that check and the tree's contradicts them on over a quarter of the voted points.

    A gap in the scan wider than the barrier lets the outside in: most points then see it on both sides
    and get no vote, and the votes cast contradict each other (a 2.4 mm band missing: 63-70 % voted, 10-12 %
    of the pairs contradicting; a box with its top unscanned: 10 % voted, and the few wrong ones turned
    whole subtrees). Where the barrier held, 88 % or more voted and at most 3 % of the pairs contradicted
    (8 % on 0.7 mm walls at the bench's heaviest noise). A barrier that leaks a little leaves a region of
    wrong votes that pass both tests; the voted orientation then fails the flipped-share check, and the
    tree's is taken if it agrees with three votes in four (a tree that contradicts the outside more often has
    turned a wall inside out: refused).
    """
    votes, outside = outside_votes(points, normals, neighbour_dist=dist)
    # Which pairs are on one sheet and parallel does not depend on the normals' signs: found once.
    dots, parallel = _parallel_pairs(points, normals, idx, sheet_gap)
    voted = votes != 0
    both = parallel & voted[:, None] & voted[idx]
    disagree = float(np.sum(both & (votes[:, None] * votes[idx] * dots < 0)) / max(both.sum(), 1))
    report = {"orientation": "tree", "outside_voted_share": round(outside["decided_share"], 4),
              "outside_votes_disagree": round(disagree, 4)}
    credible = outside["decided_share"] >= _MIN_VOTED_SHARE and disagree <= _MAX_VOTE_DISAGREEMENT
    if credible:
        oriented, components = orient_normals(points, normals, idx, dist, sheet_gap=sheet_gap, votes=votes)
        share = _flipped_share(oriented, idx, parallel)
        if share <= _MAX_FLIPPED_SHARE:
            return oriented, {**report, "components": components, "flipped_share": share, "orientation": "outside"}
    oriented, components = orient_normals(points, normals, idx, dist, sheet_gap=sheet_gap)
    if credible:
        sides = np.sign(np.einsum("ij,ij->i", oriented[voted], normals[voted]))
        agree = float(np.mean(sides == votes[voted]))
        report["outside_agreement"] = round(agree, 4)
        if agree < _MIN_TREE_AGREEMENT:
            raise NormalsError(
                f"the estimated normals cannot be oriented consistently: along the surface {1 - agree:.0%} of "
                "the points face the other way from the space around them, and taken from that space they "
                "contradict their neighbours (walls too thin for this noise?); upload oriented normals or a "
                "less noisy scan"
            )
    share = _flipped_share(oriented, idx, parallel)
    if share > _MAX_FLIPPED_SHARE:
        raise NormalsError(
            f"the estimated normals cannot be oriented consistently ({share:.0%} of neighbouring "
            "points still face opposite ways): the cloud is non-orientable, very noisy or too sparse "
            "for its thin parts; upload oriented normals or a denser scan"
        )
    return oriented, {**report, "components": components, "flipped_share": share}


def _flipped_share(normals: np.ndarray, idx: np.ndarray, parallel: np.ndarray) -> float:
    """The share of the ``parallel`` neighbour pairs (n, k) bool whose normals face opposite ways."""
    dots = np.einsum("ij,ikj->ik", normals, normals[idx])
    return float(np.sum((dots < -0.7) & parallel) / max(parallel.sum(), 1))


def _parallel_pairs(points: np.ndarray, normals: np.ndarray, idx: np.ndarray, sheet_gap: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Each neighbour pair's normal dot product (n, k), and which pairs are surely on one sheet and parallel.

    Half the sheet gap, not all of it: the two faces of a wall only a little thicker than the gap (0.7 mm
    walls at 0.25 % noise, gap 0.47 mm) have an eighth of their pairs within the gap by noise, and such pairs
    face opposite ways by right.
    """
    dots = np.einsum("ij,ikj->ik", normals, normals[idx])
    return dots, (np.abs(dots) > 0.7) & (_plane_offsets(points, normals, idx) < 0.5 * sheet_gap)


def _plane_offsets(points: np.ndarray, normals: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(n, k) mean distance of each neighbour pair from the other's tangent plane, the points' units."""
    out = np.empty(idx.shape)
    step = 200_000  # bounds the (chunk, k, 3) temporaries
    for start in range(0, len(points), step):
        sl = slice(start, start + step)
        e = points[idx[sl]] - points[sl, None, :]
        out[sl] = 0.5 * (np.abs(np.einsum("nj,nkj->nk", normals[sl], e))
                         + np.abs(np.einsum("nkj,nkj->nk", normals[idx[sl]], e)))
    return out


def orient_normals(
    points: np.ndarray, normals: np.ndarray, idx: np.ndarray, dist: np.ndarray, *, sheet_gap: float = np.inf,
    votes: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Flip normals to one consistent side along a minimum spanning tree of the k-NN graph.

    Parameters
    ----------
    points : ndarray, shape (n, 3), float64
        Positions, any unit.
    normals : ndarray, shape (n, 3), float64
        Unit normals of either sign.
    idx : ndarray, shape (n, k), integer dtype
        Each point's k nearest neighbours, self excluded.
    dist : ndarray, shape (n, k), float64
        Their distances, the points' units.
    sheet_gap : float
        The points' units. A pair's weight grows by (offset / sheet_gap)^2, the
        offset being the mean distance of each point from the other's tangent
        plane: beyond one sheet_gap that alone outweighs the worst disagreement
        of two tangent planes (1 - |cos| <= 1), so the tree only crosses a thin
        wall or gap where no path along the surface connects the two sides.
        inf: Hoppe's weight.
    votes : ndarray, shape (n,), integer dtype, optional
        +1 / -1 where a point's normal is known to point out / in, 0 where not
        (:func:`cam.reconstruct.outside.outside_votes`). Voted points take their side
        from the vote and seed the tree (each hangs from one root by an edge of no
        weight); the rest take the side of the voted point the tree reaches them
        from. A component with no vote is seeded and settled as without votes.

    Returns
    -------
    normals : ndarray, shape (n, 3), float64
        The input normals, some negated.
    components : int
        Components of the neighbour graph (each is seeded on its own).
    """
    n, k = idx.shape
    rows = np.repeat(np.arange(n), k)
    cols = idx.reshape(-1)
    dots = np.abs(np.einsum("ij,ij->i", normals[rows], normals[cols]))
    # The distance term breaks ties on planar regions (all dots 1) and keeps every weight
    # strictly positive: scipy's sparse graphs read a zero weight as a missing edge.
    scale = float(np.median(dist[:, 0])) or 1.0
    weight = (1.0 - dots) + 1e-3 * dist.reshape(-1) / scale + 1e-9
    if np.isfinite(sheet_gap):
        offsets = _plane_offsets(points, normals, idx).reshape(-1)
        weight = weight + (offsets / sheet_gap) ** 2
        keep = _sheet_edges(offsets / sheet_gap, rows, cols, n)
        rows, cols, weight = rows[keep], cols[keep], weight[keep]
    out = normals.copy()
    count, labels = connected_components(coo_matrix((weight, (rows, cols)), shape=(n, n)), directed=False)
    voted = np.zeros(0, dtype=np.int64) if votes is None else np.flatnonzero(votes)
    if len(voted):
        out[voted] *= votes[voted, None]
        # The root (node n, a zero normal, so each child keeps the side it has) makes the voted points
        # one tree's first level; 1e-12 because scipy's sparse graphs read a zero weight as no edge.
        rows = np.concatenate([rows, np.full(len(voted), n)])
        cols = np.concatenate([cols, voted])
        weight = np.concatenate([weight, np.full(len(voted), 1e-12)])
        out = np.vstack([out, np.zeros((1, 3))])
    size = len(out)
    graph = coo_matrix((weight, (rows, cols)), shape=(size, size)).tocsr()
    graph = graph.maximum(graph.T)
    tree = minimum_spanning_tree(graph)
    tree = tree + tree.T
    if len(voted):
        order, pred = breadth_first_order(tree, n, directed=False, return_predecessors=True)
        _propagate(out, order, pred)
        out = out[:n]
    area = dist[:, -1] ** 2  # about each point's share of the surface (k points within that radius)
    settled = np.isin(labels, labels[voted])
    unvoted = [np.flatnonzero(labels == comp) for comp in np.setdiff1d(np.arange(count), labels[voted])]
    for members in sorted(unvoted, key=len, reverse=True):
        centre = points[members].mean(axis=0)
        # The walk starts at the point farthest from the centre; its side is settled below with the rest.
        seed = members[np.argmax(np.linalg.norm(points[members] - centre, axis=1))]
        order, pred = breadth_first_order(tree, seed, directed=False, return_predecessors=True)
        _propagate(out, order, pred)
        # A piece cut off by a gap in the scan takes the side of the surface it continues across the gap;
        # only where it continues none is the flux below asked: a blind hole's bottom cut off by a band
        # bounds no volume, and its outward normals (into the hole) have a negative flux (the chamfered
        # cylinder of bench/reconstruct.py: its hole's bottom turned inside out, a 6 mm cavity round it).
        side = _side_across_gap(points, out, members, np.flatnonzero(settled), sheet_gap)
        if side == 0.0:
            # The seed's own normal can mislead: the farthest point is often a corner, where the plane fit
            # blends the faces (a 40 x 40 mm prism at 0.1 % noise: every normal came out inward). Over a
            # closed surface the outward normal's flux of (p - centre) is three times the volume, so its
            # sign, summed over the component with each point's share of the area, settles which side is out.
            side = np.sign(np.sum(area[members] * np.einsum("ij,ij->i", out[members], points[members] - centre)))
        if side < 0:
            out[members] = -out[members]
        settled[members] = True
    return out, count


def _sheet_edges(gaps: np.ndarray, rows: np.ndarray, cols: np.ndarray, n: int) -> np.ndarray:
    """Which neighbour pairs (``rows``, ``cols``; ``gaps`` their plane offsets in sheet gaps) are edges of the
    tree: those within _MAX_EDGE_GAPS sheet gaps, and every pair of a point that would otherwise lie in a
    piece of under _MIN_PIECE_SHARE of the points (stray points and small clusters keep their neighbours).

    Where a gap in the scan cuts the surface in two, a pair across a thin wall can be the only link left
    between the pieces (the bench's ribs with a band unscanned: one pair 2.6 mm apart, across a 3 mm rib's
    two faces, and the tree turned half the part inside out through it); cut, the pieces are settled apart
    (see _side_across_gap)."""
    keep = gaps < _MAX_EDGE_GAPS
    _, piece = connected_components(coo_matrix((np.ones(int(keep.sum())), (rows[keep], cols[keep])), shape=(n, n)),
                                    directed=False)
    small = (np.bincount(piece) < _MIN_PIECE_SHARE * n)[piece]
    return keep | small[rows] | small[cols]


def _side_across_gap(points: np.ndarray, normals: np.ndarray, members: np.ndarray, settled: np.ndarray,
                     sheet_gap: float) -> float:
    """+1 / -1: whether the normals of ``members`` (a component, indices into ``points``) agree with those of
    the ``settled`` points (indices) that continue their sheets across the gap between them, or disagree;
    0 where none does, or no side has over three quarters of the weight.

    A pair continues a sheet where its normals lie within 30 deg and the settled point lies within a fifth
    of their distance (plus ``sheet_gap`` where finite) of the member's tangent plane; pairs count by
    (nearest pair's distance / their distance)^2, so the rims facing each other across the gap decide."""
    if not len(settled):
        return 0.0
    dist, j = cKDTree(points[settled]).query(points[members], k=min(_GAP_NEIGHBOURS, len(settled)))
    dist, j = dist.reshape(len(members), -1), j.reshape(len(members), -1)
    other = settled[j]
    dots = np.einsum("mj,mkj->mk", normals[members], normals[other])
    offset = np.abs(np.einsum("mj,mkj->mk", normals[members], points[other] - points[members, None, :]))
    slack = sheet_gap if np.isfinite(sheet_gap) else 0.0
    weight = np.where((np.abs(dots) > _SAME_SHEET_COS) & (offset < 0.2 * dist + slack),
                      (dist.min() / np.maximum(dist, 1e-300)) ** 2, 0.0)
    total = weight.sum()
    vote = float(np.sum(weight * np.sign(dots)))
    return float(np.sign(vote)) if total > 0.0 and abs(vote) > 0.5 * total else 0.0


def _propagate(normals: np.ndarray, order: np.ndarray, pred: np.ndarray) -> None:
    """Give every node the side of its parent, in breadth-first order (parents come first)."""
    child = order[1:]
    parent = pred[child]
    # sign relative to the parent as estimated; the absolute sign is the product along the path.
    rel = np.sign(np.einsum("ij,ij->i", normals[child], normals[parent]))
    rel[rel == 0] = 1.0
    sign = np.ones(len(normals))
    position = np.empty(len(normals), dtype=np.int64)
    position[order] = np.arange(len(order))
    parent_pos = position[parent]
    # A loop in BFS order is the simple exact form; 1e6 nodes take well under a second in
    # numpy-free Python only if kept scalar, so this runs over plain lists.
    rel_l = rel.tolist()
    ppos = parent_pos.tolist()
    signs = [1.0] * len(order)
    for i in range(1, len(order)):
        signs[i] = signs[ppos[i - 1]] * rel_l[i - 1]
    sign[order] = np.asarray(signs)
    normals[order[1:]] *= sign[order[1:], None]
