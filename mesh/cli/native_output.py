"""Keep native libraries' prints out of the command's output.

pybullet's C code prints (`pybullet build time`, `b3Warning`, link names) straight to file
descriptor 1, past Python, so they land in the middle of a CSV that `twinmesh ik --targets ... |`
writes. `separate_native_stdout` points descriptor 1 at /dev/null (at stderr with `-v`) and moves
Python's `sys.stdout` to a copy of the real descriptor 1: what twinmesh prints stays on stdout,
what C code prints does not. Child processes inherit the redirected descriptor, so the lab's
processes are quiet the same way. pybullet's import banner goes to stderr: `quiet_pybullet_import`
silences descriptor 2 while (and only while) the extension module loads.
"""
from __future__ import annotations

import io
import os
import sys

from mesh.process import quiet_pybullet_import  # noqa: F401 - the CLI's name for it


def separate_native_stdout(show: bool = False) -> None:
    """Send C-level stdout to /dev/null (stderr when `show`), keep Python's stdout where it was."""
    old = sys.stdout
    try:
        fd = old.fileno()
    except (AttributeError, OSError, ValueError):  # already replaced (a test runner's capture): leave it
        return
    if fd != 1:
        return
    old.flush()
    real = os.dup(1)
    target = os.dup(2) if show else os.open(os.devnull, os.O_WRONLY)
    os.dup2(target, 1)
    os.close(target)
    sys.stdout = io.TextIOWrapper(io.FileIO(real, "w"), encoding=old.encoding, errors=old.errors,
                                  line_buffering=bool(old.line_buffering),
                                  write_through=getattr(old, "write_through", False))

