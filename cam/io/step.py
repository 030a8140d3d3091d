"""STEP (ISO 10303-21, AP214) export of B-spline surfaces: one face per surface, in mm.

A Part 21 file is a HEADER (what the file is, who wrote it, which schema its data follow) and a DATA
section of numbered entity instances, ``#id=TYPE(attributes);``, that refer to each other by ``#id``.
The schema is AP214 (AUTOMOTIVE_DESIGN), the one every CAD importer reads.

What an importer needs to find the geometry, and what we write:

- the product structure: PRODUCT → PRODUCT_DEFINITION_FORMATION → PRODUCT_DEFINITION →
  PRODUCT_DEFINITION_SHAPE, tied by SHAPE_DEFINITION_REPRESENTATION to the shape representation;
- the shape representation, a MANIFOLD_SURFACE_SHAPE_REPRESENTATION in a geometric context whose length
  unit is the millimetre (SI_UNIT(.MILLI.,.METRE.)), holding one SHELL_BASED_SURFACE_MODEL;
- per surface an ADVANCED_FACE on its B_SPLINE_SURFACE_WITH_KNOTS, bounded by the surface's natural
  boundary: four edges whose curves are the clamped net's first and last rows and columns (exactly the
  surface's border), each face in its own OPEN_SHELL.

Faces rather than bare surfaces because importers turn faces into trimmed, selectable, sewable CAD faces;
bare surfaces in a GEOMETRIC_CURVE_SET are often dropped or shown as wireframe. One open shell per face
because a shell is by definition connected through shared edges, and our patches share none (their
borders coincide only geometrically); an importer sews them if its user asks.

B_SPLINE_SURFACE_WITH_KNOTS stores the net as a list over u of lists over v (our ``[i, j]`` order) and
the knots as their distinct values with multiplicities. Our surfaces are polynomial: no weights.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from cam.io.atomic import atomic_write
from cam.spline.surface import make_bspline_surface

__all__ = ["step_bytes", "write_step"]

SCHEMA = "AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }"
_WIDTH = 80
#: Distance below which two points are one to a reader (LENGTH_MEASURE, mm); the fit's C0 is far finer.
_UNCERTAINTY_MM = 1e-6
#: Text up to and including the next comma or closing parenthesis outside a string ('' inside a string
#: reads as two strings side by side, which is the same split).
_PIECE = re.compile(r"(?:'[^']*'|[^,)'])+[,)]?|[,)]")


def write_step(path: str | os.PathLike[str], surfaces: Sequence, *, labels: Sequence[int] | None = None,
               created: datetime | None = None, author: str = "cloud2cnc", organization: str = "",
               product: str = "cloud2cnc surfaces") -> Path:
    """Write surfaces to `path` atomically as a STEP AP214 file; see `step_bytes`.

    Parameters
    ----------
    path : str or os.PathLike
        The target file; its name is stored in the header.
    surfaces : sequence
        Objects with degree, knots_u, knots_v, control_points (nu, nv, 3) in mm, like
        `cam.spline.surface.BSplineSurface`.
    labels : sequence of int or None, optional
        An integer per surface named in its face ("patch <label>"; default the index).
    created : datetime or None, optional
        The file's timestamp (default now, UTC).
    author, organization : str, optional
        Stored in the header.
    product : str, optional
        The product's name and the header's description.

    Returns
    -------
    path : pathlib.Path
        The path written.

    Raises
    ------
    ValueError
        As `step_bytes`.
    """
    data = step_bytes(surfaces, labels=labels, created=created, author=author, organization=organization,
                      product=product, filename=Path(path).name)
    return atomic_write(path, [data])


def step_bytes(surfaces: Sequence, *, labels: Sequence[int] | None = None, created: datetime | None = None,
               author: str = "cloud2cnc", organization: str = "", product: str = "cloud2cnc surfaces",
               filename: str = "surfaces.step") -> bytes:
    """The STEP AP214 file as bytes (ASCII, lines of at most 80 characters where a token allows).

    Parameters
    ----------
    surfaces : sequence
        Objects with degree (p, q), knots_u (nu + p + 1,), knots_v (nv + q + 1,) and control_points
        (nu, nv, 3) in mm, like `cam.spline.surface.BSplineSurface`: clamped B-splines (first and last
        p + 1 knots equal) with finite knots and coordinates. Each becomes one ADVANCED_FACE.
    labels : sequence of int or None, optional
        An integer per surface named in its face and surface ("patch <label>"; default the index).
    created : datetime or None, optional
        The file's timestamp (default now, UTC).
    author, organization : str, optional
        Stored in the header's FILE_NAME.
    product : str, optional
        The product's name and the header's description.
    filename : str, optional
        The file name stored in the header (default "surfaces.step").

    Returns
    -------
    data : bytes
        The file, lines ending in '\\n'; lengths in millimetres.

    Raises
    ------
    ValueError
        For a label count that differs from the surface count, or a surface that
        `cam.spline.surface.make_bspline_surface` refuses (its message, after the patch's name).
    """
    labels = list(range(len(surfaces))) if labels is None else [int(x) for x in labels]
    if len(labels) != len(surfaces):
        raise ValueError(f"need one label per surface, got {len(labels)} for {len(surfaces)}")
    when = (created or datetime.now(UTC)).replace(microsecond=0).isoformat()
    data = _Data()
    context = _add_context(data)
    origin = data.add("CARTESIAN_POINT('',(0.0,0.0,0.0))")
    z_axis = data.add("DIRECTION('',(0.0,0.0,1.0))")
    x_axis = data.add("DIRECTION('',(1.0,0.0,0.0))")
    axes = data.add(f"AXIS2_PLACEMENT_3D('',#{origin},#{z_axis},#{x_axis})")
    shells = [_add_face_shell(data, surf, f"patch {label}") for surf, label in zip(surfaces, labels)]
    model = data.add(f"SHELL_BASED_SURFACE_MODEL('',({_refs(shells)}))")
    shape = data.add(f"MANIFOLD_SURFACE_SHAPE_REPRESENTATION({_string(product)},(#{axes},#{model}),#{context})")
    _add_product(data, shape, product)
    header = [
        "ISO-10303-21;", "HEADER;",
        f"FILE_DESCRIPTION(({_string(f'{product}: {len(surfaces)} B-spline surfaces, millimetres')}),'2;1');",
        (f"FILE_NAME({_string(filename)},{_string(when)},({_string(author or 'unknown')}),"
         f"({_string(organization or 'unknown')}),'cloud2cnc','cloud2cnc fit','');"),
        f"FILE_SCHEMA(({_string(SCHEMA)}));", "ENDSEC;", "DATA;",
    ]
    lines = [line for text in header + data.entities for line in _wrap(text)]
    lines += ["ENDSEC;", "END-ISO-10303-21;"]
    return ("\n".join(lines) + "\n").encode("ascii")


class _Data:
    """The DATA section under construction: entity texts numbered #1, #2, ... in the order added."""

    def __init__(self) -> None:
        self.entities: list[str] = []

    def add(self, text: str) -> int:
        self.entities.append(f"#{len(self.entities) + 1}={text};")
        return len(self.entities)


def _add_context(data: _Data) -> int:
    """The geometric representation context: 3D, millimetres, radians, and the distance uncertainty."""
    mm = data.add("(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT(.MILLI.,.METRE.))")
    rad = data.add("(NAMED_UNIT(*)PLANE_ANGLE_UNIT()SI_UNIT($,.RADIAN.))")
    sr = data.add("(NAMED_UNIT(*)SI_UNIT($,.STERADIAN.)SOLID_ANGLE_UNIT())")
    eps = data.add(f"UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE({_real(_UNCERTAINTY_MM)}),#{mm},"
                   "'distance_accuracy_value','maximum distance between points that are one')")
    # A complex instance: its partial entities in alphabetical order, as Part 21 requires.
    return data.add(f"(GEOMETRIC_REPRESENTATION_CONTEXT(3)GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT((#{eps}))"
                    f"GLOBAL_UNIT_ASSIGNED_CONTEXT((#{mm},#{rad},#{sr}))"
                    "REPRESENTATION_CONTEXT('3D','3D context in millimetres'))")


def _add_product(data: _Data, shape: int, product: str) -> None:
    """The AP214 product structure through which importers find `shape`."""
    app = data.add("APPLICATION_CONTEXT('core data for automotive mechanical design processes')")
    data.add(f"APPLICATION_PROTOCOL_DEFINITION('international standard','automotive_design',2000,#{app})")
    pc = data.add(f"PRODUCT_CONTEXT('',#{app},'mechanical')")
    prod = data.add(f"PRODUCT({_string(product)},{_string(product)},'',(#{pc}))")
    data.add(f"PRODUCT_RELATED_PRODUCT_CATEGORY('part',$,(#{prod}))")
    formation = data.add(f"PRODUCT_DEFINITION_FORMATION('','',#{prod})")
    pdc = data.add(f"PRODUCT_DEFINITION_CONTEXT('part definition',#{app},'design')")
    definition = data.add(f"PRODUCT_DEFINITION('design','',#{formation},#{pdc})")
    pds = data.add(f"PRODUCT_DEFINITION_SHAPE('','',#{definition})")
    data.add(f"SHAPE_DEFINITION_REPRESENTATION(#{pds},#{shape})")


def _add_face_shell(data: _Data, surf, name: str) -> int:
    """One surface as an ADVANCED_FACE bounded by its four border edges, in an OPEN_SHELL; the shell's id."""
    try:
        # Clamped knots (checked there) make the border edges the net's outer rows.
        checked = make_bspline_surface(surf.control_points, surf.knots_u, surf.knots_v, degree=surf.degree)
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from exc
    (p, q), ku, kv, cp = checked.degree, checked.knots_u, checked.knots_v, checked.control_points
    nu, nv = cp.shape[:2]
    coords = [_finite_real(x) for x in cp.reshape(-1).tolist()]  # finite: checked above
    points = np.array([data.add(f"CARTESIAN_POINT('',({','.join(coords[3 * k:3 * k + 3])}))")
                       for k in range(nu * nv)]).reshape(nu, nv)
    net = ",".join(f"({_refs(row)})" for row in points)
    u_closed, v_closed = _logical(np.array_equal(cp[0], cp[-1])), _logical(np.array_equal(cp[:, 0], cp[:, -1]))
    surface = data.add(f"B_SPLINE_SURFACE_WITH_KNOTS({_string(name)},{p},{q},({net}),.UNSPECIFIED.,{u_closed},"
                       f"{v_closed},.U.,{_knots(ku)[0]},{_knots(kv)[0]},{_knots(ku)[1]},{_knots(kv)[1]},"
                       ".UNSPECIFIED.)")
    corner = {(a, b): data.add(f"VERTEX_POINT('',#{points[a, b]})") for a in (0, -1) for b in (0, -1)}

    def edge(start: tuple[int, int], end: tuple[int, int], refs: np.ndarray, knots: np.ndarray, degree: int) -> int:
        closed = _logical(np.array_equal(cp[start], cp[end]))
        mults, values = _knots(knots)
        curve = data.add(f"B_SPLINE_CURVE_WITH_KNOTS('',{degree},({_refs(refs)}),.UNSPECIFIED.,{closed},.U.,"
                         f"{mults},{values},.UNSPECIFIED.)")
        return data.add(f"EDGE_CURVE('',#{corner[start]},#{corner[end]},#{curve},.T.)")

    # Counter-clockwise in (u, v) seen along the normal S_u x S_v: v = v0 forward, u = u1 forward, then
    # v = v1 and u = u0 backward; the face's normal is then the surface's (same_sense .T.).
    loop = [(edge((0, 0), (-1, 0), points[:, 0], ku, p), ".T."),
            (edge((-1, 0), (-1, -1), points[-1, :], kv, q), ".T."),
            (edge((0, -1), (-1, -1), points[:, -1], ku, p), ".F."),
            (edge((0, 0), (0, -1), points[0, :], kv, q), ".F.")]
    oriented = [data.add(f"ORIENTED_EDGE('',*,*,#{e},{sense})") for e, sense in loop]
    edge_loop = data.add(f"EDGE_LOOP('',({_refs(oriented)}))")
    bound = data.add(f"FACE_OUTER_BOUND('',#{edge_loop},.T.)")
    face = data.add(f"ADVANCED_FACE({_string(name)},(#{bound}),#{surface},.T.)")
    return data.add(f"OPEN_SHELL({_string(name)},(#{face}))")


def _knots(knots: np.ndarray) -> tuple[str, str]:
    """STEP's knot lists: (multiplicities, distinct values) as attribute text."""
    values, counts = np.unique(knots, return_counts=True)
    return "(" + ",".join(str(int(c)) for c in counts) + ")", "(" + _reals(values) + ")"


def _logical(flag: bool) -> str:
    return ".T." if flag else ".F."


def _refs(ids) -> str:
    return ",".join(f"#{int(i)}" for i in np.ravel(ids))


def _reals(values) -> str:
    values = np.ravel(values)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"STEP cannot store {values[~np.isfinite(values)][0]}")
    return ",".join(map(_finite_real, values.tolist()))


def _real(x: float) -> str:
    """Shortest round-trip text of a float in Part 21's REAL form: a digit, a point, optional exponent."""
    x = float(x)
    if not np.isfinite(x):
        raise ValueError(f"STEP cannot store {x}")
    return _finite_real(x)


def _finite_real(x: float) -> str:
    mantissa, _, exponent = repr(x).upper().partition("E")
    if "." not in mantissa:
        mantissa += "."
    return mantissa + ("E" + exponent if exponent else "")


def _string(text: str) -> str:
    """A Part 21 string literal: quotes and backslashes doubled, characters outside printable ASCII as
    \\X2\\ (16-bit) or \\X4\\ (32-bit) hex runs."""
    out = []
    for ch in text:
        code = ord(ch)
        if ch in "'\\":
            out.append(ch * 2)
        elif 0x20 <= code <= 0x7E:
            out.append(ch)
        elif code <= 0xFFFF:
            out.append(f"\\X2\\{code:04X}\\X0\\")
        else:
            out.append(f"\\X4\\{code:08X}\\X0\\")
    return "'" + "".join(out) + "'"


def _wrap(text: str) -> list[str]:
    """An entity's text broken into lines of at most `_WIDTH` characters after commas or closing
    parentheses outside strings (Part 21 allows white space between tokens; a longer token stays whole)."""
    if len(text) <= _WIDTH:
        return [text]
    lines, current = [], ""
    for piece in _PIECE.findall(text):
        if current and len(current) + len(piece) > _WIDTH:
            lines.append(current)
            current = ""
        current += piece
    lines.append(current)
    return lines
