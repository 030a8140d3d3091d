"""Load a whole input file, turning file-system failures into :class:`ReadError`."""

from __future__ import annotations

import os

from cam.io.errors import ReadError

__all__ = ["read_bytes"]


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
    try:
        with open(path, "rb") as handle:
            return handle.read()
    except FileNotFoundError:
        raise ReadError(f"{os.fspath(path)} does not exist") from None
    except IsADirectoryError:
        raise ReadError(f"{os.fspath(path)} is a directory, not a file") from None
