"""The OpenAPI document, generated from the app (a test fails when the committed copy drifts)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def openapi_schema() -> dict[str, Any]:
    from core.config import Settings
    from service.app import create_app

    return create_app(Settings(data_dir=Path("unused")), reconcile=False).openapi()


def render() -> str:
    return json.dumps(openapi_schema(), indent=2, sort_keys=True) + "\n"


def write_openapi(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render())
    return path
