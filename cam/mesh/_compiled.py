"""What every compiled (numba) kernel of cam shares: its thread pool, the lock around it, and the three-term
sums written as numpy sums them (so that a kernel can give the vectorised code's results to the bit).

numba's `workqueue` pool is fork-safe (Celery's prefork children, `cam.map_forked`'s children, QuadriFlow's
child) but must not be entered by two Python threads at once, by any kernel: every parallel kernel runs
under the one `KERNEL_LOCK`.
"""

from __future__ import annotations

import math
import threading

import numba
from numba import njit

__all__ = ["KERNEL_LOCK", "dot3", "norm3"]

numba.config.THREADING_LAYER = "workqueue"
KERNEL_LOCK = threading.Lock()


@njit(cache=True, inline="always")
def dot3(x0, x1, x2, y0, y1, y2):
    """x · y as numpy's einsum("ij,ij->i") sums three products: (x0 y0 + x2 y2) + x1 y1."""
    return (x0 * y0 + x2 * y2) + x1 * y1


@njit(cache=True, inline="always")
def norm3(x0, x1, x2):
    """|x| as np.linalg.norm(axis=1) computes it: the square root of (x0² + x1²) + x2²."""
    return math.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
