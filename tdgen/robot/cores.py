"""One launch of parallel compiled code at a time in a process.

numba's threading layers (workqueue, the fallback; here omp is taken) are not safe for two threads launching parallel code at
once: it aborts the process. Every `prange` loop here (the sphere model's verdicts, points.csv's
formatting) runs under `LAUNCH`.
"""
from __future__ import annotations

import threading

LAUNCH = threading.Lock()
