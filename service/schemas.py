"""Response and request bodies of the API."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

JobStatus = Literal["queued", "running", "succeeded", "failed", "canceled"]
StageStatus = Literal["queued", "running", "succeeded", "failed", "canceled", "skipped"]


class ProblemOut(BaseModel):
    """RFC 9457 problem details."""

    model_config = ConfigDict(extra="allow")
    type: str
    title: str
    status: int | None = None
    detail: str
    instance: str | None = None
    stage: str | None = None


class StageOut(BaseModel):
    name: str
    status: StageStatus
    progress: float = Field(ge=0, le=1)
    message: str | None
    started_at: dt.datetime | None
    finished_at: dt.datetime | None
    duration_s: float | None
    attempts: int
    reused_from: str | None = Field(description="Job whose finished stage was reused (same inputs and params).")
    error: ProblemOut | None


class ArtifactOut(BaseModel):
    name: str
    stage: str
    size_bytes: int
    sha256: str
    media_type: str
    url: str


class InputOut(BaseModel):
    name: str = Field(description="The uploaded file's name, for display only; the server stores it under its hash.")
    format: str
    size_bytes: int
    sha256: str


class JobOut(BaseModel):
    id: str
    status: JobStatus
    created_at: dt.datetime
    updated_at: dt.datetime
    progress: float = Field(ge=0, le=1)
    input: InputOut
    params: dict[str, Any]
    parent_id: str | None = Field(description="The job this one was rerun from.")
    stages: list[StageOut]
    error: ProblemOut | None
    artifacts: list[ArtifactOut]
    links: dict[str, str]


class JobList(BaseModel):
    items: list[JobOut]
    next_cursor: str | None = Field(description="Pass as `cursor` for the next page; null on the last page.")


class RerunIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    params: dict[str, Any] = Field(default_factory=dict,
                                   description="Changed parameters, merged into the original job's parameters.")


class Health(BaseModel):
    status: Literal["ok"]
    checks: dict[str, str] = Field(default_factory=dict)
