"""Turn database rows into API bodies."""

from __future__ import annotations

import datetime as dt
from pathlib import PurePath

from core.db import Artifact, Job, Stage
from core.jobs import job_progress
from service.schemas import ArtifactOut, InputOut, JobOut, StageOut

MEDIA_TYPES = {
    ".ply": "application/x-ply",
    ".obj": "model/obj",
    ".stl": "model/stl",
    ".json": "application/json",
    ".nc": "text/x-gcode",
    ".csv": "text/csv",
    ".igs": "model/iges",
    ".step": "model/step",
    ".pcd": "application/x-pcd",
    ".xyz": "text/plain",
    ".html": "text/html; charset=utf-8",
}


def media_type(name: str) -> str:
    return MEDIA_TYPES.get(PurePath(name).suffix.lower(), "application/octet-stream")


def _utc(t: dt.datetime | None) -> dt.datetime | None:
    return t.replace(tzinfo=dt.UTC) if t is not None and t.tzinfo is None else t


def stage_out(stage: Stage) -> StageOut:
    duration = None
    if stage.started_at and stage.finished_at:
        duration = round((stage.finished_at - stage.started_at).total_seconds(), 3)
    return StageOut(name=stage.name, status=stage.status, progress=stage.progress, message=stage.message,
                    started_at=_utc(stage.started_at), finished_at=_utc(stage.finished_at), duration_s=duration,
                    attempts=stage.attempts, reused_from=stage.reused_from, error=stage.error)


def artifact_out(job_id: str, a: Artifact) -> ArtifactOut:
    return ArtifactOut(name=a.name, stage=a.stage, size_bytes=a.size, sha256=a.sha256,
                       media_type=media_type(a.name), url=f"/v1/jobs/{job_id}/artifacts/{a.name}")


def job_out(job: Job) -> JobOut:
    base = f"/v1/jobs/{job.id}"
    return JobOut(
        id=job.id, status=job.status, created_at=_utc(job.created_at), updated_at=_utc(job.updated_at),
        progress=job_progress(job),
        input=InputOut(name=job.input_name, format=job.input_format, size_bytes=job.input_size,
                       sha256=job.input_sha256),
        params=job.params, parent_id=job.parent_id, stages=[stage_out(s) for s in job.stages],
        error=job.error, artifacts=[artifact_out(job.id, a) for a in job.artifacts],
        links={"self": base, "artifacts": f"{base}/artifacts", "cancel": f"{base}/cancel",
               "rerun": f"{base}/rerun"},
    )
