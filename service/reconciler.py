"""Re-queue stages whose worker died: a background loop beside the API.

Several API processes may run it at once: `jobs.reconcile` re-queues each
lapsed stage with a conditional UPDATE, so only one of them sends its chain.
"""

from __future__ import annotations

import logging
import threading

from core import jobs
from core.config import Settings
from core.db import Job, get_sessionmaker
from core.queue import enqueue_stages, get_celery

log = logging.getLogger(__name__)


def reconcile_once(settings: Settings) -> int:
    """One pass; returns how many stages were re-queued."""
    Session = get_sessionmaker(settings.resolved_database_url)
    with Session.begin() as session:
        requeued = jobs.reconcile(session, max_attempts=settings.max_stage_attempts)
        chains = []
        for item in requeued:
            job = session.get(Job, item.job_id)
            start = next(s.position for s in job.stages if s.name == item.stage)
            chains.append((job.id, [(s.name, s.task_id) for s in job.stages
                                    if s.position >= start and s.status == "queued"]))
    queue = get_celery(settings)
    for job_id, stages in chains:
        log.warning("re-queueing job %s from stage %s: its worker stopped answering", job_id, stages[0][0])
        enqueue_stages(queue, settings, job_id, stages)
    return len(chains)


class Reconciler:
    def __init__(self, settings: Settings) -> None:
        self._settings = settings
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="cloud2cnc-reconciler", daemon=True)

    def _loop(self) -> None:
        while not self._stop.wait(self._settings.reconcile_interval_s):
            try:
                reconcile_once(self._settings)
            except Exception:  # noqa: BLE001 — a passing DB or broker fault; the next pass retries
                log.warning("reconcile pass failed", exc_info=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)
