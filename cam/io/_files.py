"""Load an input file, or its first bytes, turning file-system failures into :class:`ReadError`."""

from __future__ import annotations

import os

from cam.io.errors import ReadError

__all__ = ["read_bytes", "read_head"]


def read_bytes(path: str | os.PathLike[str]) -> bytes:
    """Return a whole file's bytes.

    Parameters
    ----------
    path : str or os.PathLike
        The file to read.

    Returns
    -------
    data : bytes
        The file's content.

    Raises
    ------
    ReadError
        For a missing file or a directory, naming the path.
    """
    return _read(path, -1)[0]


def read_head(path: str | os.PathLike[str], size: int) -> tuple[bytes, int]:
    """Return a file's first `size` bytes (fewer when it is shorter) and its whole length in bytes.

    Raises
    ------
    ReadError
        As `read_bytes`.
    """
    return _read(path, size)


def _read(path: str | os.PathLike[str], size: int) -> tuple[bytes, int]:
    try:
        with open(path, "rb") as handle:
            return handle.read(size), os.fstat(handle.fileno()).st_size
    except FileNotFoundError:
        raise ReadError(f"{os.fspath(path)} does not exist") from None
    except IsADirectoryError:
        raise ReadError(f"{os.fspath(path)} is a directory, not a file") from None
