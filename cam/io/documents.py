"""The JSON artifacts: written atomically, and read back into the records later stages use.

`read_surfaces` and `read_setups` raise `ReadError` naming the entry that is not what the stage
before wrote, so a stage that reads them can tell the user which file is wrong.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from cam.gcode.setup import Setup
from cam.io.atomic import atomic_write
from cam.io.errors import ReadError
from cam.spline.surface import BSplineSurface, surface_from_json

__all__ = ["read_json", "read_setups", "read_surfaces", "write_json"]


def write_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write `obj` as indented JSON to `path` through a temporary name beside it.

    Parent directories are created as needed; the write is atomic (see `atomic_write`).

    Parameters
    ----------
    path : str or os.PathLike
        The target file.
    obj : object
        Anything `json.dumps` accepts; written with an indent of 2 and a final newline.

    Returns
    -------
    path : pathlib.Path
        The path written.
    """
    text = json.dumps(obj, indent=2, sort_keys=False) + "\n"
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return atomic_write(path, [text.encode()])


def read_json(path: str | os.PathLike[str]) -> Any:
    """The JSON document in `path`.

    Parameters
    ----------
    path : str or os.PathLike
        The file to read.

    Returns
    -------
    document : object
        The parsed JSON value.

    Raises
    ------
    ReadError
        Naming the file when it is missing or unreadable, not UTF-8, or not JSON.
    """
    try:
        return json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReadError(f"{Path(path).name} is not a readable JSON document: {exc}") from exc


def read_surfaces(path: str | os.PathLike[str]) -> tuple[list[int], list[BSplineSurface]]:
    """Patch ids and B-spline surfaces of a `surfaces.json`, in file order.

    Parameters
    ----------
    path : str or os.PathLike
        The `surfaces.json` file.

    Returns
    -------
    ids : list of int
        The ``patch`` of each entry (default: its index).
    surfaces : list of BSplineSurface
        The surfaces in the part frame, mm. A document that is not an object or has no ``surfaces``
        gives two empty lists.

    Raises
    ------
    ReadError
        When the file is not readable JSON, or naming the entry that is not a valid B-spline surface.
    """
    doc = read_json(path)
    ids, surfaces = [], []
    for k, entry in enumerate(doc.get("surfaces", []) if isinstance(doc, dict) else []):
        try:
            surfaces.append(surface_from_json(entry))
            ids.append(int(entry.get("patch", k)))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ReadError(f"surfaces.json entry {k} is not a valid B-spline surface: {exc}") from exc
    return ids, surfaces


def read_setups(path: str | os.PathLike[str]) -> tuple[dict[str, Any], list[Setup]]:
    """The `setup.json` document and its setups (rigid part-to-machine transforms), in file order.

    Parameters
    ----------
    path : str or os.PathLike
        The `setup.json` file.

    Returns
    -------
    document : dict
        The whole parsed document.
    setups : list of Setup
        One per entry of ``setups``: ``id`` (default its 1-based position), ``rotation`` (3, 3) float64
        and ``translation`` (3,) float64 in mm. Empty when the document is not an object or has no
        ``setups``.

    Raises
    ------
    ReadError
        When the file is not readable JSON, or naming the setup that lacks a 3x3 rotation and a
        translation.
    """
    doc = read_json(path)
    setups = []
    for k, entry in enumerate(doc.get("setups", []) if isinstance(doc, dict) else []):
        try:
            setups.append(Setup(id=int(entry.get("id", k + 1)),
                                rotation=np.asarray(entry["rotation"], float).reshape(3, 3),
                                translation=np.asarray(entry["translation"], float).reshape(3)))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ReadError(f"setup.json setup {k} needs a 3x3 rotation and a translation: {exc}") from exc
    return doc, setups
