"""The FastAPI application: `create_app()` wires routes, problem handlers and the reconciler."""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI

from core.config import Settings, get_settings
from core.db import get_engine
from core.stages import load_stages
from service import problems
from service.deps import require_api_key
from service.reconciler import Reconciler
from service.routes import artifacts, dashboard, health, jobs

VERSION = "0.1.0"
log = logging.getLogger(__name__)


def create_app(settings: Settings | None = None, *, reconcile: bool = True) -> FastAPI:
    settings = settings or get_settings()
    load_stages(settings.stage_plugins, settings.pipeline)  # a misconfigured pipeline stops start-up, not a request

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        try:
            get_engine(settings.resolved_database_url)  # creates the tables before the first request
        except Exception:  # noqa: BLE001 — start anyway: /readyz says what is down, requests get 503
            log.warning("database not reachable at start-up", exc_info=True)
        reconciler = Reconciler(settings) if reconcile else None
        if reconciler:
            reconciler.start()
        try:
            yield
        finally:
            if reconciler:
                reconciler.stop()

    app = FastAPI(
        title="cloud2cnc",
        version=VERSION,
        summary="Point clouds in, certified CNC finishing programs out.",
        description="Upload a point cloud or mesh, watch each pipeline stage, download every artifact. "
                    "Errors are RFC 9457 problem details (`application/problem+json`).",
        lifespan=lifespan,
    )
    app.dependency_overrides[get_settings] = lambda: settings
    app.state.settings = settings
    problems.install(app)
    app.include_router(health.router)
    guarded = [Depends(require_api_key)]
    app.include_router(jobs.router, dependencies=guarded)
    app.include_router(artifacts.router, dependencies=guarded)
    app.include_router(dashboard.router)  # `/` and its static files; not part of the API schema

    return app
