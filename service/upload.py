"""Receive a multipart upload as a stream: the file goes to disk chunk by chunk, never whole into memory.

python-multipart's push parser sees each chunk once; we count bytes as they
arrive and stop reading the moment the size cap is passed (413).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from python_multipart import MultipartParser
from python_multipart.multipart import parse_options_header
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request

from service.problems import Problem

HEAD_BYTES = 64 * 1024
MAX_PARAMS_BYTES = 64 * 1024
_SLACK = 64 * 1024  # multipart framing and the params field around the file


@dataclass
class Upload:
    path: Path | None = None
    filename: str = ""
    size: int = 0
    sha256: str = ""
    head: bytes = b""
    params_text: str | None = None
    fields: list[str] = field(default_factory=list)

    def discard(self) -> None:
        if self.path is not None:
            self.path.unlink(missing_ok=True)


def display_name(raw: str) -> str:
    """The client's filename reduced to a harmless display label (it never names a stored file)."""
    base = re.split(r"[\\/]", raw)[-1]
    base = "".join(ch for ch in base if ch.isprintable() and ch not in "\"<>|")
    base = base.strip().lstrip(".") or "upload"
    return base[:200]


def _too_large(limit: int) -> Problem:
    return Problem(413, "payload-too-large", "Payload too large",
                   f"the upload is larger than this server's limit of {limit / 2**20:.0f} MiB "
                   "(CLOUD2CNC_MAX_UPLOAD_MB); decimate the cloud or raise the limit")


async def receive_upload(request: Request, *, tmp_dir: Path, max_bytes: int) -> Upload:
    """Parse `file` and `params` from a multipart/form-data request body."""
    ctype, options = parse_options_header(request.headers.get("content-type", ""))
    if ctype != b"multipart/form-data" or b"boundary" not in options:
        raise Problem(415, "unsupported-media-type", "Unsupported media type",
                      "send the upload as multipart/form-data with a `file` part and an optional `params` part")
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > max_bytes + _SLACK:
        raise _too_large(max_bytes)

    tmp_dir.mkdir(parents=True, exist_ok=True)
    up = Upload()
    digest = hashlib.sha256()
    head = bytearray()
    pending: list[bytes] = []  # file bytes parsed from the last network chunk, written off the event loop
    done: list = []            # file handles whose part ended, closed after their bytes are written
    state: dict = {"name": None, "filename": None, "fh": None, "buf": bytearray(), "headers": {}, "hname": b""}

    def on_part_begin() -> None:
        state.update(name=None, filename=None, fh=None, buf=bytearray(), headers={})

    def on_header_field(data: bytes, start: int, end: int) -> None:
        state["hname"] += data[start:end]

    def on_header_value(data: bytes, start: int, end: int) -> None:
        key = state["hname"].lower()
        state["headers"][key] = state["headers"].get(key, b"") + data[start:end]

    def on_header_end() -> None:
        state["hname"] = b""

    def on_headers_finished() -> None:
        disp, opts = parse_options_header(state["headers"].get(b"content-disposition", b""))
        name = opts.get(b"name", b"").decode("utf-8", "replace")
        state["name"] = name
        up.fields.append(name)
        if name == "file":
            if up.path is not None:
                raise Problem(422, "validation-error", "Validation error", "send exactly one `file` part")
            fd, tmp = tempfile.mkstemp(dir=tmp_dir, prefix="upload-")
            state["fh"] = os.fdopen(fd, "wb")
            up.path = Path(tmp)
            up.filename = display_name(opts.get(b"filename", b"").decode("utf-8", "replace"))

    def on_part_data(data: bytes, start: int, end: int) -> None:
        chunk = data[start:end]
        if state["name"] == "file":
            up.size += len(chunk)
            if up.size > max_bytes:
                raise _too_large(max_bytes)
            digest.update(chunk)
            if len(head) < HEAD_BYTES:
                head.extend(chunk[: HEAD_BYTES - len(head)])
            pending.append(chunk)
        elif state["name"] == "params":
            state["buf"] += chunk
            if len(state["buf"]) > MAX_PARAMS_BYTES:
                raise Problem(413, "payload-too-large", "Payload too large",
                              f"the `params` part is over {MAX_PARAMS_BYTES // 1024} KiB")

    def on_part_end() -> None:
        if state["fh"] is not None:
            done.append(state["fh"])
            state["fh"] = None
        if state["name"] == "params":
            up.params_text = bytes(state["buf"]).decode("utf-8", "replace")

    def on_end() -> None:
        state["ended"] = True

    parser = MultipartParser(options[b"boundary"], callbacks={
        "on_end": on_end,
        "on_part_begin": on_part_begin, "on_header_field": on_header_field,
        "on_header_value": on_header_value, "on_header_end": on_header_end,
        "on_headers_finished": on_headers_finished, "on_part_data": on_part_data, "on_part_end": on_part_end,
    })
    received = 0
    try:
        async for chunk in request.stream():
            received += len(chunk)
            if received > max_bytes + _SLACK:
                raise _too_large(max_bytes)
            parser.write(chunk)
            await _flush(state, pending, done)
        parser.finalize()
        await _flush(state, pending, done)
        if not state.get("ended"):
            raise ValueError("the body ends before the closing boundary (upload cut off?)")
    except Problem:
        _close(state, done)
        up.discard()
        raise
    except Exception as exc:  # the parser's own errors: malformed framing
        _close(state, done)
        up.discard()
        raise Problem(400, "malformed-multipart", "Malformed multipart body",
                      f"the multipart/form-data body could not be parsed: {exc}") from None
    _close(state, done)
    up.sha256 = digest.hexdigest()
    up.head = bytes(head)
    return up


async def _flush(state: dict, pending: list[bytes], done: list) -> None:
    fh = done[0] if done else state["fh"]  # one file part per request: the bytes belong to it
    if pending and fh is not None:
        data = b"".join(pending)
        pending.clear()
        await run_in_threadpool(fh.write, data)


def _close(state: dict, done: list) -> None:
    for fh in done + ([state["fh"]] if state.get("fh") is not None else []):
        fh.close()
    done.clear()
    state["fh"] = None
