"""The setup base: k-means on face normals picks the face group the part rests on; the tool axis points away.

Face normals are points on the unit sphere. Spherical k-means (area-weighted,
k-means++ seeding from the caller's generator) groups them into ``k``
clusters with mean directions c. A base must be one contiguous face, so each
cluster is represented by its largest piece P (by area) of faces connected
across non-sharp edges, and

- S (similarity) = Σ_{f∈P} a_f (n_f · c) / Σ_{f∈P} a_f, the area-weighted mean
  cosine between the piece's normals and the cluster direction, in [-1, 1]
  (1: all parallel, a flat face);
- Γ (quantity) = Σ_{f∈P} a_f / Σ_f a_f, the piece's share of the part's area,
  in [0, 1];
- ε = μ·S + γ·Γ (the paper's μ = 0.7, γ = 0.3).

The piece of largest ε is the base; objectives within 0.1 % are a tie, which
the cluster facing most towards -z of the part frame wins (a part is usually
scanned resting on its base, and a closed part's up- and down-facing areas
are equal, so ties are common). The tool axis is the opposite of the base's
mean normal. The setup transform rotates the tool axis onto machine +Z, then
shifts the part so that its lowest point is at z = 0 and its bounding box is
centred on x = y = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cam.mesh.quads import QuadTopology

__all__ = ["SetupBase", "find_setup_base", "setup_transform", "spherical_kmeans"]

#: Objectives this close (relative) are a tie: remeshing noise must not decide between a part's top and bottom.
_TIE = 1e-3


@dataclass(frozen=True, eq=False)
class SetupBase:
    """The chosen base and the setup it defines.

    Attributes
    ----------
    faces
        int64 (b,): base faces (empty when the base is not removed).
    tool_axis
        float64 (3,): unit tool axis in the part frame (away from the base).
    rotation, translation
        float64 (3, 3) and (3,): machine point = rotation · part point + translation.
    clusters
        Per cluster: ``direction``, ``similarity`` S, ``quantity`` Γ,
        ``objective`` ε, ``faces`` (in its largest piece), ``cluster_faces``; JSON-ready.
    chosen
        Index of the base cluster in ``clusters``.
    """

    faces: np.ndarray
    tool_axis: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    clusters: tuple[dict, ...]
    chosen: int


def spherical_kmeans(points: np.ndarray, weights: np.ndarray, k: int, rng: np.random.Generator,
                     iterations: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """Weighted k-means of unit vectors under cosine similarity, seeded k-means++ style.

    Parameters
    ----------
    points
        float (n, 3) unit vectors.
    weights
        float (n,) positive weights (face areas, mm²).
    k
        Clusters wanted; at most n are made.
    rng
        Generator for the seeding.
    iterations
        Most assignment rounds.

    Returns
    -------
    labels : ndarray
        int64 (n,) cluster of each point.
    centres : ndarray
        float64 (k', 3) unit mean directions, k' ≤ k (clusters that end up empty are dropped and the
        labels renumbered).
    """
    n = len(points)
    k = max(1, min(k, n))
    # k-means++ seeding on 1 - cos, weighted by area so tiny faces do not grab centres.
    centres = [points[rng.choice(n, p=weights / weights.sum())]]
    for _ in range(1, k):
        d = np.maximum(1.0 - points @ np.asarray(centres).T, 0.0).min(axis=1) * weights
        if d.sum() <= 0:
            break
        centres.append(points[rng.choice(n, p=d / d.sum())])
    c = np.asarray(centres)
    labels = np.zeros(n, dtype=np.int64)
    for it in range(iterations):
        new = np.argmax(points @ c.T, axis=1)
        if it and np.array_equal(new, labels):
            break
        labels = new
        sums = np.zeros_like(c)
        np.add.at(sums, labels, points * weights[:, None])
        norms = np.linalg.norm(sums, axis=1)
        keep = norms > 0
        c = np.where(keep[:, None], sums / np.where(keep, norms, 1.0)[:, None], c)
    used = np.unique(labels)
    remap = np.full(len(c), -1)
    remap[used] = np.arange(len(used))
    return remap[labels], c[used]


def setup_transform(vertices: np.ndarray, tool_axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation taking ``tool_axis`` to +Z and the translation that puts the part on z = 0, centred in x and y.

    Parameters
    ----------
    vertices
        float (n, 3), mm: the part.
    tool_axis
        float (3,), any length: the tool axis in the part frame.

    Returns
    -------
    rotation : ndarray
        float64 (3, 3).
    translation : ndarray
        float64 (3,), mm: machine point = rotation · part point + translation.
    """
    t = np.asarray(tool_axis, dtype=np.float64)
    t = t / np.linalg.norm(t)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(t, z)
    s, c = np.linalg.norm(v), float(t @ z)
    if s < 1e-12:
        rot = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # half turn about x
    else:
        k = v / s
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rot = np.eye(3) + s * kx + (1 - c) * kx @ kx  # Rodrigues
    p = np.asarray(vertices) @ rot.T
    lo, hi = p.min(axis=0), p.max(axis=0)
    return rot, np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])


def find_setup_base(
    vertices: np.ndarray,
    topo: QuadTopology,
    normals: np.ndarray,
    areas: np.ndarray,
    sharp: np.ndarray,
    *,
    clusters: int,
    mu: float,
    gamma: float,
    rng: np.random.Generator,
) -> SetupBase:
    """Pick the base cluster and its base faces (see the module docstring for S, Γ and ε).

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    topo
        Connectivity of the whole quad mesh.
    normals
        float (m, 3) unit face normals.
    areas
        float (m,) face areas, mm².
    sharp
        bool (ne,): sharp edges of ``topo``; base faces do not connect across them.
    clusters
        k of the k-means (≥ 1, as :class:`cam.params.SegmentParams` holds it).
    mu, gamma
        Weights of S and Γ (≥ 0, as the group holds them).
    rng
        Generator for the k-means seeding.

    Returns
    -------
    SetupBase
        The base faces int64 (b,) (sorted), the unit tool axis float64 (3,), the setup rotation float64
        (3, 3) and translation float64 (3,) mm, and each cluster's figures.
    """
    weights = np.maximum(areas, 1e-300)
    labels, centres = spherical_kmeans(normals, weights, clusters, rng)
    total = weights.sum()
    # Pieces of each cluster: faces of one cluster joined across non-sharp interior edges.
    ef = topo.edge_faces
    m = len(normals)
    link = (ef[:, 1] >= 0) & ~sharp
    link &= labels[ef[:, 0]] == labels[np.maximum(ef[:, 1], 0)]
    graph = coo_matrix((np.ones(int(link.sum())), (ef[link, 0], ef[link, 1])), shape=(m, m))
    _, piece = connected_components(graph, directed=False)
    piece_area = np.bincount(piece, weights=weights)
    info = []
    candidates = []
    for j, c in enumerate(centres):
        members = np.flatnonzero(labels == j)
        largest = members[np.argmax(piece_area[piece[members]])]
        faces = members[piece[members] == piece[largest]]
        w = weights[faces]
        similarity = float((w * (normals[faces] @ c)).sum() / w.sum())
        quantity = float(w.sum() / total)
        candidates.append(faces)
        info.append({"direction": c.tolist(), "similarity": similarity, "quantity": quantity,
                     "objective": mu * similarity + gamma * quantity, "faces": len(faces),
                     "cluster_faces": len(members)})
    best = max(e["objective"] for e in info)
    tied = [j for j, e in enumerate(info) if e["objective"] >= best - _TIE * max(abs(best), 1.0)]
    chosen = min(tied, key=lambda j: centres[j][2])
    base_faces = candidates[chosen]
    mean = (normals[base_faces] * weights[base_faces, None]).sum(axis=0)
    axis = -mean / np.linalg.norm(mean)
    rot, trans = setup_transform(vertices[np.unique(topo.faces)], axis)
    return SetupBase(faces=np.sort(base_faces).astype(np.int64), tool_axis=axis, rotation=rot, translation=trans,
                     clusters=tuple(info), chosen=int(chosen))
