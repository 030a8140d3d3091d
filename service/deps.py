"""FastAPI dependencies: settings, database session, artifact store, queue, API key."""

from __future__ import annotations

import hmac
from typing import Annotated, Iterator

from celery import Celery
from fastapi import Depends, Header
from sqlalchemy.orm import Session

from core.config import Settings, get_settings
from core.db import get_sessionmaker
from core.queue import get_celery
from core.store import ArtifactStore
from service.problems import Problem

SettingsDep = Annotated[Settings, Depends(get_settings)]


def get_session(settings: SettingsDep) -> Iterator[Session]:
    with get_sessionmaker(settings.resolved_database_url)() as session:
        yield session


def get_store(settings: SettingsDep) -> ArtifactStore:
    return ArtifactStore(settings.artifacts_dir)


def get_queue(settings: SettingsDep) -> Celery:
    return get_celery(settings)


def require_api_key(settings: SettingsDep,
                    x_api_key: Annotated[str | None, Header(include_in_schema=False)] = None) -> None:
    if settings.api_key and not hmac.compare_digest((x_api_key or "").encode(), settings.api_key.encode()):
        raise Problem(401, "unauthorized", "Unauthorized", "send the API key in the X-API-Key header",
                      headers={"WWW-Authenticate": "X-API-Key"})


SessionDep = Annotated[Session, Depends(get_session)]
StoreDep = Annotated[ArtifactStore, Depends(get_store)]
QueueDep = Annotated[Celery, Depends(get_queue)]
