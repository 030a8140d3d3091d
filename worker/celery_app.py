"""The worker's Celery application: the shared configuration plus the stage task.

`celery -A worker.celery_app worker` and `cloud2cnc worker` both load this module.
"""

from __future__ import annotations

import os

from core.config import get_settings, stage_processes
from core.queue import get_celery

settings = get_settings()
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    # Set before numpy loads in the pool children, so a stage does not oversubscribe the cores.
    os.environ.setdefault(var, str(settings.blas_threads))
# The compiled drop-cutter's threads: the stage's share of the CPUs, like fit's processes.
os.environ.setdefault("NUMBA_NUM_THREADS", str(stage_processes(settings.stage_processes)))

app = get_celery(settings)
app.conf.update(imports=("worker.tasks",), worker_concurrency=int(os.environ.get("CLOUD2CNC_CONCURRENCY", "1")))
