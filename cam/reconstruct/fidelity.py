"""The reconstruction's self-check: the mesh and its own cloud must stay close, both ways.

A reconstruction can be wrong without any step failing: normals oriented inside
out over part of the cloud make the field put a sheet of surface where nothing
was scanned, tens of millimetres from the part, and the marching cubes mesh is
still closed and clean. The only witness the stage has is the cloud itself, so
the mesh is measured against it in both directions:

- every mesh vertex must lie near some cloud point (no surface where nothing
  was scanned: spurious sheets, blobs, filled holes), and
- every cloud point must lie near the mesh (no scanned surface left out: a lost
  thin wall, a stray cluster the extraction dropped).

The allowance is :data:`TOLERANCE_SPACINGS` point spacings plus
:data:`TOLERANCE_NOISE` times the cloud's noise. The spacing s is the larger
of the cloud's median neighbour distance and the field's finest cell (a
surface cannot be held finer than the grid it lives on); the noise sigma is
the median RMS distance of 16 neighbours from their fitted plane. A correct
reconstruction stays within the largest gaps of a random sample (about 4
spacings) and the noise's extremes (about 4.5 sigma at 50k points): on 50k-point
brackets at sigma = 0.25 % of the diagonal, 0.9-1.0 mm both ways against an
allowance of 3.5 mm, where the inside-out mesh this was built for strayed 25 mm
(31 % of the diagonal). A 10 mm hole plugged solid (its scanned wall then far
from the surface) or a sheet where nothing was scanned is refused; a gap in the
scan narrower than twice the allowance is bridged and passes.

A wider gap (an unscanned band: on a wall the scan crosses obliquely it is
wider than the band) puts even the true surface farther than the allowance from
every point. A vertex up to :data:`BRIDGE_TOLERANCES` times the allowance out
passes as *bridged* where it lies within the allowance of the convex hull of
the points around it (those within twice its distance plus the allowance): a
surface across a gap lies in the hull of the scanned surface round the gap (on
its chords at a convex crease, about 0.7 times its distance out for a right
angle, 0.8 at a box's corner, which so passes to about 1.2 allowances), while a
sheet hovering over a face, or a fin out of an edge, lies outside the hull by
about its distance. The count, the largest distance and where it lies are
reported, as surface the stage guessed. Isolated outliers (below) take no part
in the hull: a few round a sheet would make it look bridged. The cloud alone
cannot tell an unscanned band from a hole whose walls were not scanned, nor
surface filling a concave corner from one bridging it: within the bound, both
pass.

Isolated outliers (points whose 8th neighbour is over :data:`ISOLATED_SPACINGS`
times the cloud's median 8th-neighbour distance away) are counted but allowed:
a scan has them, and a surface should not follow them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from cam import GeometryError
from cam.mesh.closest import closest_points, mesh_index

__all__ = ["BRIDGE_TOLERANCES", "TOLERANCE_NOISE", "TOLERANCE_SPACINGS", "Fidelity",
           "FidelityError", "check_fidelity", "measure_fidelity"]

TOLERANCE_SPACINGS = 8.0
TOLERANCE_NOISE = 4.0
ISOLATED_SPACINGS = 4.0
# Neighbours whose spread gives the noise (as the normal estimate's first fit) and the isolation test.
NOISE_K = 16
ISOLATION_K = 8
# A cluster of scanned surface has at least a point and its ISOLATION_K neighbours; fewer far points
# than that are outliers that happen to sit together.
MIN_CLUSTER = ISOLATION_K + 1
# The noise is a median: this many points estimate it to a per cent, whatever the cloud's size.
NOISE_SAMPLE = 20_000
# A vertex over the allowance from the cloud, but within 1.5 times it, bridges a gap in the scan when it
# lies within the allowance of the hull of the points round it (see the module's docstring): the CSG
# block of bench/reconstruct.py with a band unscanned is 1.15 times its allowance from its cloud where
# the band crosses a wall obliquely, inside the hull; a sheet 1.05 allowances over a sphere is 1.05 out.
BRIDGE_TOLERANCES = 1.5


class FidelityError(GeometryError):
    """The mesh strays from its cloud (or misses part of it) by more than the allowance; the message says
    where, by how much and what to do. ``fidelity`` holds the measurement."""

    def __init__(self, message: str, fidelity: Fidelity) -> None:
        super().__init__(message)
        self.fidelity = fidelity


@dataclass(frozen=True)
class Fidelity:
    """Distances between a mesh and its cloud, in the cloud's units (mm in the pipeline).

    tolerance: the allowance, ``TOLERANCE_SPACINGS * max(spacing, cell) + TOLERANCE_NOISE * noise``.
    spacing: the cloud's median nearest-neighbour distance.
    cell: the finest detail the reconstruction can hold (the resolution given).
    noise: the median plane-fit residual over NOISE_K neighbours (about the noise's sigma).
    mesh_to_cloud: largest distance from a mesh vertex to its nearest cloud point.
    cloud_to_mesh: largest distance from a cloud point (isolated outliers left out) to the mesh; exact
    above the tolerance, below it the distance to the nearest mesh vertex (an upper bound, at most an
    edge above the exact one).
    far_vertices, far_points: how many exceed the tolerance (vertices that bridge a gap in the scan
    not counted); far_vertices_at, far_points_at: where the farthest of each lies (None when none is far).
    bridged_vertices: the vertices over the tolerance that bridge a gap in the scan (see the module's
    docstring); bridge_distance: the farthest of them from the cloud (0 when none), bridged_at: where.
    outliers: isolated cloud points farther than the tolerance from the mesh (allowed).
    diagonal: the cloud's bounding-box diagonal.
    """

    tolerance: float
    spacing: float
    cell: float
    noise: float
    mesh_to_cloud: float
    cloud_to_mesh: float
    far_vertices: int
    far_points: int
    far_vertices_at: tuple[float, float, float] | None
    far_points_at: tuple[float, float, float] | None
    outliers: int
    diagonal: float
    bridged_vertices: int = 0
    bridge_distance: float = 0.0
    bridged_at: tuple[float, float, float] | None = None

    @property
    def ok(self) -> bool:
        return self.far_vertices == 0 and self.far_points < MIN_CLUSTER

    def report(self) -> dict:
        """JSON-ready: every field, distances also as a share of the diagonal, and ``ok``."""
        share = 1.0 / max(self.diagonal, 1e-300)
        return {
            "ok": self.ok, "tolerance": self.tolerance, "spacing": self.spacing, "cell": self.cell,
            "noise": self.noise, "rule": f"{TOLERANCE_SPACINGS:g} x max(spacing, cell) + {TOLERANCE_NOISE:g} x noise",
            "mesh_to_cloud": self.mesh_to_cloud, "cloud_to_mesh": self.cloud_to_mesh,
            "mesh_to_cloud_diagonal": self.mesh_to_cloud * share, "cloud_to_mesh_diagonal": self.cloud_to_mesh * share,
            "far_vertices": self.far_vertices, "far_points": self.far_points,
            "far_vertices_at": self.far_vertices_at, "far_points_at": self.far_points_at,
            "outliers": self.outliers, "diagonal": self.diagonal,
            "bridged_vertices": self.bridged_vertices, "bridge_distance": self.bridge_distance,
            "bridged_at": self.bridged_at,
        }


def measure_fidelity(
    vertices: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    *,
    resolution: float = 0.0,
    workers: int = 1,
) -> Fidelity:
    """Measure how far a reconstructed mesh and its cloud lie from each other.

    Parameters
    ----------
    vertices : ndarray, shape (v, 3), float64
        The mesh's vertices, the cloud's units and frame.
    faces : ndarray, shape (f, 3), int64
        Its triangles (f >= 1).
    points : ndarray, shape (n, 3), float64
        The cloud it was reconstructed from, n > NOISE_K.
    resolution : float
        The finest detail the reconstruction can hold (the field's cell, or the
        marching-cubes cell), the cloud's units: the spacing is at least this.
    workers : int
        Threads for the k-NN queries.

    Returns
    -------
    Fidelity
        The distances, the allowance and where the farthest offenders lie.

    Raises
    ------
    ValueError
        For arrays of the wrong shape, a mesh without faces or a cloud of NOISE_K points or fewer.
    """
    verts = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(faces, dtype=np.int64)
    pts = np.asarray(points, dtype=np.float64)
    if verts.ndim != 2 or verts.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3 or not len(tri):
        raise ValueError(f"need vertices (v, 3) and at least one face (f, 3), got {verts.shape} and {tri.shape}")
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) <= NOISE_K:
        raise ValueError(f"need more than {NOISE_K} cloud points (n, 3), got {pts.shape}")
    tree = cKDTree(pts)
    spacing, noise = _spacing_and_noise(pts, tree, workers)
    tolerance = TOLERANCE_SPACINGS * max(spacing, float(resolution)) + TOLERANCE_NOISE * noise
    used = np.unique(tri)
    to_cloud, _ = tree.query(verts[used], workers=workers)
    far_v = to_cloud > tolerance
    bridged = np.zeros(len(used), dtype=bool)
    if far_v.any():
        bridged[far_v] = _bridges(verts[used[far_v]], to_cloud[far_v], pts, tree, tolerance, workers)
    far_v &= ~bridged
    to_mesh = _cloud_to_mesh(verts, tri, used, pts, refine_above=tolerance, workers=workers)
    far_p = to_mesh > tolerance
    isolated = np.zeros(len(pts), dtype=bool)
    if far_p.any():
        isolated[far_p] = _isolated(pts, np.flatnonzero(far_p), tree, workers)
    counted = np.where(isolated, 0.0, to_mesh)
    far_counted = far_p & ~isolated
    return Fidelity(
        tolerance=tolerance, spacing=spacing, cell=float(resolution), noise=noise,
        mesh_to_cloud=float(to_cloud.max()), cloud_to_mesh=float(counted.max()),
        far_vertices=int(far_v.sum()), far_points=int(far_counted.sum()),
        far_vertices_at=_where(verts[used], to_cloud) if far_v.any() else None,
        far_points_at=_where(pts, counted) if far_counted.any() else None,
        outliers=int((far_p & isolated).sum()),
        diagonal=float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))),
        bridged_vertices=int(bridged.sum()),
        bridge_distance=float(to_cloud[bridged].max()) if bridged.any() else 0.0,
        bridged_at=_where(verts[used][bridged], to_cloud[bridged]) if bridged.any() else None,
    )


def check_fidelity(fidelity: Fidelity) -> None:
    """Raise :class:`FidelityError` with a message a user can act on when the mesh strays from its cloud.

    Parameters
    ----------
    fidelity : Fidelity
        A measurement from :func:`measure_fidelity`.

    Raises
    ------
    FidelityError
        When a mesh vertex lies farther than the tolerance from every cloud point (vertices that bridge
        a gap in the scan apart), or a cluster of cloud points (MIN_CLUSTER or more, isolated outliers
        not counted) farther than it from the mesh.
    """
    if fidelity.ok:
        return
    f = fidelity
    allowance = (f"the check allows {f.tolerance:.3g} mm: {TOLERANCE_SPACINGS:g} x {max(f.spacing, f.cell):.3g} mm "
                 f"(the coarser of the point spacing, {f.spacing:.3g} mm, and the reconstruction's cell, "
                 f"{f.cell:.3g} mm) + {TOLERANCE_NOISE:g} x the cloud's noise, {f.noise:.3g} mm")
    problems = []
    if f.far_vertices:
        problems.append(
            f"the reconstructed surface strays up to {f.mesh_to_cloud:.3g} mm ({f.mesh_to_cloud / f.diagonal:.1%} of "
            f"the part's diagonal) from every scanned point, farthest near {_xyz(f.far_vertices_at)}: a surface "
            "where nothing was scanned (normals inside out over part of the cloud, a spurious sheet or a filled "
            f"hole), not the part (surface across a gap in the scan passes up to {BRIDGE_TOLERANCES:g} x the "
            "allowance out, where it lies within the allowance of the hull of the scanned surface round it)")
    if f.far_points >= MIN_CLUSTER:
        problems.append(
            f"{f.far_points} scanned points lie up to {f.cloud_to_mesh:.3g} mm from the reconstructed surface, "
            f"farthest near {_xyz(f.far_points_at)}: the surface leaves out part of the scan (a stray cluster "
            "apart from the part, or a feature thinner than the reconstruction's grid)")
    raise FidelityError(
        "reconstruction rejected: " + "; and ".join(problems) + f"; {allowance}. Upload the cloud with "
        "oriented normals, crop stray points from the scan, or scan again denser or with less noise; "
        "a finer reconstruct.grid_cells and resolution help a thin feature", fidelity)


def _bridges(at: np.ndarray, distance: np.ndarray, pts: np.ndarray, tree: cKDTree, tolerance: float,
             workers: int) -> np.ndarray:
    """Whether each vertex ``at`` (m, 3), ``distance`` (m,) from the cloud and over ``tolerance``, bridges a
    gap in the scan: at most BRIDGE_TOLERANCES tolerances out, and at most ``tolerance`` outside the
    convex hull of the points within twice its distance plus the tolerance, isolated outliers left out
    (outside as the largest signed distance to the hull's facets' planes, exact where the nearest feature
    is a facet). All or none: once one fails (the farthest are looked at first) the mesh is refused
    whatever the rest are, and none counts as bridged."""
    none = np.zeros(len(at), dtype=bool)
    if distance.max() > BRIDGE_TOLERANCES * tolerance:
        return none  # refused whatever: the outliers' test (a k-NN query of the whole cloud) is not spent
    kept = ~_isolated(pts, np.arange(len(pts)), tree, workers)
    for j in np.argsort(-distance):
        near = np.asarray(tree.query_ball_point(at[j], 2.0 * distance[j] + tolerance), dtype=np.int64)
        near = near[kept[near]]
        try:
            # QJ: a flat patch of noiseless points has no 3-D hull; joggled, a flat one.
            facets = ConvexHull(pts[near], qhull_options="QJ").equations
        except QhullError:  # fewer than four points round it: nothing to bridge
            return none
        if (facets[:, :3] @ at[j] + facets[:, 3]).max() > tolerance:
            return none
    return ~none


def _spacing_and_noise(pts: np.ndarray, tree: cKDTree, workers: int) -> tuple[float, float]:
    """The median distance to the nearest neighbour and the median plane-fit residual of NOISE_K neighbours."""
    sample = pts[:: max(1, len(pts) // NOISE_SAMPLE)]
    dist, idx = tree.query(sample, k=NOISE_K + 1, workers=workers)
    nb = pts[idx[:, 1:]]
    nb = nb - nb.mean(axis=1, keepdims=True)
    smallest = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", nb, nb))[:, 0]
    residual = np.sqrt(np.maximum(smallest, 0.0) / NOISE_K)
    return float(np.median(dist[:, 1])), float(np.median(residual))


def _cloud_to_mesh(verts, tri, used, pts, *, refine_above: float, workers: int) -> np.ndarray:
    """Each point's distance to the mesh: to its nearest vertex (an upper bound, at most an edge above the
    exact one), made exact where that exceeds ``refine_above``; the exact query costs a minute on a
    50k-point cloud and a 700k-face mesh, the vertex one a second, and only large distances matter."""
    d, _ = cKDTree(verts[used]).query(pts, workers=workers)
    refine = np.flatnonzero(d > refine_above)
    if len(refine):
        _, exact, _, _ = closest_points(mesh_index(verts, tri), pts[refine])
        d[refine] = np.minimum(d[refine], exact)
    return d


def _isolated(pts: np.ndarray, which: np.ndarray, tree: cKDTree, workers: int) -> np.ndarray:
    """Whether each of ``pts[which]`` stands alone: its ISOLATION_K-th neighbour is over ISOLATED_SPACINGS
    times the cloud's median ISOLATION_K-th neighbour distance away."""
    sample = pts[:: max(1, len(pts) // NOISE_SAMPLE)]
    typical = float(np.median(tree.query(sample, k=ISOLATION_K + 1, workers=workers)[0][:, -1]))
    own = tree.query(pts[which], k=ISOLATION_K + 1, workers=workers)[0][:, -1]
    return own > ISOLATED_SPACINGS * typical


def _where(points: np.ndarray, distance: np.ndarray) -> tuple[float, float, float]:
    return tuple(round(float(c), 3) for c in points[int(np.argmax(distance))])


def _xyz(at: tuple[float, float, float] | None) -> str:
    return "(" + ", ".join(f"{c:.1f}" for c in at) + ")" if at is not None else "?"
