"""The worker's Celery application: the shared configuration plus the stage task.

`celery -A worker.celery_app worker` and `cloud2cnc worker` both load this module.
"""

from __future__ import annotations

import os

from core.config import get_settings, set_thread_limits
from core.queue import get_celery

settings = get_settings()
set_thread_limits(settings)  # before numpy loads in the pool children, so a stage does not oversubscribe the cores

app = get_celery(settings)
app.conf.update(imports=("worker.tasks",), worker_concurrency=int(os.environ.get("CLOUD2CNC_CONCURRENCY", "1")))
