"""Segmentation of a quad mesh into sharp height fields, end to end (the paper's MST method).

1. Setup base (:mod:`cam.segment.base`): k-means on face normals; its faces
   leave the segmentation domain when ``remove_base``.
2. Sharp edges (:mod:`cam.segment.sharp`): dihedral angle above θ.
3. Extraordinary points, their connection edges, auxiliary vertices, the
   weighted graph and its minimum spanning tree (:mod:`cam.segment.graph`).
4. Clipping edges in the paper's priority order: (1) the MST's edges, (2) sharp
   edges and boundaries, then (3–5) the lines that complete them — NF and
   redundant EP lines and extended sharp features, each run until it meets a
   clipping edge, shortest first (:mod:`cam.segment.clip`).
5. Patches between clipping edges, each checked as a rectangular grid
   (:mod:`cam.segment.patches`).

``method="motorcycle"`` replaces 3–4 by the motorcycle graph (the baseline);
``method="greedy"`` skips the MST (an ablation: completion only).

A quad mesh that cannot be segmented (quads that do not form a manifold,
consistently oriented mesh; nothing left once the base is removed) raises a
:class:`cam.GeometryError`. A patch that is no sharp height field is not
raised: it is returned, marked invalid, so that the caller can still show it.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field

import numpy as np

from cam import CheckCancel, GeometryError, Progress
from cam.mesh.quads import face_areas, face_normals, quad_topology
from cam.params import SegmentParams
from cam.segment.base import SetupBase, find_setup_base
from cam.segment.clip import CutState, complete_cuts, cut_open_cylinders, patch_labels
from cam.segment.graph import build_connection_graph
from cam.segment.motorcycle import motorcycle_cuts
from cam.segment.patches import PatchGrid, grid_of_patch
from cam.segment.sharp import find_sharp_edges
from cam.segment.traces import straight_continuation

__all__ = ["METHODS", "Patch", "Segmentation", "segment_quads"]

METHODS = ("mst", "greedy", "motorcycle")


@dataclass(frozen=True, eq=False, kw_only=True)
class Patch(PatchGrid):
    """One patch: its grid (`PatchGrid`'s fields, in the input quad mesh's face and vertex ids) and its place.

    Attributes
    ----------
    id
        Patch number (0-based, by lowest face index).
    sharp_sides
        Per side (bottom, right, top, left of the grid): all its edges are sharp.
    neighbors
        Ids of patches sharing a boundary edge.
    """

    id: int
    sharp_sides: tuple[bool, ...]
    neighbors: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class Segmentation:
    """The result of :func:`segment_quads`.

    Attributes
    ----------
    labels
        int64 (m,): patch id per face, -1 for base faces.
    patches
        The patches, by id.
    base
        The setup base and transform (computed even when not removed).
    base_faces
        int64 (b,): faces removed as the base (empty when ``remove_base`` is off).
    sharp_edges, cut_edges
        int64 (k, 2) vertex pairs: sharp edges of the mesh, and all clipping edges.
    extraordinary
        int64 (e,): the extraordinary points of the domain.
    stats
        JSON-ready counts and timings.
    """

    labels: np.ndarray
    patches: tuple[Patch, ...]
    base: SetupBase
    base_faces: np.ndarray
    sharp_edges: np.ndarray
    cut_edges: np.ndarray
    extraordinary: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def invalid(self) -> list[Patch]:
        return [p for p in self.patches if not p.valid]

    @property
    def ok(self) -> bool:
        return not self.invalid and self.stats.get("sharp_on_boundary", 0) == self.stats.get("sharp_in_domain", 0)


def _edge_keys(edges: np.ndarray, n: int) -> np.ndarray:
    return edges[:, 0].astype(np.int64) * n + edges[:, 1]


def segment_quads(
    vertices: np.ndarray,
    faces: np.ndarray,
    params: SegmentParams = SegmentParams(),
    *,
    progress: Progress | None = None,
    check_cancel: CheckCancel | None = None,
) -> Segmentation:
    """Segment a quad mesh into rectangular patches with every sharp edge on a patch boundary.

    Parameters
    ----------
    vertices
        float (n, 3), mm.
    faces
        int (m, 4), a manifold, consistently oriented quad mesh (as the
        remesh stage writes it).
    params
        The segment group:

        - ``sharp_angle_deg``: θ, dihedral angle above which an edge is sharp, in (0, 180).
        - ``remove_base``: remove the base faces from the domain.
        - ``mu``, ``gamma``: weights of S and Γ in the base objective (≥ 0).
        - ``sc``, ``nc``, ``ac``: graph weights SC (sharp edges), NC (NF edges), AC (auxiliary edges), > 0.
        - ``base_clusters``: k of the normal k-means, ≥ 1.
        - ``min_sharp_fragment_edges``: isolated sharp fragments with fewer edges are ignored.
        - ``method``: ``"mst"`` (the paper), ``"greedy"`` (no MST) or ``"motorcycle"`` (baseline).
        - ``seed``: seed of the k-means generator.
    progress
        ``progress(fraction, message)`` after each step.
    check_cancel
        Called after each step and from the long loops; what it raises propagates.

    Returns
    -------
    :class:`Segmentation`; check ``ok`` / ``invalid``: invalid patches are
    returned, not raised, so that the caller can still write them out.

    Raises
    ------
    ValueError
        For malformed arrays (shape, dtype, index range) or parameters out of range, naming what was seen.
    GeometryError
        When the quads are degenerate, non-manifold or inconsistently oriented, or when removing
        the base leaves nothing.
    """
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str, fraction: float) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = now - clock
        clock = now
        if progress is not None:
            progress(fraction, name)
        if check_cancel is not None:
            check_cancel()

    method = params.method
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    verts = np.asarray(vertices, dtype=np.float64)
    if verts.ndim != 2 or verts.shape[1] != 3 or not np.isfinite(verts).all():
        raise ValueError(f"vertices must be a finite (n, 3) array, got shape {verts.shape}")
    quads = np.asarray(faces)
    if quads.ndim != 2 or quads.shape[1] != 4 or len(quads) == 0:
        raise ValueError(f"faces must be a non-empty (m, 4) array of quads, got shape {quads.shape}")
    n = len(verts)
    # Shape, dtype and index range are the caller's; what quad_topology still rejects is the mesh itself.
    if quads.dtype.kind not in "iu":
        raise ValueError(f"faces must be an (m, 4) integer array, got shape {quads.shape} dtype {quads.dtype}")
    if quads.min() < 0 or quads.max() >= n:
        raise ValueError(f"faces index vertices {quads.min()}..{quads.max()} but there are {n}")
    try:
        topo = quad_topology(quads, n)
    except ValueError as exc:
        raise GeometryError(str(exc)) from exc
    quads = topo.faces
    normals = face_normals(verts, quads)
    areas = face_areas(verts, quads)
    sharp_full = find_sharp_edges(topo, normals, sharp_angle_deg=params.sharp_angle_deg,
                                  min_fragment_edges=params.min_sharp_fragment_edges)
    lap("sharp edges", 0.1)
    base = find_setup_base(verts, topo, normals, areas, sharp_full.sharp, clusters=params.base_clusters,
                           mu=params.mu, gamma=params.gamma, rng=np.random.default_rng(params.seed))
    keep = np.ones(len(quads), dtype=bool)
    if params.remove_base:
        keep[base.faces] = False
    if not keep.any():
        raise GeometryError("removing the base leaves no faces to machine; set segment.remove_base to false")
    lap("setup base", 0.2)

    domain = np.flatnonzero(keep)
    dtopo = quad_topology(quads[domain], n)
    full_keys = _edge_keys(topo.edges, n)
    dom_keys = _edge_keys(dtopo.edges, n)
    sharp = np.isin(dom_keys, full_keys[sharp_full.sharp])
    interior = (dtopo.face_count > 0) & ~dtopo.boundary_vertex
    extraordinary = interior & (dtopo.valence != 4)
    straight = straight_continuation(dtopo)
    stats: dict = {"method": method, "extraordinary_points": int(extraordinary.sum())}

    if method == "motorcycle":
        cut = motorcycle_cuts(dtopo, straight, extraordinary, sharp)
        lap("motorcycle graph", 0.7)
    else:
        initial = sharp.copy()
        if method == "mst":
            graph = build_connection_graph(dtopo, straight, verts, extraordinary, sharp, sc=params.sc, nc=params.nc,
                                           ac=params.ac)
            for i in graph.mst:
                initial[dtopo.edge_of[list(graph.edges[i].half_edges)]] = True
            kinds = [graph.edges[i].kind for i in graph.mst]
            stats.update({
                "graph_nodes": len(graph.nodes), "graph_edges": len(graph.edges),
                "connection_lines": graph.connections, "dropped_lines": graph.dropped_lines,
                "auxiliary_vertices": sum(1 for k, _ in graph.nodes if k == "aux"),
                "mst_edges": {k: kinds.count(k) for k in ("standard", "nf", "aux", "attach")},
            })
            lap("connection graph and MST", 0.45)
        state = CutState(dtopo, straight, verts, initial)
        lines = complete_cuts(state, check_cancel=check_cancel)
        cylinders = 0
        for _ in range(len(domain)):
            cut_now = cut_open_cylinders(state, check_cancel=check_cancel)
            if not cut_now:
                break
            cylinders += cut_now
            lines += complete_cuts(state, check_cancel=check_cancel)
        cut = state.cut
        stats.update({"completion_lines": lines, "cylinder_cuts": cylinders})
        lap("clipping edges", 0.7)

    labels_dom = patch_labels(dtopo, cut)
    n_patches = int(labels_dom.max()) + 1
    order = np.argsort(labels_dom, kind="stable")
    bounds = np.searchsorted(labels_dom[order], np.arange(n_patches + 1))
    grids = []
    for p in range(n_patches):
        grids.append(grid_of_patch(dtopo, cut, sharp, order[bounds[p]:bounds[p + 1]]))
        if check_cancel is not None and p % 256 == 0:
            check_cancel()
    # Neighbours: patches on the two sides of each interior clipping edge.
    ef = dtopo.edge_faces
    two = cut & (ef[:, 1] >= 0)
    pairs = np.unique(np.sort(np.stack([labels_dom[ef[two, 0]], labels_dom[ef[two, 1]]], axis=1), axis=1), axis=0)
    neighbors: list[set[int]] = [set() for _ in range(n_patches)]
    for a, b in pairs.tolist():
        if a != b:
            neighbors[a].add(b)
            neighbors[b].add(a)
    sharp_keys = set(dom_keys[sharp].tolist())
    patches = []
    for p, g in enumerate(grids):
        sharp_sides: tuple[bool, ...] = ()
        if g.valid:
            sharp_sides = tuple(
                all(min(a, b) * n + max(a, b) in sharp_keys for a, b in itertools.pairwise(s)) for s in g.sides()
            )
        patches.append(Patch(
            id=p, faces=domain[g.faces], rows=g.rows, cols=g.cols, corners=g.corners, grid=g.grid,
            face_grid=domain[g.face_grid] if g.valid else g.face_grid, sharp_sides=sharp_sides,
            neighbors=tuple(sorted(neighbors[p])), problems=g.problems,
        ))
    labels = np.full(len(quads), -1, dtype=np.int64)
    labels[domain] = labels_dom
    lap("patches", 0.95)

    on_boundary = int((sharp & cut).sum())
    stats.update({
        "patches": n_patches, "invalid_patches": sum(1 for p in patches if not p.valid),
        "faces": len(quads), "base_faces": int((~keep).sum()), "sharp_edges": int(sharp_full.sharp.sum()),
        "sharp_in_domain": int(sharp.sum()), "sharp_on_boundary": on_boundary,
        "sharp_fragments_dropped": sharp_full.dropped_edges, "clipping_edges": int(cut.sum()),
        "timings_s": timings,
    })
    return Segmentation(
        labels=labels, patches=tuple(patches), base=base, base_faces=np.flatnonzero(~keep).astype(np.int64),
        sharp_edges=topo.edges[sharp_full.sharp], cut_edges=dtopo.edges[cut],
        extraordinary=np.flatnonzero(extraordinary).astype(np.int64), stats=stats,
    )
