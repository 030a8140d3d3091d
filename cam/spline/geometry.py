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
    """A surface in the machine frame. id: the patch id of `surfaces.json`; sign: +1 when S_u × S_v is outward."""

    id: int
    surface: BSplineSurface
    sign: float = 1.0

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        return self.surface.domain


@dataclass(frozen=True)
class Frame:
    """Point, first and second derivatives, outward unit normal and both fundamental forms, all (...)-shaped.

    p, su, sv, suu, suv, svv, n: float64 (..., 3) mm; e, f, g: first fundamental form (mm²);
    l, m, nn: second fundamental form taken against the outward normal with the sign flipped, so
    that normal curvature κ = (l du² + 2m du dv + nn dv²) / (e du² + 2f du dv + g dv²) is convex-positive.
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

    rotation: float (3, 3) proper rotation; translation: float (3,) mm.
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
    """The surfaces moved into the setup's machine frame, with their outward signs."""
    return [Patch(int(i), transform_surface(s, setup.rotation, setup.translation), float(g))
            for i, s, g in zip(ids, surfaces, signs)]


def frame(patch: Patch, u: np.ndarray, v: np.ndarray) -> Frame:
    """Evaluate everything the planner needs at parameters u, v (float arrays of one shape)."""
    s = patch.surface
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    p = s.evaluate(u, v)
    su, sv = s.evaluate(u, v, du=1), s.evaluate(u, v, dv=1)
    suu, suv, svv = s.evaluate(u, v, du=2), s.evaluate(u, v, du=1, dv=1), s.evaluate(u, v, dv=2)
    cross = np.cross(su, sv) * patch.sign
    length = np.linalg.norm(cross, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(length > 0, cross / length, np.nan)
    dot = lambda a, b: np.einsum("...i,...i->...", a, b)
    return Frame(p=p, su=su, sv=sv, suu=suu, suv=suv, svv=svv, n=n,
                 e=dot(su, su), f=dot(su, sv), g=dot(sv, sv),
                 l=-dot(suu, n), m=-dot(suv, n), nn=-dot(svv, n))


def normal_curvature(fr: Frame, du: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """Signed normal curvature (1/mm, convex > 0) in the tangent direction du·S_u + dv·S_v."""
    num = fr.l * du * du + 2 * fr.m * du * dv + fr.nn * dv * dv
    den = fr.e * du * du + 2 * fr.f * du * dv + fr.g * dv * dv
    return num / den


def iso_line_frame(patch: Patch, along: str, fixed: float, q: np.ndarray) -> Frame:
    """Frame on an iso-line at parameters q (float (n,)): along 'u' means v = fixed and u = q."""
    if along == "u":
        return frame(patch, q, np.full_like(q, fixed))
    return frame(patch, np.full_like(q, fixed), q)


def across_iso_line(fr: Frame, along: str) -> tuple[np.ndarray, np.ndarray]:
    """Normal curvature across the iso-line and the distance between iso-lines per parameter unit."""
    root = np.sqrt(np.maximum(fr.e * fr.g - fr.f ** 2, 1e-300))
    if along == "u":  # line v = const; across is S_v minus its part along S_u
        kappa = normal_curvature(fr, -fr.f / fr.e, np.ones_like(fr.e))
        return kappa, root / np.sqrt(fr.e)
    kappa = normal_curvature(fr, np.ones_like(fr.e), -fr.f / fr.g)
    return kappa, root / np.sqrt(fr.g)


def principal_curvatures(fr: Frame) -> tuple[np.ndarray, np.ndarray]:
    """(κ_min, κ_max) in 1/mm from det(II − κ I) = 0, each shaped like the frame."""
    det_i = fr.e * fr.g - fr.f ** 2
    mean = (fr.e * fr.nn - 2 * fr.f * fr.m + fr.g * fr.l) / (2 * det_i)
    gauss = (fr.l * fr.nn - fr.m ** 2) / det_i
    root = np.sqrt(np.maximum(mean * mean - gauss, 0.0))
    return mean - root, mean + root


def orientation_signs(surfaces: list[BSplineSurface], *, mesh_vertices: np.ndarray | None = None,
                      mesh_faces: np.ndarray | None = None, up: np.ndarray | None = None,
                      samples: int = 9) -> np.ndarray:
    """+1 or −1 per surface so that sign·(S_u × S_v) points out of the material.

    With a closed mesh (vertices float (n, 3), faces int (m, 3), same frame as the surfaces) the
    normals are compared with the nearest outward face normals (the mesh is made outward by the
    sign of its volume). Without one, each patch is taken as a height field seen from `up`
    (float (3,), the tool axis of the first setup in this frame): the sign that makes the mean
    normal face it. Returns float64 (len(surfaces),).
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
    """A surface seen on a parameter sub-rectangle (u0, u1, v0, v1): same parameters, smaller domain."""

    base: BSplineSurface
    region: tuple[float, float, float, float]

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        u0, u1, v0, v1 = self.region
        return (u0, u1), (v0, v1)

    @property
    def control_points(self) -> np.ndarray:
        return self.base.control_points

    @property
    def knots_u(self) -> np.ndarray:
        return self.base.knots_u

    @property
    def knots_v(self) -> np.ndarray:
        return self.base.knots_v

    def evaluate(self, u: np.ndarray, v: np.ndarray, *, du: int = 0, dv: int = 0) -> np.ndarray:
        return self.base.evaluate(u, v, du=du, dv=dv)


def surface_area(surface: BSplineSurface, box: tuple[float, float, float, float] | None = None, *,
                 samples: int = 64) -> float:
    """Area (mm²) of the surface over its domain or the parameter rectangle `box` (midpoint rule)."""
    (u0, u1), (v0, v1) = surface.domain
    a, b, c, d = box if box is not None else (u0, u1, v0, v1)
    t = (np.arange(samples) + 0.5) / samples
    uu, vv = np.meshgrid(a + t * (b - a), c + t * (d - c), indexing="ij")
    n = np.cross(surface.evaluate(uu, vv, du=1), surface.evaluate(uu, vv, dv=1))
    return float(np.linalg.norm(n, axis=-1).mean()) * (b - a) * (d - c)


def area_share(surface: BSplineSurface, box: tuple[float, float, float, float], *, samples: int = 64) -> float:
    """The share of the surface's area inside the parameter rectangle `box`."""
    total = surface_area(surface, samples=samples)
    return surface_area(surface, box, samples=samples) / total if total > 0 else 0.0
