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

import importlib.abc
import importlib.machinery
import io
import os
import sys
from contextlib import contextmanager
from typing import Any, Iterator


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


@contextmanager
def _descriptor_silenced(fd: int) -> Iterator[None]:
    saved = os.dup(fd)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)


class _SilentLoader(importlib.abc.Loader):
    def __init__(self, loader: Any):
        self.loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> Any:
        with _descriptor_silenced(2):
            return self.loader.create_module(spec)

    def exec_module(self, module: Any) -> None:
        with _descriptor_silenced(2):
            self.loader.exec_module(module)


class _QuietImports(importlib.abc.MetaPathFinder):
    NAMES = frozenset({"pybullet"})

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if name not in self.NAMES:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                if spec.loader is not None:
                    spec.loader = _SilentLoader(spec.loader)
                return spec
        return None


def quiet_pybullet_import() -> None:
    """pybullet prints its build time to stderr when it loads: not when twinmesh loads it."""
    if "pybullet" not in sys.modules and not any(isinstance(f, _QuietImports) for f in sys.meta_path):
        sys.meta_path.insert(0, _QuietImports())
