"""/healthz (the process answers) and /readyz (database, broker and storage answer)."""

from __future__ import annotations

import tempfile

from fastapi import APIRouter
from fastapi.responses import JSONResponse
from sqlalchemy import text

from service.db import get_engine
from service.deps import QueueDep, SettingsDep
from service.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness")
def healthz() -> Health:
    return Health(status="ok")


def _check(fn) -> str:
    try:
        fn()
        return "ok"
    except Exception as exc:  # noqa: BLE001 — report, never raise, from a readiness probe
        return f"error: {type(exc).__name__}: {str(exc)[:200]}"


@router.get("/readyz", response_model=Health, responses={503: {"model": Health}}, summary="Readiness")
def readyz(settings: SettingsDep, queue: QueueDep) -> JSONResponse:
    def database() -> None:
        with get_engine(settings.resolved_database_url).connect() as conn:
            conn.execute(text("SELECT 1"))

    def broker() -> None:
        with queue.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, timeout=2)

    def storage() -> None:
        settings.artifacts_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=settings.artifacts_dir):
            pass

    checks = {"database": _check(database), "broker": _check(broker), "storage": _check(storage)}
    ok = all(v == "ok" for v in checks.values())
    body = Health(status="ok" if ok else "unavailable", checks=checks)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)
