"""The crease-first quad layout: every crease a chain of quad edges by construction.

1. The creases are found and cut into chains at their corners; spurs are dropped (:mod:`cam.remesh.features`).
2. A coarse triangle mesh, edges about ``coarse_quads`` quads long, is remeshed from the part with the chains
   kept as edge paths (:mod:`cam.remesh.coarse`).
3. Its triangles are paired into quads, never across a crease (:mod:`cam.remesh.pairing`).
4. Every face is split into quads about its centre, and quad edges are rotated towards valence four
   (:mod:`cam.remesh.coarsequads`).
5. Each coarse edge gets a count of quad edges such that neighbouring grids meet (:mod:`cam.remesh.quantize`).
6. Each coarse quad becomes a grid on the part's surface; a crease's points are put on the crease
   (:mod:`cam.remesh.subdivide`).

The result is pure quads and closed wherever the part is; its extraordinary vertices are the coarse quads'.
"""

from __future__ import annotations

import time

import numpy as np

from cam import CheckCancel, GeometryError, Progress
from cam.remesh.chains import Chain, points_at
from cam.remesh.coarse import CoarseMesh, coarse_triangulation, edge_table
from cam.remesh.coarsequads import rotate_to_valence, split_into_quads
from cam.remesh.features import CreaseFeatures, find_crease_features
from cam.remesh.pairing import pair_triangles
from cam.remesh.quantize import quantize_edge_counts
from cam.remesh.subdivide import QuadLayout, subdivide_layout

__all__ = ["crease_first_layout"]

# Creases: gentle ones over this angle count where they run on for two quads; a chain that turns by more than
# `_CORNER_TURN_DEG` within half a quad has a corner there (the values `cam.remesh.snap` uses).
_GENTLE_ANGLE_DEG = 35.0
_CORNER_TURN_DEG = 40.0
# A crease's quad edges are chords that stay within this share of the part's diagonal of it (three quarters of
# the tolerance of issue 35's crease recall).
_CHORD = 0.0015
# A coarse collapse stops where the merged planes lie farther than this share of the target edge from the vertex.
_COARSE_ERROR = 0.05


def crease_first_layout(vertices: np.ndarray, triangles: np.ndarray, *, target_faces: int, coarse_quads: float,
                        crease_angle_deg: float = 50.0,
                        progress: Progress | None = None, check_cancel: CheckCancel | None = None
                        ) -> tuple[QuadLayout, dict]:
    """A quad layout of a closed triangle mesh whose edges follow its creases.

    Parameters
    ----------
    vertices : (n, 3) float64
        The part's vertices, mm.
    triangles : (m, 3) int64
        Its triangles: a closed manifold surface, counter-clockwise seen from outside.
    target_faces : int
        Quads aimed for; the quad size is the square root of the part's area over it.
    crease_angle_deg : float
        Edges whose faces' normals differ by more than this are creases, degrees.
    coarse_quads : float
        The coarse mesh's edge length in quads: fewer coarse vertices (fewer extraordinary vertices) the longer.
    progress, check_cancel
        The stage callbacks (`cam`'s convention).

    Returns
    -------
    layout : QuadLayout
    report : dict
        JSON-ready: the quad size and the coarse edges' (mm, and in quads), counts of each step (chains, spurs
        and thin-region chains dropped, regions, coarse vertices, triangles, pairs, triangles left unpaired,
        coarse quads, rotations) and the seconds of each step.

    Raises
    ------
    GeometryError
        When the part has no area.
    """
    times: dict[str, float] = {}
    clock = time.monotonic()

    def lap(name: str, fraction: float, message: str) -> None:
        nonlocal clock
        times[name] = time.monotonic() - clock
        clock = time.monotonic()
        if check_cancel is not None:
            check_cancel()
        if progress is not None:
            progress(fraction, message)

    tv = np.asarray(vertices, dtype=np.float64)
    tf = np.asarray(triangles, dtype=np.int64)
    p = tv[tf]
    area = 0.5 * float(np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())
    if not area > 0:
        raise GeometryError("the mesh has no area: no quad layout can be made")
    quad_mm = float(np.sqrt(area / target_faces))
    coarse_mm = coarse_quads * quad_mm
    if progress is not None:
        progress(0.0, "finding the creases")
    features = find_crease_features(tv, tf, crease_angle_deg=crease_angle_deg, gentle_angle_deg=_GENTLE_ANGLE_DEG,
                                    corner_turn_deg=_CORNER_TURN_DEG, quad_mm=quad_mm)
    lap("features_s", 0.1, "a coarse mesh along the creases")
    mesh = coarse_triangulation(features, edge_mm=coarse_mm, min_edge_mm=2.0 * quad_mm, error_share=_COARSE_ERROR,
                                check_cancel=check_cancel)
    coarse_vertices, coarse_triangles = len(mesh.V), len(mesh.F)
    lap("coarse_s", 0.5, "pairing its triangles")
    quads, pairs = pair_triangles(mesh.V, mesh.F, set(mesh.result().crease_edges()))
    unpaired = np.ones(len(mesh.F), dtype=bool)
    unpaired[pairs.ravel()] = False
    split_into_quads(mesh, quads, mesh.region[pairs[:, 0]], mesh.F[unpaired], mesh.region[unpaired])
    mesh.relax()
    rotations = rotate_to_valence(mesh)
    coarse = mesh.result()
    lap("coarse_quads_s", 0.7, "counting quads along the coarse edges")
    edges, counts = _edge_counts(coarse, features, quad_mm, _CHORD * float(np.linalg.norm(np.ptp(tv, axis=0))))
    lap("quantize_s", 0.75, "filling the coarse quads")
    layout = subdivide_layout(coarse, features, edges, counts)
    lap("subdivide_s", 1.0, "done")
    report = {
        "layout": "creases", "quad_mm": quad_mm, "coarse_edge_mm": coarse_mm, "crease_chains": len(features.chains),
        "spurs_dropped": features.spurs_dropped, "spur_length_mm": features.spur_length_mm,
        "thin_dropped": features.thin_dropped, "thin_length_mm": features.thin_length_mm,
        "regions": int(features.face_region.max()) + 1, "coarse_vertices": coarse_vertices,
        "coarse_triangles": coarse_triangles, "coarse_pairs": len(quads), "coarse_unpaired": int(unpaired.sum()),
        "coarse_edge_quads": coarse_quads, "coarse_quad_count": len(coarse.faces), "coarse_rotations": rotations,
        **times,
    }
    return layout, report


def _edge_counts(coarse: CoarseMesh, features: CreaseFeatures, quad_mm: float, chord_mm: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The coarse quads' edges (sorted vertex pairs, (e, 2)) and the quad edges each is cut into
    (`quantize_edge_counts`): a crease edge is as long as its chain between its ends, and is cut into enough
    pieces that their chords stay within ``chord_mm`` of the chain."""
    edges, _ = edge_table(coarse.faces)
    lengths = np.linalg.norm(coarse.vertices[edges[:, 0]] - coarse.vertices[edges[:, 1]], axis=1)
    creases = coarse.crease_edges()
    fewest = np.ones(len(edges), dtype=np.int64)
    for i, key in enumerate(map(tuple, edges.tolist())):
        if key in creases:
            chain, arc_a, arc_b = creases[key]
            lengths[i] = abs(arc_b - arc_a)
            fewest[i] = _pieces_for_chords(features.chains[chain], arc_a, arc_b, chord_mm, quad_mm)
    return edges, quantize_edge_counts(edges, lengths, coarse.faces, edge_mm=quad_mm, min_counts=fewest)


def _pieces_for_chords(chain: Chain, arc_a: float, arc_b: float, chord_mm: float, quad_mm: float) -> int:
    """The fewest equal pieces of the chain between arc lengths ``arc_a`` and ``arc_b`` (mm) whose chords stay
    within ``chord_mm`` of it, but no more than half as many again as pieces a quad long (rounded: an edge under
    two thirds of a quad long is one piece).

    A chain rougher than half of ``chord_mm`` (its points that far from their mean with the points a quarter quad
    before and after: a reconstructed crease zigzags along the mesh's edges) is a curve only at a coarser scale,
    and no count of pieces follows its zigzag: there the sagitta over the whole edge sets the count, as over a
    steady curve (it falls with the square of the pieces).
    """
    lo, hi = sorted((arc_a, arc_b))
    inside = (chain.arc > lo) & (chain.arc < hi)
    if not inside.any():
        return 1
    p, s = chain.points[inside], chain.arc[inside]
    reach = 0.25 * quad_mm
    mean = (points_at(chain, np.clip(s - reach, 0.0, chain.length)) + p
            + points_at(chain, np.clip(s + reach, 0.0, chain.length))) / 3.0
    most = max(1, int(np.rint(1.5 * (hi - lo) / quad_mm)))
    n = min(most, max(1, int(np.ceil(np.sqrt(_chord_deviation(chain, lo, hi, 1, p, s) / chord_mm)))))
    if np.linalg.norm(p - mean, axis=1).max() > 0.5 * chord_mm:
        return n
    # over a kink (a rounded corner inside the edge) the sagitta falls only with the pieces: checked one by one
    while n < most and _chord_deviation(chain, lo, hi, n, p, s) > chord_mm:
        n += 1
    return n


def _chord_deviation(chain: Chain, lo: float, hi: float, n: int, p: np.ndarray, s: np.ndarray) -> float:
    """The farthest the chain's points ``p`` (at arc lengths ``s``) lie from the chords of ``n`` equal pieces of
    it between ``lo`` and ``hi``, mm."""
    cuts = lo + (hi - lo) * np.arange(n + 1) / n
    ends = points_at(chain, cuts)
    k = np.clip(np.searchsorted(cuts, s) - 1, 0, n - 1)
    a, b = ends[k], ends[k + 1]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(a + t[:, None] * ab - p, axis=1).max())
