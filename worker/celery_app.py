"""The worker's Celery application: the shared configuration plus the stage task.

`celery -A worker.celery_app worker` and `cloud2cnc worker` both load this module.
"""

from __future__ import annotations

import logging
import os

from celery.signals import task_prerun

from core.config import get_settings, set_thread_limits
from core.queue import get_celery

settings = get_settings()
set_thread_limits(settings)  # before numpy loads in the pool children, so a stage does not oversubscribe the cores

app = get_celery(settings)
app.conf.update(imports=("worker.tasks",), worker_concurrency=int(os.environ.get("CLOUD2CNC_CONCURRENCY", "1")))


@task_prerun.connect
def _remove_stale_scratch(**_: object) -> None:
    """Before each stage run (in the pool child): what runs of killed workers left in data_dir/work."""
    from worker.scratch import remove_stale_scratch

    try:
        remove_stale_scratch(get_settings())
    except Exception:  # housekeeping must not fail a stage; the next run tries again
        logging.getLogger(__name__).warning("stale scratch folders not removed", exc_info=True)
