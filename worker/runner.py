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
from dataclasses import dataclass
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


@dataclass
class _Claimed:
    """A stage this worker holds: its lease, the job's params, and the artifacts earlier stages left."""

    claim: Any
    params: JobParams
    available: dict[str, str]
    input_name: str


def _claim_stage(Session, settings: Settings, job_id: str, stage_name: str) -> _Claimed | Outcome:
    """Take the stage if it is this chain's next one and nobody holds it; otherwise what the chain does."""
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
        # Only what earlier stages wrote: a later stage may reuse a name (plan rewrites setup.json).
        earlier = {s.name for s in previous}
        available = {a.name: a.sha256 for a in job.artifacts if a.stage in earlier}
        available["input"] = job.input_sha256
        return _Claimed(claim, JobParams.model_validate(job.params), available, _input_name(job))


def _reuse_cached(Session, store: ArtifactStore, job_id: str, stage_name: str, token: str, key: str
                  ) -> Outcome | None:
    """Finish the stage from a cached run with the same key whose files are still stored; None if none."""
    with Session.begin() as session:
        hit = jobs.lookup_cache(session, key)
        if hit is None or not all(store.exists(o["sha256"]) for o in hit.outputs.values()):
            return None
        _add_artifacts(session, job_id, stage_name, hit.outputs)
        ok = jobs.finish_stage(session, job_id, token, status="succeeded", cache_key=key,
                               reused_from=hit.job_id, started_at=hit.started_at, finished_at=hit.finished_at,
                               message=f"reused from job {hit.job_id}")
        if not ok:
            session.rollback()
        return Outcome.CONTINUE if ok else Outcome.STOP


def _link_inputs(store: ArtifactStore, spec: StageSpec, claimed: _Claimed, in_dir: Path) -> dict[str, Path]:
    """The stage's inputs as links in its scratch folder, under their artifact names (the upload as input.<ext>)."""
    inputs: dict[str, Path] = {}
    for name, sha in claimed.available.items():
        if name == "input" or name in spec.inputs:
            link = in_dir / (claimed.input_name if name == "input" else name)
            link.symlink_to(store.path(sha).resolve())
            inputs[name] = link
    return inputs


class _Callbacks:
    """The stage's lease renewal, progress and cancel check, each throttled to one database write or read
    every half second; `heartbeat` is set once the lease is being renewed."""

    def __init__(self, Session, settings: Settings, job_id: str, token: str) -> None:
        self._Session, self._settings, self._job_id, self._token = Session, settings, job_id, token
        self._lock = threading.Lock()
        self._last_write = self._last_cancel = 0.0
        self._canceled = False
        self.heartbeat: _Heartbeat | None = None
        self.last: tuple[float, str | None] = (0.0, None)  # the latest progress, for a stage out of time

    def renew(self, progress: float | None = None, message: str | None = None) -> bool:
        with self._lock, self._Session.begin() as session:
            return jobs.renew_lease(session, self._token, lease_s=self._settings.stage_lease_s,
                                    progress=progress, message=message)

    def progress(self, fraction: float, message: str | None = None) -> None:
        self.last = (fraction, message or self.last[1])
        now = time.monotonic()
        # Throttle DB writes; the final 1.0 is recorded when the stage finishes.
        if now - self._last_write >= 0.5:
            self._last_write = now
            self.renew(fraction, message)

    def check_cancel(self) -> None:
        now = time.monotonic()
        if self._canceled or (self.heartbeat is not None and self.heartbeat.lost):
            raise StageCanceled()
        if now - self._last_cancel >= 0.5:
            self._last_cancel = now
            with self._Session() as session:
                if jobs.is_cancel_requested(session, self._job_id):
                    self._canceled = True
                    raise StageCanceled()


def _failure_detail(exc: BaseException, spec: StageSpec, settings: Settings, job_id: str,
                    last: tuple[float, str | None] = (0.0, None)) -> str:
    """What the user reads about an exception that is not theirs to act on: a time limit (where the stage
    was, from its `last` progress, and what makes it faster), or our bug."""
    if type(exc).__name__ == "SoftTimeLimitExceeded":
        limit = time_limit_s(spec, settings)
        fraction, message = last
        where = f"{100 * fraction:.0f} %" + (f" ({message})" if message else "")
        faster = f"; {spec.faster} make it faster" if spec.faster else ""
        return (f"stage {spec.name} ran longer than its limit of {limit:.0f} s; it had got to {where}{faster}; "
                f"an operator can raise the limit (CLOUD2CNC_STAGE_TIME_LIMITS={spec.name}=SECONDS)")
    ref = uuid.uuid4().hex[:12]
    log.exception("stage %s of job %s crashed (ref %s)", spec.name, job_id, ref)
    return f"internal error in stage {spec.name} (reference {ref}); the operator's log has details"


def _record_success(Session, store: ArtifactStore, spec: StageSpec, job_id: str, token: str, key: str,
                    outputs: dict[str, Path], started) -> Outcome:
    stored = _store_outputs(store, spec, outputs)
    with Session.begin() as session:
        _add_artifacts(session, job_id, spec.name, stored)
        finished = utcnow()
        ok = jobs.finish_stage(session, job_id, token, status="succeeded", cache_key=key,
                               started_at=started, finished_at=finished)
        if ok:
            jobs.store_cache(session, key=key, stage=spec.name, outputs=stored, job_id=job_id,
                             started_at=started, finished_at=finished)
        else:
            session.rollback()
    if not ok:
        _drop_unreferenced(Session, store, [o["sha256"] for o in stored.values()])
    return Outcome.CONTINUE if ok else Outcome.STOP


def run_stage(settings: Settings, job_id: str, stage_name: str) -> Outcome:
    """Claim one stage of one job, reuse a cached result or run it, store what it wrote, record the outcome."""
    Session = get_sessionmaker(settings.resolved_database_url)
    store = ArtifactStore(settings.artifacts_dir)
    spec = {s.name: s for s in load_stages(settings.stage_plugins, settings.pipeline)}.get(stage_name)
    claimed = _claim_stage(Session, settings, job_id, stage_name)
    if isinstance(claimed, Outcome):
        return claimed
    token = claimed.claim.token

    def finish(**kwargs: Any) -> bool:
        with Session.begin() as session:
            return jobs.finish_stage(session, job_id, token, **kwargs)

    if spec is None:
        finish(status="failed", error=_problem("unknown-stage", "Unknown stage",
                                               f"this worker has no stage {stage_name!r}; upgrade it", stage_name))
        return Outcome.STOP
    stage_settings = {k: getattr(settings, k) for k in spec.settings}
    run = implementation(stage_name, settings.stage_plugins)
    key = cache_key(spec, claimed.params, claimed.available, stage_settings, code=code_digest(run.__module__))
    reused = _reuse_cached(Session, store, job_id, stage_name, token, key)
    if reused is not None:
        return reused
    scratch = settings.data_dir / "work" / f"{job_id}-{stage_name}-{token}"
    (scratch / "out").mkdir(parents=True)
    (scratch / "in").mkdir()
    calls = _Callbacks(Session, settings, job_id, token)
    ctx = StageContext(job_id=job_id, stage=stage_name, inputs=_link_inputs(store, spec, claimed, scratch / "in"),
                       out_dir=scratch / "out", params=claimed.params, settings=stage_settings,
                       progress=calls.progress, check_cancel=calls.check_cancel)
    started = utcnow()
    try:
        with _Heartbeat(calls.renew, settings.stage_lease_s / 4) as calls.heartbeat:
            try:
                outputs = run(ctx)
            except StageSkipped as exc:
                ok = _finish_keeping(Session, store, spec, job_id, token, exc.outputs,
                                     status="skipped", message=str(exc) or None)
                return Outcome.CONTINUE if ok else Outcome.STOP
            except StageCanceled:
                finish(status="canceled", message="canceled by the user")
                return Outcome.STOP
            except (StageError, GeometryError) as exc:
                _finish_keeping(Session, store, spec, job_id, token, getattr(exc, "outputs", {}),
                                status="failed", error=_problem("stage-failed", f"Stage {stage_name} failed",
                                                                str(exc), stage_name))
                return Outcome.STOP
            except Exception as exc:  # noqa: BLE001 — anything else is our bug; the user gets a reference
                finish(status="failed", error=_problem("stage-error", f"Stage {stage_name} failed",
                                                       _failure_detail(exc, spec, settings, job_id, calls.last),
                                                       stage_name))
                return Outcome.STOP
        return _record_success(Session, store, spec, job_id, token, key, outputs, started)
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
