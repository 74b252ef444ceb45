"""One launch of parallel compiled code at a time in a process.

numba's threading layers are not all safe for two threads launching parallel code at once (the
workqueue layer aborts the process; omp is taken where GNU OpenMP is installed). Every `prange` loop
here (the sphere model's verdicts, points.csv's formatting) runs under `LAUNCH`.
"""
from __future__ import annotations

import threading

LAUNCH = threading.Lock()
