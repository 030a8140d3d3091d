"""Read numeric text columns: XYZ, PTS, TXT and CSV point clouds.

Column rule
-----------
Columns may be separated by spaces, tabs, commas or semicolons (mixed is fine);
decimals use a point. Non-numeric lines before the first numeric row are header
lines; a single integer right after them (and before each further scan block,
as Leica ``.pts`` writes) is a point count. ``#`` lines are comments anywhere.

When the last header line names every column, names decide: ``x y z``,
``nx ny nz`` (or ``normal_x``...), ``r g b`` (or ``red``...). Otherwise columns
1-3 are x y z and the rest is judged from the values:

* three columns *look like colours* when every value is an integer in 0..255
  and some value exceeds 1 (so axis-aligned normals such as ``0 0 1`` are
  never taken for colours);
* three columns *look like normals* when at least 90 % of the rows are vectors
  of length 0.9..1.1;
* colours are looked for at columns 5-7 then 4-6 when there are seven columns
  (the PTS layout ``x y z intensity r g b``), else at 4-6 then 7-9; normals
  at columns 4-6, then 7-9, where colours are not;
* anything else (intensity, scalar fields, unit-less vectors) is ignored, and
  :attr:`InputData.notes` says which columns were ignored and how to label them.

NaN and Inf tokens are kept as such so that the ingest step can drop and count
them.
"""

from __future__ import annotations

import io
import os
import re

import numpy as np

from cam.io._files import read_bytes
from cam.io.errors import ReadError
from cam.io.records import InputData

__all__ = ["read_xyz"]

_SEPARATORS = bytes.maketrans(b",;\t\r", b"    ")
_NUMBER = re.compile(
    rb"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)\Z", re.IGNORECASE
)
_INTEGER = re.compile(rb"[+-]?\d+\Z")
_MAX_HEADER_LINES = 1000
_ALIASES = {
    "x": "x", "y": "y", "z": "z",
    "point_x": "x", "point_y": "y", "point_z": "z",
    "nx": "nx", "ny": "ny", "nz": "nz",
    "normal_x": "nx", "normal_y": "ny", "normal_z": "nz",
    "normalx": "nx", "normaly": "ny", "normalz": "nz",
    "r": "r", "g": "g", "b": "b",
    "red": "r", "green": "g", "blue": "b",
}  # fmt: skip


def read_xyz(path: str | os.PathLike[str]) -> InputData:
    """Read a point cloud stored as numeric text columns (see the module docstring for the column rule).

    Parameters
    ----------
    path : str or os.PathLike
        The text file (XYZ, PTS, TXT, CSV).

    Returns
    -------
    data : InputData
        ``points`` (n, 3) float64, ``normals`` (n, 3) float64 or None, ``colors`` (n, 3) uint8 or None,
        ``faces`` None, ``format`` ``"xyz"``, the header lines as ``comments``, and ``notes`` on which
        columns were read as what and which were ignored.

    Raises
    ------
    ReadError
        For a missing file, when no numeric row exists, rows have fewer than 3 columns, a row's column
        count differs from the first row's, a token is not a number (the message names the line), or a
        ``.pts`` count exceeds the rows that follow.
    """
    raw = read_bytes(path)
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    if b"\n" not in raw and b"\r" in raw:
        raw = raw.replace(b"\r", b"\n")  # classic Mac line endings
    text = raw.translate(_SEPARATORS)
    header, start, first_line = _split_header(text, raw)
    declared = None
    end = text.find(b"\n", start)
    end = len(text) if end < 0 else end
    if _INTEGER.match(text[start:end].strip()):
        declared = int(text[start:end])
        start = end + 1
        first_line += 1
    table = _parse_rows(text[start:], first_line, declared)
    if table.shape[1] < 3:
        raise ReadError(
            f"rows have {table.shape[1]} column(s) (line {first_line}); "
            "a point needs at least x y z columns"
        )
    names = _column_names(header[-1] if header else None, table.shape[1])
    points, normals, colors, notes = _interpret(table, names)
    comments = tuple(line.decode("utf-8", errors="replace") for line in header)
    return InputData(
        points=points,
        normals=normals,
        colors=colors,
        faces=None,
        format="xyz",
        comments=comments,
        notes=tuple(notes),
    )


def _is_numeric(tokens: list[bytes]) -> bool:
    return bool(tokens) and all(_NUMBER.match(t) for t in tokens)


def _split_header(text: bytes, raw: bytes) -> tuple[list[bytes], int, int]:
    """Find the first numeric line; return the header lines, its byte offset and its line number."""
    header: list[bytes] = []
    position = 0
    number = 1
    while position < len(text):
        end = text.find(b"\n", position)
        end = len(text) if end < 0 else end
        line = text[position:end].strip()
        if line and not line.startswith(b"#") and _is_numeric(line.split()):
            return header, position, number
        if line:
            # Separators were blanked in `text`; keep the header line as the file wrote it.
            header.append(raw[position:end].strip())
            if len(header) > _MAX_HEADER_LINES:
                break
        position = end + 1
        number += 1
    raise ReadError(
        "no row of numbers found"
        + (f" in the first {_MAX_HEADER_LINES} lines" if len(header) > _MAX_HEADER_LINES else "")
        + "; expected lines of x y z values separated by spaces, tabs, commas or semicolons"
    )


def _parse_rows(body: bytes, first_line: int, declared: int | None) -> np.ndarray:
    """Parse the numeric rows; fast when regular, line by line to explain the first bad row."""
    try:
        table = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments="#")
    except ValueError:
        table = None
    if table is not None and table.size:
        if declared is not None and len(table) < declared:
            raise ReadError(
                f"the count line declares {declared} points but only {len(table)} rows follow "
                "(file truncated?)"
            )
        return table
    return _parse_rows_slowly(body, first_line, declared)


def _parse_rows_slowly(body: bytes, first_line: int, declared: int | None) -> np.ndarray:
    rows: list[list[bytes]] = []
    columns = None
    columns_line = first_line
    blocks = declared is not None
    block_line, block_declared, block_rows = first_line - 1, declared, 0
    for number, line in enumerate(body.split(b"\n"), start=first_line):
        tokens = line.split()
        if not tokens or tokens[0].startswith(b"#"):
            continue
        if blocks and len(tokens) == 1 and _INTEGER.match(tokens[0]):
            _check_block(block_declared, block_rows, block_line)
            block_line, block_declared, block_rows = number, int(tokens[0]), 0
            continue
        bad = next((t for t in tokens if not _NUMBER.match(t)), None)
        if bad is not None:
            raise ReadError(
                f"line {number}: {bad.decode(errors='replace')!r} is not a number; "
                "every row after the header must hold only numbers"
            )
        if columns is None:
            columns, columns_line = len(tokens), number
        elif len(tokens) != columns:
            raise ReadError(
                f"line {number} has {len(tokens)} columns but line {columns_line} has {columns}; "
                "every row needs the same columns"
            )
        rows.append(tokens)
        block_rows += 1
    _check_block(block_declared, block_rows, block_line)
    if not rows:
        raise ReadError("no row of numbers found after the header; the file holds no points")
    return np.array(rows, dtype=np.float64)


def _check_block(declared: int | None, rows: int, line: int) -> None:
    if declared is not None and rows < declared:
        raise ReadError(
            f"the count on line {line} declares {declared} points but only {rows} rows follow "
            "(file truncated?)"
        )


def _column_names(line: bytes | None, columns: int) -> list[str] | None:
    if line is None:
        return None
    line = line.translate(_SEPARATORS).lstrip(b"#/ ")
    names = [t.strip(b"\"'").decode("utf-8", errors="replace").lower() for t in line.split()]
    if len(names) != columns or not {"x", "y", "z"} <= {_ALIASES.get(n) for n in names}:
        return None
    return [_ALIASES.get(n, n) for n in names]


def _interpret(table: np.ndarray, names: list[str] | None):
    columns = table.shape[1]
    notes: list[str] = []
    if names is not None:
        where = {name: i for i, name in reversed(list(enumerate(names)))}
        points = table[:, [where["x"], where["y"], where["z"]]]
        normals = None
        if {"nx", "ny", "nz"} <= where.keys():
            normals = table[:, [where[n] for n in ("nx", "ny", "nz")]]
        rgb = [where[c] for c in "rgb"] if set("rgb") <= where.keys() else None
        colors = _to_colors(table[:, rgb]) if rgb is not None else None
        used = {where["x"], where["y"], where["z"]}
        used |= {where[n] for n in ("nx", "ny", "nz")} if normals is not None else set()
        used |= set(rgb or ())
        ignored = [names[i] for i in range(columns) if i not in used]
        if ignored:
            notes.append(f"columns ignored: {', '.join(ignored)}")
        return np.ascontiguousarray(points), normals, colors, notes
    points = np.ascontiguousarray(table[:, :3])
    # Seven columns are the PTS layout x y z intensity r g b; intensity may itself be 0..255.
    colour_starts = (4, 3) if columns == 7 else (3, 6)
    colors_at = next(
        (s for s in colour_starts if s + 3 <= columns and _colour_like(table[:, s : s + 3])),
        None,
    )
    taken = set(range(colors_at, colors_at + 3)) if colors_at is not None else set()
    normals_at = next(
        (
            s
            for s in (3, 6)
            if s + 3 <= columns and not taken & set(range(s, s + 3)) and _unit_like(table[:, s : s + 3])
        ),
        None,
    )
    colors = _to_colors(table[:, colors_at : colors_at + 3]) if colors_at is not None else None
    normals = None
    if normals_at is not None:
        normals = np.ascontiguousarray(table[:, normals_at : normals_at + 3])
    if colors_at is not None:
        notes.append(f"columns {colors_at + 1}-{colors_at + 3} read as RGB colours")
        taken |= set(range(colors_at, colors_at + 3))
    if normals_at is not None:
        notes.append(f"columns {normals_at + 1}-{normals_at + 3} read as normals")
        taken |= set(range(normals_at, normals_at + 3))
    ignored = [i + 1 for i in range(3, columns) if i not in taken]
    if ignored:
        which = f"column {ignored[0]}" if len(ignored) == 1 else f"columns {', '.join(map(str, ignored))}"
        notes.append(
            f"{which} ignored (not colours or unit normals); "
            "to use them, add a header line naming the columns, e.g. 'x y z nx ny nz'"
        )
    return points, normals, colors, notes


def _finite_rows(values: np.ndarray) -> np.ndarray:
    return values[np.isfinite(values).all(axis=1)]


def _colour_like(values: np.ndarray) -> bool:
    finite = _finite_rows(values)
    return (
        len(finite) > 0
        and bool(np.all(finite == np.round(finite)))
        and finite.min() >= 0
        and finite.max() <= 255
        and finite.max() > 1
    )


def _unit_like(values: np.ndarray) -> bool:
    finite = _finite_rows(values)
    if len(finite) == 0:
        return False
    lengths = np.linalg.norm(finite, axis=1)
    return bool(np.mean((lengths >= 0.9) & (lengths <= 1.1)) >= 0.9)


def _to_colors(values: np.ndarray) -> np.ndarray:
    clean = np.nan_to_num(values, nan=0.0, posinf=255.0, neginf=0.0)
    if clean.size and clean.max() <= 1.0 and not np.all(clean == np.round(clean)):
        clean = clean * 255.0  # 0..1 float colours
    return np.clip(np.rint(clean), 0, 255).astype(np.uint8)
