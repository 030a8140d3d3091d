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
    """Write `obj` as indented JSON to `path` through a temporary name beside it; returns the path."""
    text = json.dumps(obj, indent=2, sort_keys=False) + "\n"
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return atomic_write(path, [text.encode()])


def read_json(path: str | os.PathLike[str]) -> Any:
    """The JSON document in `path`; `ReadError` naming the file when it is missing or not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReadError(f"{Path(path).name} is not a readable JSON document: {exc}") from exc


def read_surfaces(path: str | os.PathLike[str]) -> tuple[list[int], list[BSplineSurface]]:
    """Patch ids and B-spline surfaces of a `surfaces.json` (part frame, mm), in file order."""
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
    """The `setup.json` document and its setups (rigid part-to-machine transforms), in file order."""
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
