"""Job and stage state: the transitions the API, the worker and the reconciler make.

Every transition that two processes could race on is a single conditional
UPDATE, so exactly one of them wins (a stage is claimed once, re-queued once,
finished once by the holder of its lease).
"""

from __future__ import annotations

import datetime as dt
import uuid
from dataclasses import dataclass
from typing import Any

from sqlalchemy import and_, delete, or_, select, update
from sqlalchemy.orm import Session

from core.db import Artifact, CacheEntry, Job, Stage, utcnow

JOB_STATUSES = ("queued", "running", "succeeded", "failed", "canceled")
STAGE_STATUSES = JOB_STATUSES + ("skipped",)
DONE = ("succeeded", "skipped")
FINAL = ("succeeded", "failed", "canceled")


def new_id() -> str:
    return uuid.uuid4().hex


def create_job(session: Session, *, input_name: str, input_sha256: str, input_size: int,
               input_format: str, params: dict[str, Any], stage_names: list[str],
               parent_id: str | None = None) -> Job:
    job = Job(id=new_id(), input_name=input_name, input_sha256=input_sha256, input_size=input_size,
              input_format=input_format, params=params, parent_id=parent_id, status="queued")
    job.stages = [Stage(name=n, position=i, status="queued", task_id=new_id())
                  for i, n in enumerate(stage_names)]
    session.add(job)
    session.flush()
    return job


def add_artifact(session: Session, job_id: str, *, name: str, stage: str, sha256: str, size: int) -> None:
    session.execute(delete(Artifact).where(Artifact.job_id == job_id, Artifact.name == name))
    session.add(Artifact(job_id=job_id, name=name, stage=stage, sha256=sha256, size=size))


def job_progress(job: Job) -> float:
    if not job.stages:
        return 1.0
    parts = [1.0 if s.status in DONE else s.progress for s in job.stages]
    return round(sum(parts) / len(parts), 4)


def refresh_job_status(session: Session, job_id: str) -> str:
    """Derive the job's status from its stages and store it (a canceled job stays canceled)."""
    job = session.get(Job, job_id, populate_existing=True)
    if job is None:
        return "deleted"
    statuses = [s.status for s in job.stages]
    if job.status == "canceled" or job.cancel_requested:
        status = "canceled"
    elif "failed" in statuses:
        status = "failed"
        failed = next(s for s in job.stages if s.status == "failed")
        job.error = failed.error
    elif all(s in DONE for s in statuses):
        status = "succeeded"
    elif any(s != "queued" for s in statuses):
        status = "running"
    else:
        status = "queued"
    job.status = status
    job.updated_at = utcnow()
    return status


def request_cancel(session: Session, job: Job) -> bool:
    """Mark a job canceled; queued stages are canceled now, a running one stops at its next check.

    Returns False when the job had already ended.
    """
    if job.status in FINAL:
        return False
    job.cancel_requested = True
    job.status = "canceled"
    job.updated_at = utcnow()
    session.execute(update(Stage).where(Stage.job_id == job.id, Stage.status == "queued")
                    .values(status="canceled"))
    return True


@dataclass(frozen=True)
class Claim:
    token: str
    attempt: int


def claim_stage(session: Session, job_id: str, name: str, *, lease_s: float, worker: str) -> Claim | None:
    """Take a queued stage (or one whose lease ran out) for this worker, or None if another has it."""
    now = utcnow()
    token = new_id()
    result = session.execute(
        update(Stage)
        .where(Stage.job_id == job_id, Stage.name == name,
               or_(Stage.status == "queued",
                   and_(Stage.status == "running", Stage.lease_expires_at < now)))
        .values(status="running", lease_token=token, lease_expires_at=now + dt.timedelta(seconds=lease_s),
                worker=worker, attempts=Stage.attempts + 1, started_at=now, finished_at=None,
                progress=0.0, message=None, error=None)
        .execution_options(synchronize_session=False))
    if result.rowcount != 1:
        return None
    attempt = session.execute(select(Stage.attempts).where(Stage.job_id == job_id, Stage.name == name)).scalar_one()
    refresh_job_status(session, job_id)
    return Claim(token=token, attempt=attempt)


def renew_lease(session: Session, token: str, *, lease_s: float, progress: float | None = None,
                message: str | None = None) -> bool:
    """Extend a held lease (and record progress); False when the lease was lost."""
    values: dict[str, Any] = {"lease_expires_at": utcnow() + dt.timedelta(seconds=lease_s)}
    if progress is not None:
        values["progress"] = max(0.0, min(1.0, float(progress)))
    if message is not None:
        values["message"] = message[:500]
    result = session.execute(update(Stage).where(Stage.lease_token == token, Stage.status == "running")
                             .values(**values).execution_options(synchronize_session=False))
    return result.rowcount == 1


def finish_stage(session: Session, job_id: str, token: str, *, status: str, error: dict | None = None,
                 cache_key: str | None = None, reused_from: str | None = None,
                 started_at: dt.datetime | None = None, finished_at: dt.datetime | None = None,
                 message: str | None = None) -> bool:
    """End the stage held under `token`; False (and nothing written) when the lease was lost."""
    if status not in ("succeeded", "skipped", "failed", "canceled"):
        raise ValueError(f"not a final stage status: {status!r}")
    values: dict[str, Any] = {
        "status": status, "error": error, "cache_key": cache_key, "reused_from": reused_from,
        "finished_at": finished_at or utcnow(), "lease_token": None, "lease_expires_at": None,
        "progress": 1.0 if status in DONE else Stage.progress,
    }
    if started_at is not None:
        values["started_at"] = started_at
    if message is not None:
        values["message"] = message[:500]
    result = session.execute(update(Stage).where(Stage.job_id == job_id, Stage.lease_token == token,
                                                 Stage.status == "running")
                             .values(**values).execution_options(synchronize_session=False))
    if result.rowcount != 1:
        return False
    refresh_job_status(session, job_id)
    return True


def is_cancel_requested(session: Session, job_id: str) -> bool:
    flag = session.execute(select(Job.cancel_requested).where(Job.id == job_id)).scalar_one_or_none()
    return flag is None or bool(flag)


def lookup_cache(session: Session, key: str) -> CacheEntry | None:
    return session.get(CacheEntry, key)


def store_cache(session: Session, *, key: str, stage: str, outputs: dict[str, Any], job_id: str,
                started_at: dt.datetime | None, finished_at: dt.datetime | None) -> None:
    if session.get(CacheEntry, key) is None:
        session.add(CacheEntry(cache_key=key, stage=stage, outputs=outputs, job_id=job_id,
                               started_at=started_at, finished_at=finished_at))


@dataclass(frozen=True)
class Requeue:
    job_id: str
    stage: str


def reconcile(session: Session, *, max_attempts: int) -> list[Requeue]:
    """Re-queue stages whose worker died (lease lapsed); fail those that died `max_attempts` times."""
    now = utcnow()
    lapsed = session.execute(select(Stage).where(Stage.status == "running",
                                                 Stage.lease_expires_at < now)).scalars().all()
    requeue = []
    for stage in lapsed:
        if stage.job.cancel_requested:
            values: dict[str, Any] = {"status": "canceled", "finished_at": now, "lease_token": None,
                                      "lease_expires_at": None, "message": "canceled by the user"}
        elif stage.attempts >= max_attempts:
            error = {
                "type": "urn:cloud2cnc:problem:worker-lost",
                "title": "Worker lost",
                "detail": f"the worker running stage {stage.name} stopped {stage.attempts} times "
                          "(killed, out of memory or its machine went away); giving up",
                "stage": stage.name,
            }
            values = {"status": "failed", "error": error, "finished_at": now,
                                      "lease_token": None, "lease_expires_at": None}
        else:
            values = {"status": "queued", "lease_token": None, "lease_expires_at": None,
                      "task_id": new_id(), "message": "re-queued: its worker stopped answering"}
        result = session.execute(update(Stage).where(Stage.id == stage.id, Stage.lease_token == stage.lease_token,
                                                     Stage.status == "running")
                                 .values(**values).execution_options(synchronize_session=False))
        if result.rowcount == 1:
            refresh_job_status(session, stage.job_id)
            if values["status"] == "queued":
                requeue.append(Requeue(stage.job_id, stage.name))
    return requeue


def delete_job(session: Session, job: Job) -> list[str]:
    """Delete a job; returns the artifact hashes that no other job or cache entry still uses."""
    hashes = {a.sha256 for a in job.artifacts}
    session.delete(job)
    session.flush()
    if not hashes:
        return []
    used = set(session.execute(select(Artifact.sha256).where(Artifact.sha256.in_(hashes))).scalars())
    used |= set(session.execute(select(Job.input_sha256).where(Job.input_sha256.in_(hashes))).scalars())
    orphans = sorted(hashes - used)
    # Cache entries that point at removed files would hand out missing artifacts: drop them.
    for entry in session.execute(select(CacheEntry)).scalars():
        if any(o.get("sha256") in orphans for o in entry.outputs.values()):
            session.delete(entry)
    return orphans
