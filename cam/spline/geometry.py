"""Differential geometry of the fitted patches in the machine frame: frames, fundamental forms, curvature.

A `Patch` is one B-spline surface moved into a setup's machine frame (tool axis +Z) with the
sign that makes its normal point out of the material, towards where the tool can be. Normal
curvature is signed the way the scallop relations want it: positive where the surface bulges
towards the tool (convex), negative where it is hollow.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cam.spline.surface import BSplineSurface, make_bspline_surface

if TYPE_CHECKING:
    from cam.gcode.setup import Setup

__all__ = [
    "Frame",
    "Patch",
    "across_iso_line",
    "area_share",
    "frame",
    "iso_line_frame",
    "machine_patches",
    "normal_curvature",
    "orientation_signs",
    "principal_curvatures",
    "surface_area",
    "transform_surface",
]


@dataclass(frozen=True, eq=False)
class Patch:
    """A surface in the machine frame.

    Attributes
    ----------
    id : int
        The patch id of `surfaces.json`.
    surface : BSplineSurface
        The surface, moved into the setup's machine frame (mm).
    sign : float
        +1 when S_u × S_v points out of the material, -1 when it points in.
    """

    id: int
    surface: BSplineSurface
    sign: float = 1.0

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The surface's parameter rectangle ((u0, u1), (v0, v1)), see `BSplineSurface.domain`."""
        return self.surface.domain


@dataclass(frozen=True)
class Frame:
    """Point, first and second derivatives, outward unit normal and both fundamental forms, all (...)-shaped.

    Attributes
    ----------
    p : (..., 3) float64
        Points in mm.
    su, sv : (..., 3) float64
        First partial derivatives S_u, S_v in mm per parameter unit.
    suu, suv, svv : (..., 3) float64
        Second partial derivatives in mm per parameter unit².
    n : (..., 3) float64
        Outward unit normal sign · (S_u × S_v) / |S_u × S_v|; NaN where the surface is degenerate.
    e, f, g : (...) float64
        First fundamental form S_u·S_u, S_u·S_v, S_v·S_v (mm² per parameter unit²).
    l, m, nn : (...) float64
        Second fundamental form taken against the outward normal with the sign flipped (mm per parameter
        unit²), so that normal curvature κ = (l du² + 2m du dv + nn dv²) / (e du² + 2f du dv + g dv²) is
        convex-positive.
    """

    p: np.ndarray
    su: np.ndarray
    sv: np.ndarray
    suu: np.ndarray
    suv: np.ndarray
    svv: np.ndarray
    n: np.ndarray
    e: np.ndarray
    f: np.ndarray
    g: np.ndarray
    l: np.ndarray
    m: np.ndarray
    nn: np.ndarray


def transform_surface(surface: BSplineSurface, rotation: np.ndarray, translation: np.ndarray) -> BSplineSurface:
    """The surface moved by x ↦ R·x + t (exact: B-splines are affine invariant).

    Parameters
    ----------
    surface : BSplineSurface
        The surface to move.
    rotation : (3, 3) array_like of float
        R, a proper rotation (orthonormal within 1e-6, determinant > 0).
    translation : (3,) array_like of float
        The translation t in mm.

    Returns
    -------
    moved : BSplineSurface
        Same degree, knots and parameterisation; control points R·c + t.

    Raises
    ------
    ValueError
        When rotation is not 3 x 3 or translation not 3 values, or rotation is not a proper rotation.
    """
    rot = np.asarray(rotation, dtype=np.float64)
    tr = np.asarray(translation, dtype=np.float64)
    if rot.shape != (3, 3) or tr.shape != (3,):
        raise ValueError(f"rotation must be 3x3 and translation 3 values, got {rot.shape} and {tr.shape}")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) <= 0:
        raise ValueError(f"rotation is not a proper rotation matrix: {rot.tolist()}")
    cp = surface.control_points @ rot.T + tr
    return make_bspline_surface(cp, surface.knots_u, surface.knots_v, degree=surface.degree)


def machine_patches(ids: list[int], surfaces: list[BSplineSurface], signs: np.ndarray, setup: Setup) -> list[Patch]:
    """The surfaces moved into the setup's machine frame, with their outward signs.

    Parameters
    ----------
    ids : list of int
        Patch ids, one per surface.
    surfaces : list of BSplineSurface
        The surfaces in the part frame (mm).
    signs : (k,) array_like of float
        +1 or -1 per surface, as `orientation_signs` gives them.
    setup : Setup
        The setup whose rotation and translation (mm) take part points to machine points.

    Returns
    -------
    patches : list of Patch
        One per surface, in order.

    Raises
    ------
    ValueError
        When the setup's rotation is not a proper rotation (see `transform_surface`).
    """
    return [Patch(int(i), transform_surface(s, setup.rotation, setup.translation), float(g))
            for i, s, g in zip(ids, surfaces, signs)]


def frame(patch: Patch, u: np.ndarray, v: np.ndarray) -> Frame:
    """Evaluate everything the planner needs at parameters u, v.

    Parameters
    ----------
    patch : Patch
        The patch, in the machine frame.
    u, v : (...) array_like of float
        Parameters, both of one shape.

    Returns
    -------
    frame : Frame
        Every field shaped (...) or (..., 3).
    """
    s = patch.surface
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    d = s.derivatives(u, v, order=2)  # one pass for all six terms
    p, su, sv, suu, suv, svv = d[0, 0], d[1, 0], d[0, 1], d[2, 0], d[1, 1], d[0, 2]
    cross = np.cross(su, sv) * patch.sign
    length = np.linalg.norm(cross, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(length > 0, cross / length, np.nan)
    dot = lambda a, b: np.einsum("...i,...i->...", a, b)
    return Frame(p=p, su=su, sv=sv, suu=suu, suv=suv, svv=svv, n=n,
                 e=dot(su, su), f=dot(su, sv), g=dot(sv, sv),
                 l=-dot(suu, n), m=-dot(suv, n), nn=-dot(svv, n))


def normal_curvature(fr: Frame, du: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """Signed normal curvature in the tangent direction du·S_u + dv·S_v.

    Parameters
    ----------
    fr : Frame
        The frame at the points.
    du, dv : (...) array_like of float
        Components of the direction in parameter units; only the direction counts, not its length.

    Returns
    -------
    kappa : (...) float64
        Curvature in 1/mm, convex (bulging towards the tool) > 0.
    """
    num = fr.l * du * du + 2 * fr.m * du * dv + fr.nn * dv * dv
    den = fr.e * du * du + 2 * fr.f * du * dv + fr.g * dv * dv
    return num / den


def iso_line_frame(patch: Patch, along: str, fixed: float, q: np.ndarray) -> Frame:
    """Frame on an iso-line at parameters q.

    Parameters
    ----------
    patch : Patch
        The patch, in the machine frame.
    along : str
        'u' for the line v = fixed with u = q; 'v' for u = fixed with v = q.
    fixed : float
        The parameter that is constant along the line.
    q : (n,) float64
        Parameters along the line.

    Returns
    -------
    frame : Frame
        Fields shaped (n,) or (n, 3).
    """
    if along == "u":
        return frame(patch, q, np.full_like(q, fixed))
    return frame(patch, np.full_like(q, fixed), q)


def across_iso_line(fr: Frame, along: str) -> tuple[np.ndarray, np.ndarray]:
    """Normal curvature across the iso-line and the distance between iso-lines per parameter unit.

    Parameters
    ----------
    fr : Frame
        The frame on the line (see `iso_line_frame`).
    along : str
        'u' for a line v = const (across is S_v minus its part along S_u); 'v' for a line u = const.

    Returns
    -------
    kappa : (...) float64
        Normal curvature in 1/mm (convex > 0) in the tangent direction perpendicular to the line.
    spacing : (...) float64
        Distance between neighbouring iso-lines in mm per unit of the fixed parameter.
    """
    root = np.sqrt(np.maximum(fr.e * fr.g - fr.f ** 2, 1e-300))
    if along == "u":  # line v = const; across is S_v minus its part along S_u
        kappa = normal_curvature(fr, -fr.f / fr.e, np.ones_like(fr.e))
        return kappa, root / np.sqrt(fr.e)
    kappa = normal_curvature(fr, np.ones_like(fr.e), -fr.f / fr.g)
    return kappa, root / np.sqrt(fr.g)


def principal_curvatures(fr: Frame) -> tuple[np.ndarray, np.ndarray]:
    """Principal curvatures from det(II − κ I) = 0.

    Parameters
    ----------
    fr : Frame
        The frame at the points.

    Returns
    -------
    kappa_min, kappa_max : (...) float64
        Smallest and largest normal curvature in 1/mm (convex > 0), each shaped like the frame.
    """
    det_i = fr.e * fr.g - fr.f ** 2
    mean = (fr.e * fr.nn - 2 * fr.f * fr.m + fr.g * fr.l) / (2 * det_i)
    gauss = (fr.l * fr.nn - fr.m ** 2) / det_i
    root = np.sqrt(np.maximum(mean * mean - gauss, 0.0))
    return mean - root, mean + root


def orientation_signs(surfaces: list[BSplineSurface], *, mesh_vertices: np.ndarray | None = None,
                      mesh_faces: np.ndarray | None = None, up: np.ndarray | None = None,
                      samples: int = 9) -> np.ndarray:
    """+1 or −1 per surface so that sign·(S_u × S_v) points out of the material.

    With a closed mesh the normals are compared with the nearest outward face normals (the mesh is made
    outward by the sign of its volume). Without one, each patch is taken as a height field seen from
    `up`: the sign that makes the mean normal face it.

    Parameters
    ----------
    surfaces : list of BSplineSurface
        The surfaces (mm).
    mesh_vertices : (n, 3) array_like of float or None, optional
        Vertices of a closed mesh in mm, same frame as the surfaces.
    mesh_faces : (m, 3) array_like of int or None, optional
        Its triangles; both mesh arguments are needed for the mesh test.
    up : (3,) array_like of float or None, optional
        The tool axis of the first setup in this frame (default +Z); used without a mesh.
    samples : int, optional
        Normals compared per direction, on [0.05, 0.95] of the domain (default 9).

    Returns
    -------
    signs : (len(surfaces),) float64
        +1 or -1.
    """
    from scipy.spatial import cKDTree

    g = np.linspace(0.05, 0.95, samples)
    signs = np.ones(len(surfaces))
    tree = face_normals = None
    if mesh_vertices is not None and mesh_faces is not None and len(mesh_faces):
        tri = np.asarray(mesh_vertices, dtype=np.float64)[np.asarray(mesh_faces)]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        volume = np.einsum("ij,ij->i", tri[:, 0], cross).sum() / 6.0
        face_normals = cross * (1.0 if volume >= 0 else -1.0)
        tree = cKDTree(tri.mean(axis=1))
    axis = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    for i, s in enumerate(surfaces):
        (u0, u1), (v0, v1) = s.domain
        uu, vv = np.meshgrid(u0 + g * (u1 - u0), v0 + g * (v1 - v0), indexing="ij")
        nrm = np.cross(s.evaluate(uu, vv, du=1), s.evaluate(uu, vv, dv=1)).reshape(-1, 3)
        if tree is not None:
            _, idx = tree.query(s.evaluate(uu, vv).reshape(-1, 3))
            score = np.einsum("ij,ij->i", nrm, face_normals[idx])
            score = np.sign(score).sum()
        else:
            score = (nrm @ axis).sum()
        signs[i] = 1.0 if score >= 0 else -1.0
    return signs


@dataclass(frozen=True, eq=False)
class SubSurface:
    """A surface seen on a parameter sub-rectangle (u0, u1, v0, v1): same parameters, smaller domain.

    Attributes
    ----------
    base : BSplineSurface
        The whole surface; evaluation, knots and control points are its own.
    region : tuple of float
        The sub-rectangle (u0, u1, v0, v1) in the base's parameters, returned as `domain`.
    """

    base: BSplineSurface
    region: tuple[float, float, float, float]

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The sub-rectangle as ((u0, u1), (v0, v1))."""
        u0, u1, v0, v1 = self.region
        return (u0, u1), (v0, v1)

    @property
    def control_points(self) -> np.ndarray:
        """The base surface's control net: (nu, nv, 3) float64, mm."""
        return self.base.control_points

    @property
    def knots_u(self) -> np.ndarray:
        """The base surface's knots in u: (nu + p + 1,) float64."""
        return self.base.knots_u

    @property
    def knots_v(self) -> np.ndarray:
        """The base surface's knots in v: (nv + q + 1,) float64."""
        return self.base.knots_v

    def derivatives(self, u: np.ndarray, v: np.ndarray, *, order: int = 2) -> dict[tuple[int, int], np.ndarray]:
        """The base surface's points and derivatives (see `BSplineSurface.derivatives`)."""
        return self.base.derivatives(u, v, order=order)

    def evaluate(self, u: np.ndarray, v: np.ndarray, *, du: int = 0, dv: int = 0) -> np.ndarray:
        """Evaluate the base surface (see `BSplineSurface.evaluate`).

        Parameters
        ----------
        u, v : (...) float
            Parameters, both of one shape; values outside the base's domain are clipped to it, not to
            `region`.
        du, dv : int, optional
            Orders of differentiation in u and in v (default 0: points).

        Returns
        -------
        values : (..., 3) float64
            Points in mm, or derivatives in mm per parameter unit^(du+dv).
        """
        return self.base.evaluate(u, v, du=du, dv=dv)


def surface_area(surface: BSplineSurface, box: tuple[float, float, float, float] | None = None, *,
                 samples: int = 64) -> float:
    """Area of the surface over its domain or the parameter rectangle `box` (midpoint rule).

    Parameters
    ----------
    surface : BSplineSurface
        The surface (mm).
    box : tuple of float or None, optional
        (u0, u1, v0, v1) in parameters; None (default) for the whole domain.
    samples : int, optional
        Midpoints per direction (default 64).

    Returns
    -------
    area : float
        In mm².
    """
    (u0, u1), (v0, v1) = surface.domain
    a, b, c, d = box if box is not None else (u0, u1, v0, v1)
    t = (np.arange(samples) + 0.5) / samples
    uu, vv = np.meshgrid(a + t * (b - a), c + t * (d - c), indexing="ij")
    n = np.cross(surface.evaluate(uu, vv, du=1), surface.evaluate(uu, vv, dv=1))
    return float(np.linalg.norm(n, axis=-1).mean()) * (b - a) * (d - c)


def area_share(surface: BSplineSurface, box: tuple[float, float, float, float], *, samples: int = 64) -> float:
    """The share of the surface's area inside the parameter rectangle `box`.

    Parameters
    ----------
    surface : BSplineSurface
        The surface (mm).
    box : tuple of float
        (u0, u1, v0, v1) in parameters.
    samples : int, optional
        Midpoints per direction of each area (default 64).

    Returns
    -------
    share : float
        Area in `box` over the whole area; 0.0 for a surface of no area.
    """
    total = surface_area(surface, samples=samples)
    return surface_area(surface, box, samples=samples) / total if total > 0 else 0.0
