"""Readers and writers for point clouds and meshes (the only file I/O in :mod:`cam`).

Names are loaded on first use: the web service imports :mod:`cam.io.formats`
to vet uploads, and importing this package must not pull numpy into it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "atomic_write": "cam.io.atomic",
    "ReadError": "cam.io.errors",
    "WriteError": "cam.io.errors",
    "FORMATS": "cam.io.formats",
    "FORMAT_EXTENSIONS": "cam.io.formats",
    "SNIFF_BYTES": "cam.io.formats",
    "describe_unsupported": "cam.io.formats",
    "sniff_format": "cam.io.formats",
    "read_obj": "cam.io.mesh",
    "read_stl": "cam.io.mesh",
    "read_e57": "cam.io.e57",
    "read_las": "cam.io.las",
    "read_pcd": "cam.io.pcd",
    "read_ply": "cam.io.ply",
    "write_ply_mesh": "cam.io.ply",
    "write_ply_points": "cam.io.ply",
    "read_input": "cam.io.read",
    "InputData": "cam.io.records",
    "read_xyz": "cam.io.text",
    "read_json": "cam.io.documents",
    "read_setups": "cam.io.documents",
    "read_surfaces": "cam.io.documents",
    "write_json": "cam.io.documents",
}

__all__ = [
    "FORMATS",
    "FORMAT_EXTENSIONS",
    "SNIFF_BYTES",
    "InputData",
    "ReadError",
    "WriteError",
    "atomic_write",
    "describe_unsupported",
    "read_e57",
    "read_input",
    "read_json",
    "read_las",
    "read_obj",
    "read_pcd",
    "read_ply",
    "read_setups",
    "read_stl",
    "read_surfaces",
    "read_xyz",
    "sniff_format",
    "write_json",
    "write_ply_mesh",
    "write_ply_points",
]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'cam.io' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:
    from cam.io.atomic import atomic_write
    from cam.io.e57 import read_e57
    from cam.io.errors import ReadError, WriteError
    from cam.io.formats import (
        FORMAT_EXTENSIONS,
        FORMATS,
        SNIFF_BYTES,
        describe_unsupported,
        sniff_format,
    )
    from cam.io.las import read_las
    from cam.io.mesh import read_obj, read_stl
    from cam.io.pcd import read_pcd
    from cam.io.ply import read_ply, write_ply_mesh, write_ply_points
    from cam.io.read import read_input
    from cam.io.records import InputData
    from cam.io.text import read_xyz
