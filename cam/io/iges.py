"""IGES 5.3 export of B-spline surfaces: one rational B-spline surface entity (type 128) each, in mm.

An IGES file is fixed-format 80-column text in five sections: Start (S, free text),
Global (G, delimiters, units, precision, dates), Directory Entry (D, two lines per
entity pointing at its parameters), Parameter Data (P, the entity's numbers) and
Terminate (T, the section counts). Columns 73-80 of every line hold the section
letter and its line number.

Entity 128 parameters, in order: K1, K2 (upper control-point indices), M1, M2
(degrees), PROP1..PROP5 (closed in u, closed in v, polynomial, periodic in u,
periodic in v), the u knots, the v knots, the weights and then the control
points with the u index varying fastest, and the parameter range u0, u1, v0, v1.
Our surfaces are polynomial, so every weight is 1 and PROP3 = 1.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from cam.io.atomic import atomic_write

__all__ = ["iges_bytes", "write_iges"]

_DATA_COLS = 72
_PARAM_COLS = 64


def write_iges(path: str | os.PathLike[str], surfaces: Sequence, *, labels: Sequence[int] | None = None,
               created: datetime | None = None, author: str = "cloud2cnc", organization: str = "",
               product: str = "cloud2cnc surfaces") -> Path:
    """Write surfaces to `path` atomically as an IGES 5.3 file; see `iges_bytes`.

    Parameters
    ----------
    path : str or os.PathLike
        The target file; its name is stored in the Global section.
    surfaces : sequence
        Objects with degree, knots_u, knots_v, control_points (nu, nv, 3) in mm, like
        `cam.spline.surface.BSplineSurface`.
    labels : sequence of int or None, optional
        An integer per surface stored as its entity subscript (the patch id; default the index).
    created : datetime or None, optional
        The file's timestamp (default now, UTC).
    author, organization : str, optional
        Stored in the Global section ("unknown" when empty).
    product : str, optional
        Stored in the Start and Global sections.

    Returns
    -------
    path : pathlib.Path
        The path written.

    Raises
    ------
    ValueError
        As `iges_bytes`.
    """
    data = iges_bytes(surfaces, labels=labels, created=created, author=author, organization=organization,
                      product=product, filename=Path(path).name)
    return atomic_write(path, [data])


def iges_bytes(surfaces: Sequence, *, labels: Sequence[int] | None = None, created: datetime | None = None,
               author: str = "cloud2cnc", organization: str = "", product: str = "cloud2cnc surfaces",
               filename: str = "surfaces.igs") -> bytes:
    """The IGES 5.3 file as bytes (ASCII, CRLF-free, 80 columns).

    Parameters
    ----------
    surfaces : sequence
        Objects with degree (p, q), knots_u (nu + p + 1,), knots_v (nv + q + 1,) and control_points
        (nu, nv, 3) in mm, like `cam.spline.surface.BSplineSurface`: clamped B-splines with finite
        coordinates. Each becomes one entity 128 with every weight 1.
    labels : sequence of int or None, optional
        An integer per surface stored as its entity subscript (the patch id; default the index).
    created : datetime or None, optional
        The file's timestamp (default now, UTC).
    author, organization : str, optional
        Stored in the Global section ("unknown" when empty).
    product : str, optional
        Stored in the Start and Global sections.
    filename : str, optional
        The file name stored in the Global section (default "surfaces.igs").

    Returns
    -------
    data : bytes
        The file, lines ending in '\\n'; units millimetres.

    Raises
    ------
    ValueError
        For a label count that differs from the surface count, control points not shaped (nu, nv, 3),
        knot counts that do not fit them, a non-finite knot or coordinate, or a text field too long for
        an IGES line.
    """
    labels = list(range(len(surfaces))) if labels is None else [int(x) for x in labels]
    if len(labels) != len(surfaces):
        raise ValueError(f"need one label per surface, got {len(labels)} for {len(surfaces)}")
    stamp = (created or datetime.now(timezone.utc)).strftime("%Y%m%d.%H%M%S")
    extent = max([float(np.abs(np.asarray(s.control_points)).max()) for s in surfaces] + [1.0])
    start = [f"{product}: {len(surfaces)} B-spline surfaces (entity 128), millimetres"]
    glob = _global_section(filename=filename, stamp=stamp, extent=extent, author=author,
                           organization=organization, product=product)
    directory: list[str] = []
    params: list[str] = []
    for k, (surf, label) in enumerate(zip(surfaces, labels)):
        de_line = 2 * k + 1
        lines = _wrap(_surface_params(surf), back_pointer=de_line, first_line=len(params) + 1)
        directory += _directory_entry(entity=128, param_start=len(params) + 1, param_lines=len(lines),
                                      label="PATCH", subscript=label, seq=de_line)
        params += lines
    out = [_line(text, "S", i + 1) for i, text in enumerate(start)]
    out += [_line(text, "G", i + 1) for i, text in enumerate(glob)]
    out += directory
    out += params
    counts = f"S{len(start):7d}G{len(glob):7d}D{len(directory):7d}P{len(params):7d}"
    out.append(_line(counts, "T", 1))
    return ("\n".join(out) + "\n").encode("ascii")


def _line(text: str, section: str, seq: int) -> str:
    if len(text) > _DATA_COLS:
        raise ValueError(f"IGES line longer than {_DATA_COLS} columns: {text!r}")
    return f"{text:<{_DATA_COLS}}{section}{seq:7d}"


def _hollerith(text: str) -> str:
    text = text.encode("ascii", "replace").decode("ascii")
    return f"{len(text)}H{text}"


def _real(x: float) -> str:
    """Shortest round-trip text of a float, always with a decimal point (IGES real constant)."""
    x = float(x)
    if not np.isfinite(x):
        raise ValueError(f"IGES cannot store {x}")
    text = repr(x).upper()
    mantissa, _, exponent = text.partition("E")
    if "." not in mantissa:
        mantissa += ".0"
    return mantissa + ("E" + exponent if exponent else "")


def _global_section(*, filename: str, stamp: str, extent: float, author: str, organization: str,
                    product: str) -> list[str]:
    fields = [
        "1H,", "1H;", _hollerith(product), _hollerith(filename), _hollerith("cloud2cnc"),
        _hollerith("cloud2cnc fit"), "32", "38", "6", "308", "15", _hollerith(product),
        "1.0", "2", _hollerith("MM"), "1", "1.0", _hollerith(stamp), "1.0E-6", _real(extent),
        _hollerith(author or "unknown"), _hollerith(organization or "unknown"), "11", "0", _hollerith(stamp),
    ]
    return _pack(fields, _DATA_COLS)


def _pack(tokens: list[str], width: int) -> list[str]:
    """Tokens joined by ',' and ended by ';', broken into lines between tokens."""
    lines, current = [], ""
    for i, tok in enumerate(tokens):
        piece = tok + (";" if i == len(tokens) - 1 else ",")
        if len(piece) > width:
            raise ValueError(f"IGES token longer than a line: {tok!r}")
        if len(current) + len(piece) > width:
            lines.append(current)
            current = ""
        current += piece
    if current:
        lines.append(current)
    return lines


def _surface_params(surf) -> list[str]:
    p, q = (int(d) for d in surf.degree)
    ku = np.asarray(surf.knots_u, dtype=np.float64)
    kv = np.asarray(surf.knots_v, dtype=np.float64)
    cp = np.asarray(surf.control_points, dtype=np.float64)
    if cp.ndim != 3 or cp.shape[2] != 3:
        raise ValueError(f"control points must have shape (nu, nv, 3), got {cp.shape}")
    nu, nv = cp.shape[:2]
    if ku.size != nu + p + 1 or kv.size != nv + q + 1:
        raise ValueError(f"knot counts {ku.size}, {kv.size} do not fit {nu} x {nv} control points of degree {(p, q)}")
    tokens = ["128", str(nu - 1), str(nv - 1), str(p), str(q), "0", "0", "1", "0", "0"]
    tokens += [_real(t) for t in ku] + [_real(t) for t in kv]
    tokens += ["1.0"] * (nu * nv)
    # Control points with the u index varying fastest: iterate v outside, u inside.
    tokens += [_real(c) for c in np.swapaxes(cp, 0, 1).reshape(-1)]
    tokens += [_real(ku[p]), _real(ku[-p - 1]), _real(kv[q]), _real(kv[-q - 1])]
    return tokens


def _wrap(tokens: Iterable[str], *, back_pointer: int, first_line: int) -> list[str]:
    lines = _pack(list(tokens), _PARAM_COLS)
    return [_line(f"{text:<{_PARAM_COLS}} {back_pointer:7d}", "P", first_line + i) for i, text in enumerate(lines)]


def _directory_entry(*, entity: int, param_start: int, param_lines: int, label: str, subscript: int,
                     seq: int) -> list[str]:
    one = f"{entity:8d}{param_start:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{'00000000':>8}"
    two = f"{entity:8d}{0:8d}{0:8d}{param_lines:8d}{0:8d}{'':8}{'':8}{label[:8]:>8}{subscript:8d}"
    return [_line(one, "D", seq), _line(two, "D", seq + 1)]
