"""Code that runs uncompiled in tests that are not about compiling.

Our compiled code is kept by what our compiled modules hold (`tdgen/robot/numba_locator.py`): a wheel in a
fresh venv loads this machine's compile only once that compile is done, and an edited copy of a compiled
module would compile its loops again, minutes of CPU that prove nothing about what such a test checks.
Given an empty compiled-code folder and the lock a background compile takes held here, such processes run
what a first start runs before its compile is done (pybullet's exact test, numpy), whatever the machine's
compile state, and start no compile of their own that would outlive the test.
The compile itself is tested in tests/test_first_start.py.
"""
from __future__ import annotations

import fcntl
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from tdgen.robot.cores import COMPILING_LOCK


@contextmanager
def compiling_elsewhere(folder: Path) -> Iterator[dict[str, str]]:
    """The environment (`NUMBA_CACHE_DIR`) of processes that find `folder` empty and its compile under way."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / COMPILING_LOCK, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        yield {"NUMBA_CACHE_DIR": str(folder)}
