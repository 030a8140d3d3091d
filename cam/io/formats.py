"""Recognise an upload's format from its first bytes.

Standard library only: the web service imports this module to reject garbage at
upload time without loading numpy.

The sniffer trusts content, never the file name: a ``.txt`` may hold XYZ
columns, a ``.ply`` may be a renamed ZIP, a ``.las`` may be LAZ. It is strict enough that random bytes,
images, archives, JSON, HTML and prose are refused, and lenient enough for what
real scanners and CAD tools write (header lines, comma or semicolon separators,
``solid`` at the start of a binary STL header).
"""

from __future__ import annotations

import math
import re
import struct

__all__ = [
    "FORMAT_EXTENSIONS",
    "FORMATS",
    "SNIFF_BYTES",
    "describe_unsupported",
    "sniff_format",
]

#: How many leading bytes callers should pass to :func:`sniff_format`.
SNIFF_BYTES = 65536

#: Every value :func:`sniff_format` can return, mapped to the extension an
#: upload is stored under (the two STL flavours share one).
FORMAT_EXTENSIONS: dict[str, str] = {
    "ply": ".ply",
    "obj": ".obj",
    "stl_ascii": ".stl",
    "stl_binary": ".stl",
    "pcd": ".pcd",
    "xyz": ".xyz",
    "e57": ".e57",
    "las": ".las",
    "laz": ".laz",
}
FORMATS = tuple(FORMAT_EXTENSIONS)

# ASTM E2807: the 48-byte header starts with this signature, then major version 1 (uint32, little-endian).
_E57_SIGNATURE = b"ASTM-E57"
# ASPRS LAS 1.0-1.4: "LASF", then the version's major and minor bytes at 24 and 25, and the point data record
# format (uint8) at 104, whose two top bits mark LAZ compression.
_LAS_SIGNATURE = b"LASF"
_LAS_MIN_HEADER = 227

_STL_HEADER = 80
_STL_RECORD = 50
# More records than this are not needed to tell a binary STL from noise, and
# checking them all would make sniffing cost grow with the head size.
_STL_RECORDS_CHECKED = 64

_NUMBER = re.compile(
    rb"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)\Z",
    re.IGNORECASE,
)
_INTEGER = re.compile(rb"[+-]?\d+\Z")
# Columns may be separated by any mix of these; CSV exports often use ", ".
_SEPARATORS = re.compile(rb"[ \t,;]+")

_OBJ_KEYWORDS = frozenset(
    b"v vt vn vp f l p o g s mg usemtl mtllib maplib usemap lod shadow_obj trace_obj "
    b"cstype deg bmat step curv curv2 surf parm trim hole scrv sp end con "
    b"ctech stech bevel c_interp d_interp call csh".split()
)
_PCD_KEYWORDS = frozenset(
    b"VERSION FIELDS SIZE TYPE COUNT WIDTH HEIGHT VIEWPOINT POINTS DATA".split()
)
# Up to this many non-numeric lines may precede the numbers of an XYZ file.
_MAX_HEADER_LINES = 50


def sniff_format(head: bytes, *, total_size: int | None = None) -> str | None:
    """Name the point cloud or mesh format of a file from its first bytes.

    Parameters
    ----------
    head : bytes
        The first bytes of the file (bytes, bytearray or memoryview), ideally :data:`SNIFF_BYTES` of them
        (or the whole file when it is shorter). A UTF-8 byte order mark is skipped.
    total_size : int or None, optional
        The file's full size in bytes, when known. Binary STL is then accepted only when the size is
        exactly ``84 + 50 * triangle_count``; a head shorter than :data:`SNIFF_BYTES` without
        ``total_size`` is taken to be the whole file.

    Returns
    -------
    format : str or None
        One of ``"ply"``, ``"obj"``, ``"stl_ascii"``, ``"stl_binary"``, ``"pcd"``, ``"xyz"`` (numeric
        text columns: XYZ, PTS, TXT, CSV), ``"e57"``, ``"las"``, ``"laz"``, or ``None`` when the bytes are
        none of these. A scanner file is recognised from its fixed header alone, so a truncated one is still
        named (its reader then says what is missing).

    Raises
    ------
    TypeError
        When `head` is not bytes-like.
    """
    if not isinstance(head, (bytes, bytearray, memoryview)):
        raise TypeError(f"sniff_format needs bytes, got {type(head).__name__}")
    head = bytes(head)
    if head.startswith(b"\xef\xbb\xbf"):
        head = head[3:]
        if total_size is not None:
            total_size -= 3
    if not head.strip():
        return None
    if total_size is None and len(head) < SNIFF_BYTES:
        total_size = len(head)
    whole = total_size is not None and total_size <= len(head)

    if re.match(rb"ply[ \t]*\r?\n", head):
        return "ply"
    scanner = _scanner_format(head)
    if scanner is not None:
        return scanner

    text = _as_text(head, whole=whole)
    if text is not None:
        lines = text.splitlines()
        # The last line of a partial head may be cut mid-token.
        if not whole and len(lines) > 1:
            lines = lines[:-1]
        if _looks_like_ascii_stl(text):
            return "stl_ascii"
        if _looks_like_pcd(lines):
            return "pcd"
    if _looks_like_binary_stl(head, total_size):
        return "stl_binary"
    if text is None:
        return None
    if _looks_like_obj(lines):
        return "obj"
    if _looks_like_xyz(lines):
        return "xyz"
    return None


def describe_unsupported(head: bytes) -> str | None:
    """Say what a refused upload seems to be, so the error can tell the user what to do.

    Parameters
    ----------
    head : bytes
        The first bytes of the file; only the first 64 are looked at.

    Returns
    -------
    description : str or None
        A short clause such as ``"a ZIP archive; unpack it and upload the point cloud inside"``, or
        ``None`` when nothing is recognised.
    """
    head = bytes(head[:64])
    known = [
        (b"PK\x03\x04", "a ZIP archive; unpack it and upload the point cloud inside"),
        (b"\x1f\x8b", "a gzip file; decompress it and upload the point cloud inside"),
        (b"7z\xbc\xaf\x27\x1c", "a 7-Zip archive; unpack it and upload the point cloud inside"),
        (b"LASF", ("a LAS/LAZ file of a version other than 1.0-1.4; export it as LAS 1.4 or PLY "
                   "(e.g. with CloudCompare or PDAL)")),
        (b"ASTM-E57", ("an E57 file of a version other than 1.x; export it as E57 1.0 or PLY "
                       "(e.g. with CloudCompare)")),
        (b"\x89PNG", "a PNG image, not a point cloud"),
        (b"\xff\xd8\xff", "a JPEG image, not a point cloud"),
        (b"%PDF", "a PDF document, not a point cloud"),
        (b"ISO-10303-21", "a STEP CAD file; export the part as STL or OBJ"),
    ]
    for magic, what in known:
        if head.startswith(magic):
            return what
    return None


def _scanner_format(head: bytes) -> str | None:
    """``"e57"``, ``"las"`` or ``"laz"`` when the head starts with that format's header, else None."""
    # A head too short to hold the version is a truncated file of that format: its reader says so.
    if head.startswith(_E57_SIGNATURE):
        if len(head) < 12:
            return "e57"
        (major,) = struct.unpack_from("<I", head, 8)
        return "e57" if major == 1 else None
    if head.startswith(_LAS_SIGNATURE):
        if len(head) < _LAS_MIN_HEADER:
            return "las"
        major, minor = head[24], head[25]
        if major != 1 or minor > 4:
            return None
        # LAZ sets bit 7 of the point format (bit 6 in some older writers) so that LAS readers refuse it.
        return "laz" if head[104] & 0xC0 else "las"
    return None


def _as_text(head: bytes, *, whole: bool) -> str | None:
    """Decode the head as text, or None when it holds binary data."""
    if b"\x00" in head:
        return None
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError as exc:
        # A multi-byte character may be cut by the end of a partial head.
        if whole or exc.start < len(head) - 3:
            text = head.decode("latin-1")
        else:
            text = head[: exc.start].decode("utf-8", errors="replace")
    controls = sum(1 for ch in text if ord(ch) < 32 and ch not in "\t\n\r\f\v")
    if controls:
        return None
    return text


def _looks_like_ascii_stl(text: str) -> bool:
    # Binary STL headers may start with "solid" too; only facet text confirms ASCII.
    if not text.lstrip().lower().startswith("solid"):
        return False
    return re.search(r"\bfacet\s+normal\b|\bendsolid\b", text, re.IGNORECASE) is not None


def _looks_like_pcd(lines: list[str]) -> bool:
    keywords = []
    for line in lines:
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        word = stripped.split()[0].encode()
        if word not in _PCD_KEYWORDS:
            break
        keywords.append(word)
        if word == b"DATA":
            break
    return bool(keywords) and keywords[0] in (b"VERSION", b"FIELDS") and b"FIELDS" in keywords


def _looks_like_binary_stl(head: bytes, total_size: int | None) -> bool:
    if len(head) < _STL_HEADER + 4:
        return False
    (count,) = struct.unpack_from("<I", head, _STL_HEADER)
    expected = _STL_HEADER + 4 + _STL_RECORD * count
    if count == 0:
        return False
    if total_size is not None and total_size != expected:
        return False
    available = min(count, (len(head) - _STL_HEADER - 4) // _STL_RECORD, _STL_RECORDS_CHECKED)
    if available == 0:
        return total_size is not None
    # Vertices of a real part are finite and of sane magnitude; random bytes fail this quickly.
    for i in range(available):
        offset = _STL_HEADER + 4 + i * _STL_RECORD + 12
        for value in struct.unpack_from("<9f", head, offset):
            if not math.isfinite(value) or abs(value) > 1e12:
                return False
    return True


def _looks_like_obj(lines: list[str]) -> bool:
    vertices = 0
    unknown = 0
    significant = 0
    for line in lines:
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        significant += 1
        fields = stripped.split()
        word = fields[0].encode()
        if word not in _OBJ_KEYWORDS:
            unknown += 1
            continue
        if word == b"v":
            numbers = [f for f in fields[1:] if _NUMBER.match(f.encode())]
            if len(numbers) < 3 or len(numbers) != len(fields) - 1:
                return False
            vertices += 1
    # A stray unknown statement is tolerated (exporters add private ones).
    return vertices > 0 and unknown <= max(1, significant // 100)


def _looks_like_xyz(lines: list[str]) -> bool:
    header = 0
    columns: int | None = None
    rows = 0
    count_line_allowed = True
    blocks = False
    for line in lines:
        stripped = line.strip().encode()
        if not stripped:
            continue
        if stripped.startswith(b"#"):
            continue
        tokens = [t for t in _SEPARATORS.split(stripped) if t]
        numeric = all(_NUMBER.match(t) for t in tokens)
        if not numeric:
            if rows or columns is not None:
                return False
            header += 1
            if header > _MAX_HEADER_LINES:
                return False
            continue
        if len(tokens) == 1 and (count_line_allowed or blocks) and _INTEGER.match(tokens[0]):
            # A point count as in .pts files, which may hold several scans, each led by its count.
            count_line_allowed = False
            blocks = True
            continue
        count_line_allowed = False
        if columns is None:
            columns = len(tokens)
            if not 3 <= columns <= 64:
                return False
        elif len(tokens) != columns:
            return False
        rows += 1
    return rows > 0
