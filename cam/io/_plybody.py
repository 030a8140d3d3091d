"""Decode the body of a PLY file into per-element property arrays.

Each element becomes a dict from property name to either a 1-d array (scalar
property) or a ``(counts, flat)`` pair (list property: ``counts`` int64 (n,)
items per record, ``flat`` the items of all records concatenated).
"""

from __future__ import annotations

import io
import struct

import numpy as np

from cam.io._plyheader import PlyElement, PlyHeader, PlyProperty
from cam.io.errors import ReadError

__all__ = ["read_ascii_elements", "read_binary_elements"]

_STRUCT_CODES = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I"}


def read_binary_elements(data: bytes, header: PlyHeader) -> dict[str, dict]:
    """Decode every element of a binary PLY body, in header order.

    Parameters
    ----------
    data : bytes
        The whole file's bytes.
    header : PlyHeader
        Its parsed header, of a binary format.

    Returns
    -------
    elements : dict of str to dict
        Per element name, per property name: a (count,) array of the declared type (native byte order),
        or for a list property a ``(counts, flat)`` pair (see the module docstring).

    Raises
    ------
    ReadError
        When the body is shorter than the header declares, or a list length is negative.
    """
    endian = "<" if header.format == "binary_little_endian" else ">"
    offset = header.body_offset
    elements: dict[str, dict] = {}
    for element in header.elements:
        if element.has_lists:
            values, offset = _binary_lists(data, offset, element, endian)
        else:
            values, offset = _binary_fixed(data, offset, element, endian)
        elements[element.name] = values
    return elements


def read_ascii_elements(data: bytes, header: PlyHeader) -> dict[str, dict]:
    """Decode every element of an ascii PLY body (one record per line), in header order.

    Parameters
    ----------
    data : bytes
        The whole file's bytes.
    header : PlyHeader
        Its parsed header, of the ascii format.

    Returns
    -------
    elements : dict of str to dict
        Per element name, per property name: a (count,) array (float properties of their declared type,
        integer ones as int64), or for a list property a ``(counts, flat)`` pair (see the module
        docstring).

    Raises
    ------
    ReadError
        When the body has fewer records than declared, or a line holds too few or too many values, a
        value that is not a number, or a non-integer for an integer property (the message names the
        line or property).
    """
    body = data[header.body_offset :].replace(b"\r\n", b"\n")
    numbered = [(i, line) for i, line in enumerate(body.split(b"\n")) if line.strip()]
    first_line = header.line_count + 1
    position = 0
    elements: dict[str, dict] = {}
    for element in header.elements:
        chunk = numbered[position : position + element.count]
        if len(chunk) < element.count:
            raise ReadError(
                f"ascii PLY header declares {element.count} {_plural(element)} but the file "
                f"holds only {len(chunk)} (file truncated, or the header count is wrong)"
            )
        elements[element.name] = _ascii_element(chunk, element, first_line)
        position += element.count
    return elements


def _plural(element: PlyElement) -> str:
    return {"vertex": "vertices", "face": "faces", "edge": "edges"}.get(
        element.name, f"'{element.name}' records"
    )


def _truncated(element: PlyElement, complete: int) -> ReadError:
    return ReadError(
        f"binary PLY ends after {complete} of {element.count} {_plural(element)} (file truncated?)"
    )


def _native(array: np.ndarray, code: str) -> np.ndarray:
    # No copy when already native: callers stack or convert the columns anyway.
    return array.astype(np.dtype(code), copy=False)


def _store(values: dict, prop: PlyProperty, value) -> None:
    # A repeated property name keeps its first occurrence.
    values.setdefault(prop.name, value)


def _binary_fixed(data: bytes, offset: int, element: PlyElement, endian: str):
    # Fields are named by position so repeated property names cannot clash.
    dtype = np.dtype([(f"f{i}", endian + p.code) for i, p in enumerate(element.properties)])
    if dtype.itemsize == 0 or element.count == 0:
        return {p.name: np.empty(0, p.code) for p in element.properties}, offset
    available = (len(data) - offset) // dtype.itemsize
    if available < element.count:
        raise _truncated(element, max(available, 0))
    table = np.frombuffer(data, dtype=dtype, count=element.count, offset=offset)
    values: dict = {}
    for i, prop in enumerate(element.properties):
        _store(values, prop, _native(table[f"f{i}"], prop.code))
    return values, offset + element.count * dtype.itemsize


def _binary_lists(data: bytes, offset: int, element: PlyElement, endian: str):
    if element.count == 0:
        empty = {
            p.name: (np.empty(0, np.int64), np.empty(0, p.code)) if p.is_list else np.empty(0, p.code)
            for p in element.properties
        }
        return empty, offset
    counts = _first_record_counts(data, offset, element, endian)
    if counts is None:
        raise _truncated(element, 0)
    if min(counts) > 0:
        fixed = _binary_fixed_lists(data, offset, element, endian, counts)
        if fixed is not None:
            return fixed
    return _binary_scan(data, offset, element, endian)


def _first_record_counts(data, offset, element, endian) -> list[int] | None:
    counts = []
    position = offset
    for prop in element.properties:
        if prop.is_list:
            reader = struct.Struct(endian + _STRUCT_CODES[prop.count_code])
            if position + reader.size > len(data):
                return None
            (count,) = reader.unpack_from(data, position)
            counts.append(count)
            position += reader.size + max(count, 0) * np.dtype(prop.code).itemsize
        else:
            position += np.dtype(prop.code).itemsize
    return counts


def _binary_fixed_lists(data, offset, element, endian, counts):
    """Read an element whose lists all have their first record's length, or return None."""
    fields = []
    lengths = iter(counts)
    for i, prop in enumerate(element.properties):
        if prop.is_list:
            fields.append((f"c{i}", endian + prop.count_code))
            fields.append((f"f{i}", endian + prop.code, (next(lengths),)))
        else:
            fields.append((f"f{i}", endian + prop.code))
    dtype = np.dtype(fields)
    available = min(element.count, (len(data) - offset) // dtype.itemsize)
    table = np.frombuffer(data, dtype=dtype, count=available, offset=offset)
    lengths = iter(counts)
    for i, prop in enumerate(element.properties):
        if prop.is_list and not np.all(table[f"c{i}"] == next(lengths)):
            return None
    if available < element.count:
        raise _truncated(element, available)
    values: dict = {}
    for i, prop in enumerate(element.properties):
        column = table[f"f{i}"]
        if prop.is_list:
            per_record = np.full(element.count, column.shape[1], dtype=np.int64)
            _store(values, prop, (per_record, _native(column.reshape(-1), prop.code)))
        else:
            _store(values, prop, _native(column, prop.code))
    return values, offset + element.count * dtype.itemsize


def _binary_scan(data, offset, element, endian):
    """Walk records one by one to find their offsets, then gather all values at once."""
    props = element.properties
    sizes = [np.dtype(p.code).itemsize for p in props]
    readers = [
        struct.Struct(endian + _STRUCT_CODES[p.count_code]).unpack_from if p.is_list else None
        for p in props
    ]
    count_sizes = [np.dtype(p.count_code).itemsize if p.is_list else 0 for p in props]
    starts: list[list[int]] = [[] for _ in props]
    lengths: list[list[int]] = [[] for _ in props]
    end = len(data)
    position = offset
    for record in range(element.count):
        for i in range(len(props)):
            if readers[i] is None:
                starts[i].append(position)
                position += sizes[i]
                continue
            if position + count_sizes[i] > end:
                raise _truncated(element, record)
            (count,) = readers[i](data, position)
            if count < 0:
                raise ReadError(
                    f"binary PLY {element.name} record {record} has a negative list "
                    f"length {count}; the file is corrupt"
                )
            position += count_sizes[i]
            starts[i].append(position)
            lengths[i].append(count)
            position += count * sizes[i]
        if position > end:
            raise _truncated(element, record)
    buffer = np.frombuffer(data, dtype=np.uint8)
    values: dict = {}
    for i, prop in enumerate(props):
        begin = np.asarray(starts[i], dtype=np.int64)
        dtype = np.dtype(endian + prop.code)
        if prop.is_list:
            per_record = np.asarray(lengths[i], dtype=np.int64)
            flat = _gather(buffer, begin, per_record, dtype)
            _store(values, prop, (per_record, _native(flat, prop.code)))
        else:
            ones = np.ones(len(begin), dtype=np.int64)
            _store(values, prop, _native(_gather(buffer, begin, ones, dtype), prop.code))
    return values, position


def _gather(buffer: np.ndarray, starts: np.ndarray, lengths: np.ndarray, dtype: np.dtype):
    total = int(lengths.sum())
    if total == 0:
        return np.empty(0, dtype=dtype)
    record_first = np.cumsum(lengths) - lengths
    within = np.arange(total, dtype=np.int64) - np.repeat(record_first, lengths)
    item_starts = np.repeat(starts, lengths) + within * dtype.itemsize
    byte_index = item_starts[:, None] + np.arange(dtype.itemsize, dtype=np.int64)
    return buffer[byte_index].reshape(-1).view(dtype)


def _ascii_element(chunk: list[tuple[int, bytes]], element: PlyElement, first_line: int) -> dict:
    props = element.properties
    if element.count == 0:
        return {
            p.name: (np.empty(0, np.int64), np.empty(0, p.code)) if p.is_list else np.empty(0, p.code)
            for p in props
        }
    try:
        table = np.loadtxt(
            io.BytesIO(b"\n".join(line for _, line in chunk)),
            dtype=np.float64,
            ndmin=2,
            comments=None,
        )
    except ValueError:
        table = None
    values = _ascii_fixed(table, element) if table is not None else None
    if values is None:
        values = _ascii_scan(chunk, element, first_line)
    first = {}
    for prop in props:
        first.setdefault(prop.name, prop)
    return {name: _cast(value, first[name], element) for name, value in values.items()}


def _ascii_fixed(table: np.ndarray, element: PlyElement) -> dict | None:
    """Split a rectangular table into properties, or return None when lists vary in length."""
    values: dict = {}
    column = 0
    for prop in element.properties:
        if column >= table.shape[1]:
            return None
        if prop.is_list:
            length = table[0, column]
            if not (np.isfinite(length) and length >= 0 and length == np.floor(length)):
                return None
            if not np.all(table[:, column] == length):
                return None
            length = int(length)
            items = table[:, column + 1 : column + 1 + length]
            if items.shape[1] != length:
                return None
            per_record = np.full(len(table), length, dtype=np.int64)
            values.setdefault(prop.name, (per_record, items.reshape(-1)))
            column += 1 + length
        else:
            values.setdefault(prop.name, table[:, column])
            column += 1
    if column != table.shape[1]:
        return None
    return values


def _ascii_scan(chunk, element: PlyElement, first_line: int) -> dict:
    """Parse record by record; slow, but it names the line of any malformed record."""
    props = element.properties
    scalars: list[list[float]] = [[] for _ in props]
    lengths: list[list[int]] = [[] for _ in props]
    for index, line in chunk:
        number = first_line + index
        tokens = line.split()
        at = 0
        try:
            for i, prop in enumerate(props):
                if prop.is_list:
                    length = int(tokens[at])
                    if length < 0:
                        raise ValueError
                    items = tokens[at + 1 : at + 1 + length]
                    if len(items) != length:
                        raise IndexError
                    lengths[i].append(length)
                    scalars[i].extend(map(float, items))
                    at += 1 + length
                else:
                    scalars[i].append(float(tokens[at]))
                    at += 1
        except IndexError:
            raise ReadError(
                f"ascii PLY line {number} has {len(tokens)} values, too few for one "
                f"{element.name} record ({', '.join(element.names)})"
            ) from None
        except ValueError:
            bad = next((t for t in tokens if not _is_number(t)), tokens[at] if at < len(tokens) else b"")
            raise ReadError(
                f"ascii PLY line {number} holds {bad.decode(errors='replace')!r} where a "
                f"number was expected in a {element.name} record"
            ) from None
        if at != len(tokens):
            raise ReadError(
                f"ascii PLY line {number} has {len(tokens)} values but a {element.name} record "
                f"({', '.join(element.names)}) has {at}; the file is malformed"
            )
    values: dict = {}
    for i, prop in enumerate(props):
        flat = np.asarray(scalars[i], dtype=np.float64)
        if prop.is_list:
            values.setdefault(prop.name, (np.asarray(lengths[i], dtype=np.int64), flat))
        else:
            values.setdefault(prop.name, flat)
    return values


def _is_number(token: bytes) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _cast(value, prop: PlyProperty, element: PlyElement):
    """Give ascii values their declared type, so integer colours stay integers."""
    if isinstance(value, tuple):
        lengths, flat = value
        return lengths, _to_type(flat, prop, element)
    return _to_type(value, prop, element)


def _to_type(values: np.ndarray, prop: PlyProperty, element: PlyElement) -> np.ndarray:
    dtype = np.dtype(prop.code)
    if dtype.kind == "f":
        return values.astype(dtype)
    whole = np.isfinite(values) & (values == np.round(values))
    if not whole.all():
        bad = values[~whole][0]
        raise ReadError(
            f"ascii PLY {element.name} property {prop.name!r} is declared integer but holds {bad!r}"
        )
    return values.astype(np.int64)
