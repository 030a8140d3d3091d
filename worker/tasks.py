"""Thin Celery tasks: a task names a job and a stage; the work lives in `worker.runner`."""

from __future__ import annotations

from celery import shared_task
from celery.exceptions import Ignore

from core.config import get_settings
from core.queue import TASK_NAME
from worker.runner import Outcome, run_stage


@shared_task(name=TASK_NAME, bind=True)
def run_stage_task(self, job_id: str, stage: str) -> None:
    if run_stage(get_settings(), job_id, stage) is Outcome.STOP:
        # Ignore ends the chain: the next stages of a failed, canceled or duplicate run are not sent.
        raise Ignore()
