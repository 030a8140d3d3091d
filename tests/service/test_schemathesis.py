"""Property-based requests generated from our own OpenAPI schema: no 5xx, anywhere."""

from __future__ import annotations

import tempfile
from pathlib import Path

import schemathesis
from hypothesis import HealthCheck, settings

from core.config import Settings
from service.app import create_app

_DATA = Path(tempfile.mkdtemp(prefix="c2c-schemathesis-"))
app = create_app(Settings(data_dir=_DATA, min_points=10), reconcile=False)
schema = schemathesis.openapi.from_asgi("/openapi.json", app)


@schema.parametrize()
@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_server_errors(case):
    response = case.call()
    assert response.status_code < 500, (case.method, case.formatted_path, response.status_code, response.text[:500])
    if response.status_code >= 400:
        content_type = response.headers.get("content-type", [""])
        content_type = content_type[0] if isinstance(content_type, list) else content_type
        assert content_type.startswith("application/problem+json"), (response.status_code, response.text[:300])
