"""The web dashboard: `/` serves the single page, `/static/...` its files, `/ui/params-schema.json` the form.

Plain files, no build step: ES modules, CSS and the vendored three.js under `service/static/`
(`scripts/vendor_three.sh` puts three.js there). None of these routes is part of the API schema.
"""

from __future__ import annotations

import base64
import hashlib
import re
from functools import lru_cache
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse

from core.params import JobParams
from service.problems import Problem

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"

router = APIRouter(include_in_schema=False)

_NO_CACHE = {"Cache-Control": "no-cache"}  # revalidate (ETag / Last-Modified) so an upgrade shows at once
_MEDIA = {".js": "text/javascript; charset=utf-8", ".mjs": "text/javascript; charset=utf-8",
          ".css": "text/css; charset=utf-8", ".html": "text/html; charset=utf-8", ".svg": "image/svg+xml",
          ".png": "image/png", ".json": "application/json", ".ico": "image/x-icon"}
_INLINE_SCRIPT = re.compile(rb"<script(?![^>]*\bsrc=)[^>]*>(.*?)</script>", re.S)


@lru_cache(maxsize=4)
def _index(mtime_ns: int) -> tuple[bytes, str]:
    """index.html and its Content-Security-Policy: only this origin, the inline import map by hash."""
    html = (STATIC_DIR / "index.html").read_bytes()
    hashes = " ".join(f"'sha256-{base64.b64encode(hashlib.sha256(m).digest()).decode()}'"
                      for m in _INLINE_SCRIPT.findall(html))
    csp = ("default-src 'self'; "
           f"script-src 'self' {hashes}; "
           "style-src 'self'; img-src 'self' data: blob:; worker-src 'self' blob:; "
           "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'self'; form-action 'self'")
    return html, csp


@router.get("/")
def dashboard() -> HTMLResponse:
    path = STATIC_DIR / "index.html"
    html, csp = _index(path.stat().st_mtime_ns)
    return HTMLResponse(html, headers={**_NO_CACHE, "Content-Security-Policy": csp,
                                       "X-Content-Type-Options": "nosniff", "Referrer-Policy": "same-origin"})


@router.get("/static/{path:path}")
def static_file(path: str) -> FileResponse:
    root = STATIC_DIR.resolve()
    target = (root / path).resolve()
    if not path or not target.is_relative_to(root) or not target.is_file() or target.name.startswith("."):
        raise Problem(404, "not-found", "Not found", f"no dashboard file {path!r}")
    return FileResponse(target, media_type=_MEDIA.get(target.suffix.lower()),
                        headers={**_NO_CACHE, "X-Content-Type-Options": "nosniff"})


@lru_cache(maxsize=1)
def _schema() -> dict:
    return JobParams.model_json_schema()


@router.get("/ui/params-schema.json")
def params_schema() -> JSONResponse:
    """The JSON schema of `JobParams` that the dashboard builds its parameter form from."""
    return JSONResponse(_schema(), headers=_NO_CACHE)
