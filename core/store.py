"""Content-addressed artifact store: a file's name is its SHA-256.

Files are written to a temporary name in the store and renamed into place,
so a reader never sees half a file and two writers of the same bytes agree.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from pathlib import Path

_CHUNK = 1 << 20


def hash_file(path: Path) -> tuple[str, int]:
    """SHA-256 hex digest and size in bytes of a file, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            digest.update(chunk)
            size += len(chunk)
    return digest.hexdigest(), size


class ArtifactStore:
    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, sha256: str) -> Path:
        if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
            raise ValueError(f"not a SHA-256 hex digest: {sha256!r}")
        return self.root / sha256[:2] / sha256

    def exists(self, sha256: str) -> bool:
        return self.path(sha256).is_file()

    def put(self, src: Path, *, sha256: str | None = None, move: bool = False) -> tuple[str, int]:
        """Add a file; returns (sha256, size). `move` consumes `src` when it is on the same disk."""
        if sha256 is None:
            sha256, size = hash_file(src)
        else:
            size = src.stat().st_size
        dest = self.path(sha256)
        if dest.is_file():
            if move:
                src.unlink(missing_ok=True)
            return sha256, size
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=dest.parent, prefix=".tmp-")
        os.close(fd)
        try:
            if move:
                try:
                    os.replace(src, tmp)
                except OSError:
                    shutil.copyfile(src, tmp)
                    src.unlink(missing_ok=True)
            else:
                shutil.copyfile(src, tmp)
            os.replace(tmp, dest)
        finally:
            Path(tmp).unlink(missing_ok=True)
        return sha256, size

    def delete(self, sha256: str) -> None:
        self.path(sha256).unlink(missing_ok=True)
