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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from cam import CheckCancel, GeometryError, Progress
from cam.mesh.quads import QuadTopology, face_areas, face_normals, quad_topology
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
        int (m, 4) vertex indices: a manifold, consistently oriented quad mesh (as the
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
    Segmentation
        ``labels`` int64 (m,) patch per face (-1 on the base), the patches, the base, and int64 index arrays
        of the base faces, sharp and clipping edges and extraordinary points; check ``ok`` / ``invalid``:
        invalid patches are returned, not raised, so that the caller can still write them out.

    Raises
    ------
    ValueError
        For malformed arrays (shape, dtype, index range, non-finite coordinates), naming what was seen.
    GeometryError
        When the quads are degenerate, non-manifold or inconsistently oriented, or when removing
        the base leaves nothing.
    """
    timings: dict[str, float] = {}
    lap = _lap_timer(timings, progress, check_cancel)
    verts, topo = _checked_mesh(vertices, faces)
    normals = face_normals(verts, topo.faces)
    sharp_full = find_sharp_edges(topo, normals, sharp_angle_deg=params.sharp_angle_deg,
                                  min_fragment_edges=params.min_sharp_fragment_edges)
    lap("sharp edges", 0.1)
    base, keep = _find_base(verts, topo, normals, sharp_full.sharp, params)
    lap("setup base", 0.2)
    dom = _domain(topo, keep, sharp_full.sharp)
    stats: dict = {"method": params.method, "extraordinary_points": int(dom.extraordinary.sum())}
    cut, cut_stats = _clipping_edges(dom, verts, params, lap=lap, check_cancel=check_cancel)
    stats.update(cut_stats)
    labels_dom, patches = _read_patches(dom, cut, check_cancel=check_cancel)
    labels = np.full(len(topo.faces), -1, dtype=np.int64)
    labels[dom.faces] = labels_dom
    lap("patches", 0.95)
    stats.update({
        "patches": len(patches), "invalid_patches": sum(1 for p in patches if not p.valid),
        "faces": len(topo.faces), "base_faces": int((~keep).sum()), "sharp_edges": int(sharp_full.sharp.sum()),
        "sharp_in_domain": int(dom.sharp.sum()), "sharp_on_boundary": int((dom.sharp & cut).sum()),
        "sharp_fragments_dropped": sharp_full.dropped_edges, "clipping_edges": int(cut.sum()),
        "timings_s": timings,
    })
    return Segmentation(
        labels=labels, patches=tuple(patches), base=base, base_faces=np.flatnonzero(~keep).astype(np.int64),
        sharp_edges=topo.edges[sharp_full.sharp], cut_edges=dom.topo.edges[cut],
        extraordinary=np.flatnonzero(dom.extraordinary).astype(np.int64), stats=stats,
    )


class _Domain(NamedTuple):
    """The faces left to segment once the base is removed, with their own connectivity."""

    faces: np.ndarray  # int64 (k,): their ids in the whole mesh
    topo: QuadTopology  # their connectivity (same vertex ids)
    sharp: np.ndarray  # bool (ne,): sharp edges, indexed like topo.edges
    extraordinary: np.ndarray  # bool (n,): interior vertices of valence other than 4
    straight: np.ndarray  # int64 (4k,): straight continuation of each half-edge, or -1
    edge_keys: np.ndarray  # int64 (ne,): a * n + b of each edge (a, b) of topo.edges


def _edge_keys(edges: np.ndarray, n: int) -> np.ndarray:
    return edges[:, 0].astype(np.int64) * n + edges[:, 1]


def _lap_timer(timings: dict[str, float], progress: Progress | None,
               check_cancel: CheckCancel | None) -> Callable[[str, float], None]:
    """``lap(name, fraction)``: record the seconds since the previous lap under ``name`` in ``timings``,
    report ``fraction`` to ``progress`` and give the caller's ``check_cancel`` its chance to stop."""
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

    return lap


def _checked_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, QuadTopology]:
    """float64 (n, 3) vertices and the quads' connectivity; ValueError or GeometryError as segment_quads says."""
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
        return verts, quad_topology(quads, n)
    except ValueError as exc:
        raise GeometryError(str(exc)) from exc


def _find_base(verts: np.ndarray, topo: QuadTopology, normals: np.ndarray, sharp: np.ndarray,
               params: SegmentParams) -> tuple[SetupBase, np.ndarray]:
    """The setup base, and bool (m,) the faces left to segment (all but the base when it is removed).

    Raises GeometryError when removing the base leaves nothing.
    """
    areas = face_areas(verts, topo.faces)
    base = find_setup_base(verts, topo, normals, areas, sharp, clusters=params.base_clusters,
                           mu=params.mu, gamma=params.gamma, rng=np.random.default_rng(params.seed))
    keep = np.ones(len(topo.faces), dtype=bool)
    if params.remove_base:
        keep[base.faces] = False
    if not keep.any():
        raise GeometryError("removing the base leaves no faces to machine; set segment.remove_base to false")
    return base, keep


def _domain(topo: QuadTopology, keep: np.ndarray, sharp: np.ndarray) -> _Domain:
    """The faces ``keep`` marks as a domain of their own, its sharp edges carried over from ``topo``'s."""
    n = topo.n_vertices
    domain = np.flatnonzero(keep)
    dtopo = quad_topology(topo.faces[domain], n)
    dom_keys = _edge_keys(dtopo.edges, n)
    dom_sharp = np.isin(dom_keys, _edge_keys(topo.edges, n)[sharp])
    interior = (dtopo.face_count > 0) & ~dtopo.boundary_vertex
    extraordinary = interior & (dtopo.valence != 4)
    return _Domain(domain, dtopo, dom_sharp, extraordinary, straight_continuation(dtopo), dom_keys)


def _clipping_edges(dom: _Domain, verts: np.ndarray, params: SegmentParams, *, lap: Callable[[str, float], None],
                    check_cancel: CheckCancel | None) -> tuple[np.ndarray, dict]:
    """bool (ne,): the clipping edges of ``params.method``, and the counts to report."""
    if params.method == "motorcycle":
        cut = motorcycle_cuts(dom.topo, dom.straight, dom.extraordinary, dom.sharp)
        lap("motorcycle graph", 0.7)
        return cut, {}
    initial, stats = dom.sharp.copy(), {}
    if params.method == "mst":
        initial, stats = _mst_cuts(dom, verts, params)
        lap("connection graph and MST", 0.45)
    state = CutState(dom.topo, dom.straight, verts, initial)
    lines, cylinders = _complete(state, n_faces=len(dom.faces), check_cancel=check_cancel)
    stats.update({"completion_lines": lines, "cylinder_cuts": cylinders})
    lap("clipping edges", 0.7)
    return state.cut, stats


def _mst_cuts(dom: _Domain, verts: np.ndarray, params: SegmentParams) -> tuple[np.ndarray, dict]:
    """bool (ne,): the sharp edges and those of the connection graph's spanning forest, and the graph's counts."""
    graph = build_connection_graph(dom.topo, dom.straight, verts, dom.extraordinary, dom.sharp, sc=params.sc,
                                   nc=params.nc, ac=params.ac)
    initial = dom.sharp.copy()
    for i in graph.mst:
        initial[dom.topo.edge_of[list(graph.edges[i].half_edges)]] = True
    kinds = [graph.edges[i].kind for i in graph.mst]
    return initial, {
        "graph_nodes": len(graph.nodes), "graph_edges": len(graph.edges),
        "connection_lines": graph.connections, "dropped_lines": graph.dropped_lines,
        "auxiliary_vertices": sum(1 for k, _ in graph.nodes if k == "aux"),
        "mst_edges": {k: kinds.count(k) for k in ("standard", "nf", "aux", "attach")},
    }


def _complete(state: CutState, *, n_faces: int, check_cancel: CheckCancel | None) -> tuple[int, int]:
    """Complete the cuts, then cut open cylinders and complete again until none is left.

    Returns the completion lines and the cylinder cuts added; ``n_faces`` caps the rounds (each round adds
    clipping edges, so the cap is a safety net, never the end in practice).
    """
    lines = complete_cuts(state, check_cancel=check_cancel)
    cylinders = 0
    for _ in range(n_faces):
        cut_now = cut_open_cylinders(state, check_cancel=check_cancel)
        if not cut_now:
            break
        cylinders += cut_now
        lines += complete_cuts(state, check_cancel=check_cancel)
    return lines, cylinders


def _read_patches(dom: _Domain, cut: np.ndarray, *,
                  check_cancel: CheckCancel | None) -> tuple[np.ndarray, list[Patch]]:
    """int64 (k,) patch id of each domain face, and the patches (ids of the whole mesh) in id order."""
    labels = patch_labels(dom.topo, cut)
    n_patches = int(labels.max()) + 1
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(n_patches + 1))
    grids = []
    for p in range(n_patches):
        grids.append(grid_of_patch(dom.topo, cut, dom.sharp, order[bounds[p]:bounds[p + 1]]))
        if check_cancel is not None and p % 256 == 0:
            check_cancel()
    neighbors = _patch_neighbors(dom.topo, cut, labels, n_patches)
    sharp_keys = set(dom.edge_keys[dom.sharp].tolist())
    n = dom.topo.n_vertices
    patches = []
    for p, g in enumerate(grids):
        sharp_sides: tuple[bool, ...] = ()
        if g.valid:
            sharp_sides = tuple(
                all(min(a, b) * n + max(a, b) in sharp_keys for a, b in itertools.pairwise(s)) for s in g.sides()
            )
        patches.append(Patch(
            id=p, faces=dom.faces[g.faces], rows=g.rows, cols=g.cols, corners=g.corners, grid=g.grid,
            face_grid=dom.faces[g.face_grid] if g.valid else g.face_grid, sharp_sides=sharp_sides,
            neighbors=tuple(sorted(neighbors[p])), problems=g.problems,
        ))
    return labels, patches


def _patch_neighbors(topo: QuadTopology, cut: np.ndarray, labels: np.ndarray, n_patches: int) -> list[set[int]]:
    """Per patch, the patches on the other side of its interior clipping edges."""
    ef = topo.edge_faces
    two = cut & (ef[:, 1] >= 0)
    pairs = np.unique(np.sort(np.stack([labels[ef[two, 0]], labels[ef[two, 1]]], axis=1), axis=1), axis=0)
    neighbors: list[set[int]] = [set() for _ in range(n_patches)]
    for a, b in pairs.tolist():
        if a != b:
            neighbors[a].add(b)
            neighbors[b].add(a)
    return neighbors
