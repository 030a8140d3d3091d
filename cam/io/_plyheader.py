"""Parse the text header of a PLY file into elements and typed properties."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from cam.io.errors import ReadError

__all__ = ["PLY_TYPES", "PlyElement", "PlyHeader", "PlyProperty", "parse_header"]

#: PLY scalar type names (classic and sized aliases) to numpy type codes, without byte order.
PLY_TYPES: dict[str, str] = {
    "char": "i1", "int8": "i1",
    "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4",
    "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip

_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
# Headers are small; a file without end_header in this many bytes is not a PLY file.
_MAX_HEADER_BYTES = 1 << 20
_END_HEADER = re.compile(rb"^end_header[ \t]*(?:\r?\n|\Z)", re.MULTILINE)


@dataclass(frozen=True)
class PlyProperty:
    """One property: a scalar of ``code``, or a list of ``code`` items led by a ``count_code`` count.

    Attributes
    ----------
    name : str
        The property name.
    code : str
        numpy type code of the value or of the list items, without byte order (see `PLY_TYPES`).
    count_code : str or None
        numpy type code of a list's count (an integer type); None for a scalar.
    """

    name: str
    code: str
    count_code: str | None = None

    @property
    def is_list(self) -> bool:
        """True for a list property."""
        return self.count_code is not None


@dataclass
class PlyElement:
    """One element of a PLY header and its properties, in file order.

    Attributes
    ----------
    name : str
        The element name, such as ``vertex`` or ``face``.
    count : int
        Number of records.
    properties : list of PlyProperty
        The properties of each record.
    """
    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        """The property names, in order."""
        return [p.name for p in self.properties]

    @property
    def has_lists(self) -> bool:
        """True when some property is a list (records may then vary in length)."""
        return any(p.is_list for p in self.properties)


@dataclass
class PlyHeader:
    """A parsed PLY header.

    Attributes
    ----------
    format : str
        ``ascii``, ``binary_little_endian`` or ``binary_big_endian``.
    elements : list of PlyElement
        The elements in file order.
    comments : list of str
        The ``comment`` and ``obj_info`` lines' text, in order.
    body_offset : int
        Byte offset of the body, just past the ``end_header`` line.
    line_count : int
        Number of text lines in the header, so ascii body errors can name file line numbers.
    """
    format: str
    elements: list[PlyElement]
    comments: list[str]
    body_offset: int
    #: Number of text lines in the header, so ascii body errors can name file line numbers.
    line_count: int

    def element(self, name: str) -> PlyElement:
        """The element called `name`.

        Parameters
        ----------
        name : str
            Element name.

        Returns
        -------
        element : PlyElement
            The first element of that name.

        Raises
        ------
        StopIteration
            When the header has no such element.
        """
        return next(e for e in self.elements if e.name == name)


def parse_header(data: bytes) -> PlyHeader:
    """Parse the header at the start of ``data`` (the whole file's bytes).

    Parameters
    ----------
    data : bytes
        The file's content.

    Returns
    -------
    header : PlyHeader
        Format, elements, comments and where the body starts.

    Raises
    ------
    ReadError
        When the file does not start with ``ply``, has no ``end_header`` in its first 1 MiB, holds a
        non-ASCII header byte, an unknown keyword or type, a malformed format, element or property line,
        a property before any element, no format line, or an element declared twice.
    """
    if not re.match(rb"ply[ \t]*\r?\n", data):
        raise ReadError("the file does not start with the line 'ply'; it is not a PLY file")
    end = _END_HEADER.search(data, 0, _MAX_HEADER_BYTES)
    if end is None:
        raise ReadError(
            "the PLY header has no 'end_header' line in its first 1 MiB; "
            "the file is truncated or not a PLY file"
        )
    try:
        text = data[: end.start()].decode("ascii")
    except UnicodeDecodeError as exc:
        raise ReadError(
            f"the PLY header holds a non-ASCII byte at offset {exc.start}; the header is corrupt"
        ) from None
    lines = text.splitlines()
    fmt: str | None = None
    elements: list[PlyElement] = []
    comments: list[str] = []
    for number, line in enumerate(lines[1:], start=2):
        words = line.split()
        if not words:
            continue
        keyword = words[0]
        if keyword in ("comment", "obj_info"):
            comments.append(line.split(None, 1)[1] if len(words) > 1 else "")
        elif keyword == "format":
            fmt = _parse_format(words, number)
        elif keyword == "element":
            elements.append(_parse_element(words, number))
        elif keyword == "property":
            if not elements:
                raise ReadError(
                    f"PLY header line {number} declares a property before any element; "
                    "the header is malformed"
                )
            elements[-1].properties.append(_parse_property(words, number))
        else:
            raise ReadError(
                f"PLY header line {number} starts with unknown keyword {keyword!r}; "
                "expected format, element, property or comment"
            )
    if fmt is None:
        raise ReadError("the PLY header has no 'format' line; the header is malformed")
    names = [e.name for e in elements]
    for name in names:
        if names.count(name) > 1:
            raise ReadError(f"the PLY header declares the element {name!r} twice")
    return PlyHeader(
        format=fmt,
        elements=elements,
        comments=comments,
        body_offset=end.end(),
        line_count=len(lines) + 1,
    )


def _parse_format(words: list[str], number: int) -> str:
    if len(words) != 3 or words[1] not in _FORMATS:
        got = " ".join(words[1:]) or "nothing"
        raise ReadError(
            f"PLY header line {number} gives format {got!r}; "
            f"expected one of {', '.join(_FORMATS)} followed by a version"
        )
    return words[1]


def _parse_element(words: list[str], number: int) -> PlyElement:
    if len(words) != 3 or not words[2].isdigit():
        raise ReadError(
            f"PLY header line {number} reads {' '.join(words)!r}; "
            "expected 'element <name> <count>' with a non-negative count"
        )
    return PlyElement(words[1], int(words[2]))


def _parse_property(words: list[str], number: int) -> PlyProperty:
    if len(words) == 5 and words[1] == "list":
        count_code, code = _type(words[2], number), _type(words[3], number)
        if count_code[0] == "f":
            raise ReadError(
                f"PLY header line {number} uses {words[2]!r} as a list count type; "
                "list counts must be integers"
            )
        return PlyProperty(words[4], code, count_code)
    if len(words) == 3:
        return PlyProperty(words[2], _type(words[1], number))
    raise ReadError(
        f"PLY header line {number} reads {' '.join(words)!r}; expected "
        "'property <type> <name>' or 'property list <count type> <item type> <name>'"
    )


def _type(name: str, number: int) -> str:
    try:
        return PLY_TYPES[name]
    except KeyError:
        raise ReadError(
            f"PLY header line {number} uses unknown type {name!r}; "
            f"known types are {', '.join(PLY_TYPES)}"
        ) from None
