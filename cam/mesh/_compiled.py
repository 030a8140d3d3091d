"""What every compiled (numba) kernel of cam shares: its thread pool and the lock around it.

numba's `workqueue` pool is fork-safe (Celery's prefork children, `cam.map_forked`'s children, QuadriFlow's
child) but must not be entered by two Python threads at once, by any kernel: every parallel kernel runs
under the one `KERNEL_LOCK`.
"""

from __future__ import annotations

import threading

import numba

__all__ = ["KERNEL_LOCK"]

numba.config.THREADING_LAYER = "workqueue"
KERNEL_LOCK = threading.Lock()
