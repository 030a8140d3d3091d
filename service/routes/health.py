"""/healthz (the process answers) and /readyz (database, broker and storage answer)."""

from __future__ import annotations

import tempfile

from fastapi import APIRouter
from fastapi.responses import JSONResponse
from sqlalchemy import text

from core.db import get_engine
from service.deps import QueueDep, SettingsDep
from service.problems import problem_response
from service.schemas import Health, ProblemOut

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


@router.get("/readyz", response_model=Health, responses={503: {"model": ProblemOut, "content": {
    "application/problem+json": {}}, "description": "A dependency is down; `checks` says which"}},
    summary="Readiness")
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
    down = [k for k, v in checks.items() if v != "ok"]
    if down:
        return problem_response(503, "not-ready", "Not ready", f"not reachable: {', '.join(down)}",
                                instance="/readyz", checks=checks)
    return JSONResponse(Health(status="ok", checks=checks).model_dump())
