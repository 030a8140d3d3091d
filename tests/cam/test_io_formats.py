"""Content sniffing: real files are recognised, anything else is refused."""

from __future__ import annotations

import io
import json
import struct
import subprocess
import sys
import zipfile

import numpy as np
import pytest
import trimesh

from cam.io.formats import (
    FORMAT_EXTENSIONS,
    FORMATS,
    SNIFF_BYTES,
    describe_unsupported,
    sniff_format,
)


def _sniff_whole(data: bytes) -> str | None:
    return sniff_format(data[:SNIFF_BYTES], total_size=len(data))


def _box_stl(encoding: str) -> bytes:
    box = trimesh.creation.box(extents=(10.0, 20.0, 30.0))
    return trimesh.exchange.stl.export_stl_ascii(box).encode() if encoding == "ascii" else (
        trimesh.exchange.stl.export_stl(box)
    )


def test_importing_formats_does_not_load_numpy():
    code = "import cam.io.formats, sys; assert 'numpy' not in sys.modules, 'numpy was imported'"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_every_format_has_a_stored_extension():
    assert set(FORMATS) == set(FORMAT_EXTENSIONS)
    assert set(FORMAT_EXTENSIONS.values()) == {".ply", ".obj", ".stl", ".pcd", ".xyz", ".e57", ".las", ".laz"}


@pytest.mark.parametrize(
    "data",
    [
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n",
        b"ply\r\nformat binary_little_endian 1.0\r\nelement vertex 0\r\nend_header\r\n",
    ],
)
def test_ply(data):
    assert _sniff_whole(data) == "ply"


def test_obj_with_comments_groups_and_faces():
    data = (
        b"# exported\nmtllib part.mtl\no part\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\n"
        b"usemtl steel\ns off\nf 1//1 2//1 3//1\n"
    )
    assert _sniff_whole(data) == "obj"


def test_stl_ascii_and_binary():
    assert _sniff_whole(_box_stl("ascii")) == "stl_ascii"
    assert _sniff_whole(_box_stl("binary")) == "stl_binary"


def test_binary_stl_whose_header_starts_with_solid():
    data = bytearray(_box_stl("binary"))
    data[:80] = b"solid exported by a CAD tool".ljust(80, b" ")
    assert _sniff_whole(bytes(data)) == "stl_binary"


def test_binary_stl_size_must_match_triangle_count():
    data = _box_stl("binary")
    assert sniff_format(data, total_size=len(data) + 50) is None
    assert sniff_format(data[:-10], total_size=len(data) - 10) is None


def test_pcd():
    data = (
        b"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
        b"TYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1\nDATA ascii\n1 2 3\n"
    )
    assert _sniff_whole(data) == "pcd"


@pytest.mark.parametrize(
    "data",
    [
        b"1 2 3\n4 5 6\n",
        b"1.5,2.5,3.5\n-4e-3,5,6\n",
        b"1\t2\t3\t0\t0\t1\n4\t5\t6\t0\t1\t0\n",
        b"x;y;z\n1;2;3\n4;5;6\n",
        b"X,Y,Z,R,G,B\n1, 2, 3, 255, 0, 0\n",
        b"//X Y Z\n# comment\n\n1 2 3\nnan nan nan\n",
        b"2\n1 2 3 -120 10 20 30\n4 5 6 33 40 50 60\n",
        b"\xef\xbb\xbfx y z\r\n1 2 3\r\n",
    ],
)
def test_xyz_variants(data):
    assert _sniff_whole(data) == "xyz"


def test_xyz_head_cut_mid_line():
    rng = np.random.default_rng(3)
    text = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in rng.normal(size=(20_000, 3)))
    data = text.encode()
    assert len(data) > SNIFF_BYTES
    assert sniff_format(data[:SNIFF_BYTES], total_size=len(data)) == "xyz"


def _zip_bytes() -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("cloud.xyz", "1 2 3\n4 5 6\n")
    return buffer.getvalue()


PARAGRAPH = (
    b"The part was scanned on Tuesday with the handheld scanner.\n"
    b"Please machine it from 6061 aluminium, 2 pieces, tolerance 0.05 mm.\n"
    b"Thanks, and call me if anything is unclear.\n"
)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"   \n\n",
        b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4,
        _zip_bytes(),
        json.dumps({"points": [[1, 2, 3], [4, 5, 6]]}).encode(),
        json.dumps([[1, 2, 3], [4, 5, 6]], indent=2).encode(),
        b"<!DOCTYPE html>\n<html><head><title>x</title></head><body><p>1 2 3</p></body></html>\n",
        PARAGRAPH,
        b"42\n",
        b"1 2\n3 4\n",
        b"solid part\nthis is not a facet list\n",
        b"GIF89a" + bytes(200),
    ],
    ids=["empty", "blank", "png", "zip", "json", "json-array", "html", "prose", "number",
         "two-columns", "solid-prose", "gif"],
)  # fmt: skip
def test_refuses_non_geometry(data):
    assert _sniff_whole(data) is None
    assert sniff_format(data) is None


@pytest.mark.parametrize("size", [1, 83, 84, 200, 5000, SNIFF_BYTES])
def test_refuses_random_bytes(size):
    rng = np.random.default_rng(size)
    for _ in range(20):
        data = rng.integers(0, 256, size=size, dtype=np.uint8).tobytes()
        assert sniff_format(data, total_size=size) is None
        assert sniff_format(data) is None


def test_refuses_random_bytes_with_a_matching_stl_size():
    rng = np.random.default_rng(7)
    for _ in range(20):
        data = bytearray(rng.integers(0, 256, size=84 + 50 * 30, dtype=np.uint8).tobytes())
        struct.pack_into("<I", data, 80, 30)
        assert sniff_format(bytes(data), total_size=len(data)) is None


def test_describe_unsupported_names_archives_and_las():
    assert "unpack" in describe_unsupported(_zip_bytes())
    assert "LAS" in describe_unsupported(b"LASF" + bytes(100))
    assert describe_unsupported(PARAGRAPH) is None


def test_sniff_rejects_non_bytes():
    with pytest.raises(TypeError):
        sniff_format("ply\n")  # type: ignore[arg-type]
