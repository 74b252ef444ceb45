"""Where numba keeps our compiled code: named after what our compiled modules hold, not where they sit.

numba names a module's cache folder after the folder's path, so the same code installed again (a second venv,
a fresh clone, a wheel) compiled everything again: a minute and more of a core, in every new place. Named
after the modules' contents (`cores.sources_hash`), a machine compiles each version of our code once, wherever
it is installed, and code that differs by a byte compiles its own. numba imports this class by its dotted
name (`NUMBA_CACHE_LOCATOR_CLASSES`, which `cores` sets before numba is imported); every other package's
compiled functions are kept where numba keeps them.
"""
from __future__ import annotations

import functools
import hashlib
import os

from numba.core.caching import UserProvidedCacheLocator

from tdgen.robot import cores


class ByContentLocator(UserProvidedCacheLocator):
    """numba's `NUMBA_CACHE_DIR` locator, with our compiled modules in one folder per version of their code."""

    def __init__(self, py_func, py_file: str):
        super().__init__(py_func, py_file)
        self.source_file = py_file

    @classmethod
    def get_suitable_cache_subpath(cls, py_file: str) -> str:
        if cores.is_compiled_module(py_file):
            return f"twinmesh-{cores.sources_hash()}"
        return super().get_suitable_cache_subpath(py_file)

    def get_source_stamp(self) -> bytes:
        """The source's contents, not its modification time: a fresh clone's files are new, their code is not."""
        st = os.stat(self.source_file)
        return _file_hash(self.source_file, st.st_mtime, st.st_size)


@functools.cache
def _file_hash(path: str, mtime: float, size: int) -> bytes:  # mtime and size: a file edited meanwhile is read again
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).digest()
