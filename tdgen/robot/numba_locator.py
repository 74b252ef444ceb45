"""Where numba keeps our compiled code: named after what our compiled modules hold, not where they sit.

numba names a module's cache folder after the folder's path, so the same code installed again (a second venv,
a fresh clone, a wheel) compiled everything again: a minute and more of a core, in every new place. Named
after the modules' contents (`cores.sources_hash`), a machine compiles each version of our code once, wherever
it is installed, and code that differs by a byte compiles its own. numba imports this class by its dotted
name (`NUMBA_CACHE_LOCATOR_CLASSES`, which `cores` sets before numba is imported); every other package's
compiled functions are kept where numba keeps them. numba (0.68 on) stamps each source by its contents, not its
modification time, so a fresh clone's new files find the code compiled for the same bytes.
"""
from __future__ import annotations

from numba.core.caching import UserProvidedCacheLocator

from tdgen.robot import cores


class ByContentLocator(UserProvidedCacheLocator):
    """numba's `NUMBA_CACHE_DIR` locator, with our compiled modules in one folder per version of their code."""

    @classmethod
    def get_suitable_cache_subpath(cls, py_file: str) -> str:
        if cores.is_compiled_module(py_file):
            return f"twinmesh-{cores.sources_hash()}"
        return super().get_suitable_cache_subpath(py_file)
