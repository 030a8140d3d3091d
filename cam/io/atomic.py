"""Write a file so that readers see either nothing or the complete file."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

__all__ = ["atomic_write"]


def atomic_write(path: str | os.PathLike[str], chunks: Iterable[bytes]) -> Path:
    """Write ``chunks`` to ``path`` through a temporary file renamed into place.

    The temporary file lives in the target's directory because ``os.replace`` is atomic only within one
    file system; on any error it is removed and an existing file at ``path`` is left untouched. The file
    is made readable by other processes (mode 0644).

    Parameters
    ----------
    path : str or os.PathLike
        The target file; its directory must exist.
    chunks : iterable of bytes-like
        Written in order (bytes, or arrays written through their buffer).

    Returns
    -------
    path : pathlib.Path
        ``path`` as a Path.
    """
    target = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        # mkstemp creates the file private to its owner; artifacts are read by other processes.
        os.chmod(tmp_name, 0o644)
        with os.fdopen(fd, "wb") as handle:
            for chunk in chunks:
                handle.write(chunk)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise
    return target
