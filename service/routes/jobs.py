"""/v1/jobs: create, list, get, cancel, rerun, delete."""

from __future__ import annotations

import base64
import binascii
import datetime as dt
import hashlib
import json
import tempfile
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Body, Header, Query, Request, Response
from pydantic import ValidationError
from sqlalchemy import and_, delete, or_, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from cam.io.formats import FORMAT_EXTENSIONS, describe_unsupported, sniff_format
from core import jobs as jobstore
from core.db import IdempotencyKey, Job, get_sessionmaker
from core.params import JobParams, merge_params
from core.queue import enqueue_stages, revoke
from core.stages import load_stages
from core.store import ArtifactStore
from service.deps import QueueDep, SessionDep, SettingsDep, StoreDep
from service.present import job_out
from service.problems import Problem, validation_errors
from service.schemas import JobList, JobOut, JobStatus, ProblemOut, RerunIn
from service.upload import Upload, receive_upload

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

_PROBLEM = {"model": ProblemOut, "content": {"application/problem+json": {}}}
_ERRORS = {s: _PROBLEM for s in (400, 401, 404, 409, 413, 415, 422, 503)}

_UPLOAD_SCHEMA = {
    "requestBody": {
        "required": True,
        "content": {"multipart/form-data": {"schema": {
            "type": "object",
            "required": ["file"],
            "properties": {
                "file": {"type": "string", "format": "binary",
                         "description": "Point cloud (PLY, XYZ/PTS/TXT/CSV, PCD, E57, LAS/LAZ) or mesh (OBJ, STL, PLY with faces)."},
                "params": {"type": "string", "description": "JobParams as JSON; omitted groups take defaults."},
            },
        }}},
    }
}


def _not_found(job_id: str) -> Problem:
    return Problem(404, "job-not-found", "Job not found", f"there is no job {job_id!r}")


def _get_job(session: Session, job_id: str) -> Job:
    job = session.get(Job, job_id) if len(job_id) <= 64 else None
    if job is None:
        raise _not_found(job_id)
    return job


def _parse_params(data: Any) -> dict[str, Any]:
    try:
        return JobParams.model_validate(data).model_dump(mode="json")
    except ValidationError as exc:
        errors = validation_errors(exc.errors(include_url=False), prefix="params.")
        detail = "; ".join(f"{e['field']}: {e['message']}" for e in errors)
        raise Problem(422, "invalid-params", "Invalid parameters", detail, errors=errors) from None


def _params_from_text(text: str | None) -> dict[str, Any]:
    if text is None or not text.strip():
        return _parse_params({})
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise Problem(422, "invalid-params", "Invalid parameters",
                      f"`params` is not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}",
                      errors=[{"field": "params", "message": "not valid JSON"}]) from None
    if not isinstance(data, dict):
        raise Problem(422, "invalid-params", "Invalid parameters", "`params` must be a JSON object",
                      errors=[{"field": "params", "message": "must be a JSON object"}])
    return _parse_params(data)


def _store_json(store: ArtifactStore, obj: Any, tmp_dir: Path) -> tuple[str, int]:
    tmp_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=tmp_dir, delete=False, suffix=".json") as fh:
        json.dump(obj, fh, indent=2)
        fh.write("\n")
    return store.put(Path(fh.name), move=True)


def _start_job(session: Session, store: ArtifactStore, settings, *, input_name: str, input_sha256: str,
               input_size: int, input_format: str, params: dict[str, Any], parent_id: str | None = None) -> Job:
    stages = [s.name for s in load_stages(settings.stage_plugins, settings.pipeline)]
    job = jobstore.create_job(session, input_name=input_name, input_sha256=input_sha256, input_size=input_size,
                              input_format=input_format, params=params, stage_names=stages, parent_id=parent_id)
    jobstore.add_artifact(session, job.id, name="input" + FORMAT_EXTENSIONS[input_format], stage="upload",
                          sha256=input_sha256, size=input_size)
    sha, size = _store_json(store, params, settings.uploads_dir)
    jobstore.add_artifact(session, job.id, name="params.json", stage="upload", sha256=sha, size=size)
    return job


def _enqueue(session: Session, queue, settings, job: Job) -> None:
    try:
        enqueue_stages(queue, settings, job.id, [(s.name, s.task_id) for s in job.stages])
    except Exception as exc:  # noqa: BLE001 — the broker is down: the job must not sit queued forever
        for s in job.stages:
            s.status = "canceled"
        job.status = "failed"
        job.error = {"type": "urn:cloud2cnc:problem:queue-unavailable", "title": "Queue unavailable",
                     "detail": f"the job could not be queued: {type(exc).__name__}; try again later"}
        session.commit()
        raise Problem(503, "queue-unavailable", "Queue unavailable",
                      "the job queue (broker) is not reachable; try again later") from None


def _location(response: Response, job_id: str) -> None:
    response.headers["Location"] = f"/v1/jobs/{job_id}"


def _reserve_key(Session, key: str) -> bool:
    """Insert the key as `creating`; False when it exists and is done (a replay), 409 while in progress."""
    with Session() as session:
        try:
            session.add(IdempotencyKey(key=key, state="creating"))
            session.commit()
            return True
        except IntegrityError:
            session.rollback()
            row = session.get(IdempotencyKey, key)
            if row is None or row.state == "creating":
                raise Problem(409, "idempotency-in-progress", "Request in progress",
                              "a request with this Idempotency-Key is still being processed; retry shortly") from None
            return False


def _release_key(Session, key: str) -> None:
    with Session() as session:
        session.execute(delete(IdempotencyKey).where(IdempotencyKey.key == key))
        session.commit()


def _check_upload(upload: Upload) -> tuple[dict[str, Any], str]:
    """The validated params and the sniffed format of a received upload, or a 4xx problem."""
    if upload.path is None:
        raise Problem(422, "missing-file", "Missing file",
                      "the request has no `file` part; send the point cloud or mesh as `file`",
                      errors=[{"field": "file", "message": "required"}])
    if upload.size == 0:
        raise Problem(422, "empty-file", "Empty file", "the uploaded file is empty",
                      errors=[{"field": "file", "message": "empty"}])
    params = _params_from_text(upload.params_text)
    fmt = sniff_format(upload.head, total_size=upload.size)
    if fmt is None:
        looks_like = describe_unsupported(upload.head)
        raise Problem(415, "unsupported-format", "Unsupported file format",
                      f"{upload.filename or 'the upload'} is not a point cloud or mesh format we read"
                      + (f" (it looks like {looks_like})" if looks_like else "")
                      + ": send PLY, XYZ/PTS/TXT/CSV, PCD, E57, LAS/LAZ, OBJ or STL (the format is read from the content, "
                      "not the extension)",
                      errors=[{"field": "file", "message": "unrecognised format"}])
    return params, fmt


def _create_from_upload(Session, store: ArtifactStore, queue, settings, upload: Upload,
                        key: str | None, key_is_new: bool) -> tuple[str, dict[str, Any]]:
    """Blocking part of job creation (database, store, broker); returns (job id, response body)."""
    with Session() as session:
        try:
            try:
                params, fmt = _check_upload(upload)
                request_hash = hashlib.sha256((upload.sha256 + json.dumps(params, sort_keys=True)).encode()).hexdigest()
                if key is not None and not key_is_new:
                    row = session.get(IdempotencyKey, key)
                    if row.request_hash != request_hash:
                        raise Problem(422, "idempotency-key-reused", "Idempotency-Key reused",
                                      "this Idempotency-Key was used with a different file or parameters")
                    return row.job_id, row.response  # the first response, replayed as it was sent
                store.put(upload.path, sha256=upload.sha256, move=True)
            finally:
                upload.discard()
            job = _start_job(session, store, settings, input_name=upload.filename or "upload",
                             input_sha256=upload.sha256, input_size=upload.size, input_format=fmt, params=params)
            if key is not None:
                row = session.get(IdempotencyKey, key)
                row.request_hash, row.job_id = request_hash, job.id
            session.commit()
            _enqueue(session, queue, settings, job)
        except BaseException:
            session.rollback()
            if key is not None and key_is_new:
                _release_key(Session, key)
            raise
        session.refresh(job)
        out = job_out(job).model_dump(mode="json")
        if key is not None:
            row = session.get(IdempotencyKey, key)
            row.state, row.response = "done", out
            session.commit()
        return job.id, out


@router.post("", status_code=202, response_model=JobOut, responses=_ERRORS, openapi_extra=_UPLOAD_SCHEMA,
             summary="Upload a point cloud or mesh and start a job")
async def create_job(request: Request, response: Response, store: StoreDep, queue: QueueDep,
                     settings: SettingsDep,
                     idempotency_key: Annotated[str | None, Header(max_length=255)] = None) -> JobOut:
    # Only the streaming stays on the event loop; database, store and broker calls block, so they
    # run in the threadpool with a session opened and closed there (a session held across the
    # response would pin a pooled connection until a teardown that needs this very loop).
    Session = get_sessionmaker(settings.resolved_database_url)
    key_is_new = False
    if idempotency_key is not None:
        if not idempotency_key.strip() or not idempotency_key.isprintable():
            raise Problem(400, "invalid-idempotency-key", "Invalid Idempotency-Key",
                          "Idempotency-Key must be 1 to 255 printable characters")
        key_is_new = await run_in_threadpool(_reserve_key, Session, idempotency_key)
    try:
        upload = await receive_upload(request, tmp_dir=settings.uploads_dir, max_bytes=settings.max_upload_bytes)
    except BaseException:
        if key_is_new:
            await run_in_threadpool(_release_key, Session, idempotency_key)
        raise
    job_id, body = await run_in_threadpool(_create_from_upload, Session, store, queue, settings, upload,
                                           idempotency_key, key_is_new)
    _location(response, job_id)
    return JobOut.model_validate(body)


def _encode_cursor(job: Job) -> str:
    raw = json.dumps({"t": job.created_at.isoformat(), "id": job.id}).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def _decode_cursor(cursor: str) -> tuple[dt.datetime, str]:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        data = json.loads(raw)
        return dt.datetime.fromisoformat(data["t"]), str(data["id"])
    except (binascii.Error, ValueError, KeyError, TypeError, UnicodeDecodeError):
        raise Problem(400, "invalid-cursor", "Invalid cursor",
                      "the cursor is not one this API returned; start again without it") from None


@router.get("", response_model=JobList, responses=_ERRORS, summary="List jobs, newest first")
def list_jobs(session: SessionDep,
              status: Annotated[JobStatus | None, Query(description="Only jobs in this status.")] = None,
              limit: Annotated[int, Query(ge=1, le=200)] = 50,
              cursor: Annotated[str | None, Query(max_length=512)] = None) -> JobList:
    query = select(Job).order_by(Job.created_at.desc(), Job.id.desc())
    if status is not None:
        query = query.where(Job.status == status)
    if cursor:
        t, job_id = _decode_cursor(cursor)
        query = query.where(or_(Job.created_at < t, and_(Job.created_at == t, Job.id < job_id)))
    rows = session.execute(query.limit(limit + 1)).scalars().all()
    more = len(rows) > limit
    rows = rows[:limit]
    return JobList(items=[job_out(j) for j in rows], next_cursor=_encode_cursor(rows[-1]) if more else None)


@router.get("/{job_id}", response_model=JobOut, responses=_ERRORS, summary="A job with its stages and artifacts")
def get_job(job_id: str, session: SessionDep) -> JobOut:
    return job_out(_get_job(session, job_id))


@router.post("/{job_id}/cancel", status_code=202, response_model=JobOut, responses=_ERRORS,
             summary="Cancel a queued or running job")
def cancel_job(job_id: str, session: SessionDep, queue: QueueDep) -> JobOut:
    job = _get_job(session, job_id)
    queued = [s.task_id for s in job.stages if s.status == "queued"]
    if not jobstore.request_cancel(session, job):
        raise Problem(409, "job-finished", "Job already finished",
                      f"job {job_id} is {job.status}; only queued or running jobs can be canceled")
    session.commit()
    revoke(queue, queued)
    session.refresh(job)
    return job_out(job)


@router.post("/{job_id}/rerun", status_code=202, response_model=JobOut, responses=_ERRORS,
             summary="Start a new job from the same input with changed parameters")
def rerun_job(job_id: str, response: Response, session: SessionDep, store: StoreDep, queue: QueueDep,
              settings: SettingsDep, body: Annotated[RerunIn, Body()] = RerunIn()) -> JobOut:
    old = _get_job(session, job_id)
    if not store.exists(old.input_sha256):
        raise Problem(409, "input-missing", "Input missing",
                      f"the input of job {job_id} is no longer stored; upload it again")
    params = _parse_params(merge_params(old.params, body.params))
    job = _start_job(session, store, settings, input_name=old.input_name, input_sha256=old.input_sha256,
                     input_size=old.input_size, input_format=old.input_format, params=params, parent_id=old.id)
    session.commit()
    _enqueue(session, queue, settings, job)
    session.refresh(job)
    _location(response, job.id)
    return job_out(job)


@router.delete("/{job_id}", status_code=204, responses=_ERRORS, summary="Delete a job and its artifacts")
def delete_job(job_id: str, session: SessionDep, store: StoreDep, queue: QueueDep) -> Response:
    job = _get_job(session, job_id)
    queued = [s.task_id for s in job.stages if s.status == "queued"]
    jobstore.request_cancel(session, job)
    orphans = jobstore.delete_job(session, job)
    session.commit()
    revoke(queue, queued)
    for sha in orphans:
        store.delete(sha)
    return Response(status_code=204)
