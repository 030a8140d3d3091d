"""Read any supported upload, recognising its format from its content."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from cam.io._files import read_head
from cam.io.e57 import read_e57
from cam.io.errors import ReadError
from cam.io.formats import SNIFF_BYTES, describe_unsupported, sniff_format
from cam.io.las import read_las
from cam.io.mesh import read_obj, read_stl
from cam.io.pcd import read_pcd
from cam.io.ply import read_ply
from cam.io.records import InputData
from cam.io.text import read_xyz

__all__ = ["read_input"]

_READERS: dict[str, Callable[[str | os.PathLike[str]], InputData]] = {
    "ply": read_ply,
    "obj": read_obj,
    "stl_ascii": read_stl,
    "stl_binary": read_stl,
    "pcd": read_pcd,
    "xyz": read_xyz,
}
# Scanner formats declare (or stream) far more points than their bytes suggest, so their readers take the
# point limit and refuse before decoding a file that cannot pass it.
_CAPPED_READERS: dict[str, Callable[..., InputData]] = {
    "e57": read_e57,
    "las": read_las,
    "laz": read_las,
}
# The formats read, as error messages list them.
_READ_FORMATS = "PLY, XYZ/PTS/TXT/CSV, PCD, E57, LAS/LAZ, OBJ, STL"


def read_input(path: str | os.PathLike[str], *, max_points: int | None = None) -> InputData:
    """Read a point cloud or mesh upload of any supported format.

    The format comes from the first :data:`~cam.io.formats.SNIFF_BYTES` bytes and the file size, never
    from the file name, so a renamed or extension-less upload reads the same.

    Parameters
    ----------
    path : str or os.PathLike
        The uploaded file.
    max_points : int or None, keyword-only
        The operator's point limit, handed to the E57 and LAS/LAZ readers so that they refuse a file over it
        before decoding it; the other formats are checked by :func:`cam.ingest.clean_cloud` after reading.

    Returns
    -------
    data : InputData
        See :class:`~cam.io.records.InputData`; ``faces`` is None for a point cloud.

    Raises
    ------
    ReadError
        For a missing file or a directory, an empty file, a format we do not read (saying what it looks
        like when it can), a file that holds no points, or any reader's complaint about the content.
    """
    target = Path(path)
    head, size = read_head(target, SNIFF_BYTES)
    if size == 0 or not head.strip():
        raise ReadError("the file is empty")
    kind = sniff_format(head, total_size=size)
    if kind is None:
        what = describe_unsupported(head)
        looks = f"; it looks like {what}" if what else ""
        raise ReadError(
            f"{target.name} is not a point cloud or mesh format we read "
            f"({_READ_FORMATS}){looks}"
        )
    if kind in _CAPPED_READERS:
        data = _CAPPED_READERS[kind](target, max_points=max_points)
    else:
        data = _READERS[kind](target)
    if len(data.points) == 0:
        raise ReadError(f"{target.name} holds no points")
    return data
