"""Run one stage of one job against the job database and the artifact store.

This is the body of the Celery task, kept free of Celery so it can be tested
and reasoned about on its own: claim the stage, reuse a cached result or run
the implementation in a scratch folder, store the outputs, record the outcome.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import threading
import time
import uuid
from enum import Enum
from pathlib import Path
from typing import Any, Callable

from sqlalchemy import select

from cam import GeometryError
from core import jobs
from core.config import Settings
from core.db import Artifact, Job, get_sessionmaker, utcnow
from core.params import JobParams
from core.stages import StageSpec, cache_key, code_digest, load_stages, time_limit_s
from core.store import ArtifactStore
from worker.context import StageCanceled, StageContext, StageError, StageSkipped
from worker.stages import implementation

log = logging.getLogger(__name__)


class Outcome(Enum):
    CONTINUE = "continue"  # the stage is done (now or before): the chain goes on
    STOP = "stop"          # failed, canceled, or someone else holds it: the chain ends here


def _problem(kind: str, title: str, detail: str, stage: str) -> dict[str, Any]:
    return {"type": f"urn:cloud2cnc:problem:{kind}", "title": title, "detail": detail, "stage": stage}


def _input_name(job: Job) -> str:
    from cam.io.formats import FORMAT_EXTENSIONS

    return "input" + FORMAT_EXTENSIONS.get(job.input_format, "")


class _Heartbeat:
    """Renews the stage's lease in the background while the implementation computes."""

    def __init__(self, renew: Callable[[], bool], interval_s: float) -> None:
        self._renew = renew
        self._interval = interval_s
        self._stop = threading.Event()
        self.lost = False
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        while not self._stop.wait(self._interval):
            try:
                if not self._renew():
                    self.lost = True
                    return
            except Exception:  # noqa: BLE001 — a DB hiccup must not kill the stage; the next beat retries
                log.warning("lease renewal failed", exc_info=True)

    def __enter__(self) -> _Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def run_stage(settings: Settings, job_id: str, stage_name: str) -> Outcome:
    Session = get_sessionmaker(settings.resolved_database_url)
    store = ArtifactStore(settings.artifacts_dir)
    specs = {s.name: s for s in load_stages(settings.stage_plugins, settings.pipeline)}
    spec = specs.get(stage_name)
    worker = f"{socket.gethostname()}:{os.getpid()}"

    with Session.begin() as session:
        job = session.get(Job, job_id)
        if job is None or job.cancel_requested or job.status in ("failed", "canceled"):
            return Outcome.STOP
        stage = next((s for s in job.stages if s.name == stage_name), None)
        if stage is None:
            return Outcome.STOP
        if stage.status in jobs.DONE:
            return Outcome.CONTINUE
        previous = [s for s in job.stages if s.position < stage.position]
        if any(s.status not in jobs.DONE for s in previous):
            # Only a chain delivers stages, so this is a stale duplicate message.
            return Outcome.STOP
        claim = jobs.claim_stage(session, job_id, stage_name, lease_s=settings.stage_lease_s, worker=worker)
        if claim is None:
            return Outcome.STOP
        params = JobParams.model_validate(job.params)
        # Only what earlier stages wrote: a later stage may reuse a name (plan rewrites setup.json).
        earlier = {s.name for s in previous}
        available = {a.name: a.sha256 for a in job.artifacts if a.stage in earlier}
        input_name = _input_name(job)
        available["input"] = job.input_sha256

    def finish(**kwargs: Any) -> bool:
        with Session.begin() as session:
            return jobs.finish_stage(session, job_id, claim.token, **kwargs)

    if spec is None:
        finish(status="failed", error=_problem("unknown-stage", "Unknown stage",
                                               f"this worker has no stage {stage_name!r}; upgrade it", stage_name))
        return Outcome.STOP

    stage_settings = {k: getattr(settings, k) for k in spec.settings}
    run = implementation(stage_name, settings.stage_plugins)
    key = cache_key(spec, params, available, stage_settings, code=code_digest(run.__module__))

    with Session.begin() as session:
        hit = jobs.lookup_cache(session, key)
        if hit is not None and all(store.exists(o["sha256"]) for o in hit.outputs.values()):
            _add_artifacts(session, job_id, stage_name, hit.outputs)
            ok = jobs.finish_stage(session, job_id, claim.token, status="succeeded", cache_key=key,
                                   reused_from=hit.job_id, started_at=hit.started_at, finished_at=hit.finished_at,
                                   message=f"reused from job {hit.job_id}")
            if not ok:
                session.rollback()
            return Outcome.CONTINUE if ok else Outcome.STOP

    scratch = settings.data_dir / "work" / f"{job_id}-{stage_name}-{claim.token}"
    out_dir = scratch / "out"
    in_dir = scratch / "in"
    out_dir.mkdir(parents=True)
    in_dir.mkdir()
    inputs: dict[str, Path] = {}
    for name, sha in available.items():
        if name == "input" or name in spec.inputs:
            link = in_dir / (input_name if name == "input" else name)
            link.symlink_to(store.path(sha).resolve())
            inputs[name] = link

    state = {"last_write": 0.0, "last_cancel": 0.0, "canceled": False}
    lock = threading.Lock()

    def renew(progress: float | None = None, message: str | None = None) -> bool:
        with lock, Session.begin() as session:
            return jobs.renew_lease(session, claim.token, lease_s=settings.stage_lease_s,
                                    progress=progress, message=message)

    def progress(fraction: float, message: str | None = None) -> None:
        now = time.monotonic()
        # Throttle DB writes; the final 1.0 is recorded by finish().
        if now - state["last_write"] >= 0.5:
            state["last_write"] = now
            renew(fraction, message)

    def check_cancel() -> None:
        now = time.monotonic()
        if state["canceled"] or heartbeat.lost:
            raise StageCanceled()
        if now - state["last_cancel"] >= 0.5:
            state["last_cancel"] = now
            with Session() as session:
                if jobs.is_cancel_requested(session, job_id):
                    state["canceled"] = True
                    raise StageCanceled()

    ctx = StageContext(job_id=job_id, stage=stage_name, inputs=inputs, out_dir=out_dir, params=params,
                       settings=stage_settings, progress=progress, check_cancel=check_cancel)
    started = utcnow()
    try:
        with _Heartbeat(renew, settings.stage_lease_s / 4) as heartbeat:
            try:
                outputs = run(ctx)
            except StageSkipped as exc:
                ok = _finish_keeping(Session, store, spec, job_id, claim.token, exc.outputs,
                                     status="skipped", message=str(exc) or None)
                return Outcome.CONTINUE if ok else Outcome.STOP
            except StageCanceled:
                finish(status="canceled", message="canceled by the user")
                return Outcome.STOP
            except (StageError, GeometryError) as exc:
                _finish_keeping(Session, store, spec, job_id, claim.token, getattr(exc, "outputs", {}),
                                status="failed", error=_problem("stage-failed", f"Stage {stage_name} failed",
                                                                str(exc), stage_name))
                return Outcome.STOP
            except Exception as exc:  # noqa: BLE001 — anything else is our bug; the user gets a reference
                ref = uuid.uuid4().hex[:12]
                if type(exc).__name__ == "SoftTimeLimitExceeded":
                    limit = time_limit_s(spec, settings.stage_time_limit_s)
                    detail = (f"stage {stage_name} ran longer than its limit of {limit:.0f} s; "
                              "try a smaller input or coarser parameters")
                else:
                    log.exception("stage %s of job %s crashed (ref %s)", stage_name, job_id, ref)
                    detail = f"internal error in stage {stage_name} (reference {ref}); the operator's log has details"
                finish(status="failed", error=_problem("stage-error", f"Stage {stage_name} failed", detail,
                                                       stage_name))
                return Outcome.STOP
        stored = _store_outputs(store, spec, outputs)
        with Session.begin() as session:
            _add_artifacts(session, job_id, stage_name, stored)
            finished = utcnow()
            ok = jobs.finish_stage(session, job_id, claim.token, status="succeeded", cache_key=key,
                                   started_at=started, finished_at=finished)
            if ok:
                jobs.store_cache(session, key=key, stage=stage_name, outputs=stored, job_id=job_id,
                                 started_at=started, finished_at=finished)
            else:
                session.rollback()
        if not ok:
            _drop_unreferenced(Session, store, [o["sha256"] for o in stored.values()])
        return Outcome.CONTINUE if ok else Outcome.STOP
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _finish_keeping(Session, store: ArtifactStore, spec: StageSpec, job_id: str, token: str,
                    outputs: dict[str, Path], **finish: Any) -> bool:
    """End a stage that did not succeed (skipped, failed) and keep what it left: a passed-on input, or files
    for inspection. False when the lease was lost; then the files go again unless another job uses them."""
    kept = _store_outputs(store, spec, outputs)
    with Session.begin() as session:
        ok = jobs.finish_stage(session, job_id, token, **finish)
        if ok:
            _add_artifacts(session, job_id, spec.name, kept)
    if not ok:
        _drop_unreferenced(Session, store, [o["sha256"] for o in kept.values()])
    return ok


def _store_outputs(store: ArtifactStore, spec: StageSpec, outputs: dict[str, Path]) -> dict[str, dict[str, Any]]:
    stored = {}
    for name, path in outputs.items():
        if name not in spec.outputs:
            raise RuntimeError(f"stage {spec.name} wrote undeclared artifact {name!r}")
        sha, size = store.put(Path(path), move=True)
        stored[name] = {"sha256": sha, "size": size}
    return stored


def _add_artifacts(session: Any, job_id: str, stage: str, stored: dict[str, dict[str, Any]]) -> None:
    for name, o in stored.items():
        jobs.add_artifact(session, job_id, name=name, stage=stage, sha256=o["sha256"], size=o["size"])


def _drop_unreferenced(Session: Any, store: ArtifactStore, hashes: list[str]) -> None:
    """Files stored by a stage that lost its lease are removed unless some job uses them."""
    with Session() as session:
        used = set(session.execute(select(Artifact.sha256).where(Artifact.sha256.in_(hashes))).scalars())
    for sha in set(hashes) - used:
        store.delete(sha)
