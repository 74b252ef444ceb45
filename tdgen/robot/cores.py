"""Compiled code: one launch of parallel code at a time in a process, and where the compiled code is kept.

numba's threading layers are not all safe for two threads launching parallel code at once (the
workqueue layer aborts the process; omp is taken where GNU OpenMP is installed). Every `prange` loop
here (the sphere model's verdicts, points.csv's formatting) runs under `LAUNCH`.

numba keeps what it compiled beside the sources unless told otherwise: inside site-packages, which
may be read-only and is not the user's. Our compiled code is kept in the user's cache directory
instead (`user_cache`, beside tdgen's artefacts), in a folder named after what our compiled modules
hold (`numba_locator`), so a machine compiles each version of our code once, whatever installed it.
numba reads where when it is imported and each compiled function when it is defined, so every module
of ours takes `njit` and `prange` from here: the one place that says where, before numba is imported.
"""
from __future__ import annotations

import functools
import os
import sys
import threading
from pathlib import Path
from types import ModuleType

import platformdirs

LAUNCH = threading.Lock()
_started = threading.Event()  # a background compile was started by this process


def user_cache() -> Path:
    """`$TWINMESH_CACHE`, else twinmesh's folder in the user's cache directory (`$XDG_CACHE_HOME/twinmesh`,
    by default `~/.cache/twinmesh`, on Linux; the platform's own elsewhere)."""
    root = os.environ.get("TWINMESH_CACHE")
    return Path(root).expanduser() if root else platformdirs.user_cache_path("twinmesh")


def compiled_code_dir() -> Path:
    """Where numba keeps the compiled code: `$NUMBA_CACHE_DIR` if the user set it, else `user_cache()/numba`."""
    return Path(os.environ.get("NUMBA_CACHE_DIR") or user_cache() / "numba")


# numba's own locators after ours, in numba's order: ours places only our compiled modules
LOCATORS = ("tdgen.robot.numba_locator.ByContentLocator,UserProvidedCacheLocator,InTreeCacheLocator,"
            "UserWideCacheLocator,IPythonCacheLocator,ZipCacheLocator")


def _keep_compiled_code() -> None:
    """numba's cache in `compiled_code_dir()`, our modules' by their contents (unless the user chose numba's
    locators), for this process and those it starts."""
    os.environ["NUMBA_CACHE_DIR"] = str(compiled_code_dir())
    os.environ.setdefault("NUMBA_CACHE_LOCATOR_CLASSES", LOCATORS)
    if "numba" in sys.modules:  # imported before us (by a user's script): none of our functions defined yet
        from numba.core import config

        config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]  # type: ignore[attr-defined]
        config.CACHE_LOCATOR_CLASSES = os.environ["NUMBA_CACHE_LOCATOR_CLASSES"]  # type: ignore[attr-defined]


_keep_compiled_code()


def __getattr__(name: str):
    """`njit` and `prange`, numba's, imported on first use (after the cache's place is set): numba and what it
    loads weigh about 70 MB, and `twinmesh up` on every host imports this module for `compiled()` alone."""
    if name in ("njit", "prange"):
        import numba

        return getattr(numba, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["LAUNCH", "compiled_code_dir", "first_compile_notice", "user_cache"]  # and njit, prange (above)


COMPILED_MODULES = ("sphere_kernel.py", "points_csv.py", "kinematics.py")  # ours that numba compiles


def compiled_stamp() -> Path:
    """The file `fast_collision.compile_all` writes once it has compiled everything, named after what the
    compiled code is valid for (`sources_hash`). The same code installed elsewhere (a second venv, a fresh
    clone) finds it compiled; a new version, or another machine sharing the home directory, compiles afresh."""
    return compiled_code_dir() / f"twinmesh-compiled-{sources_hash()}"


@functools.cache
def sources_hash() -> str:
    """What our compiled modules hold, with numba's version, Python's and the machine's: the name of the folder
    numba keeps their compiled code in (`numba_locator`) and of the stamp that says it is complete. Where the
    user chose numba's own locators, which keep compiled code by its folder, the folder counts too."""
    import hashlib
    import platform
    from importlib.metadata import version

    h = hashlib.sha256(f"{version('numba')} {sys.version} {platform.machine()}".encode())
    if os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES") != LOCATORS:  # the user's choice: numba's own, by path
        h.update(os.path.abspath(Path(__file__).parent).encode())
    for name in COMPILED_MODULES:
        h.update((Path(__file__).parent / name).read_bytes())
    return h.hexdigest()[:16]


def is_compiled_module(py_file: str) -> bool:
    """Is `py_file` one of our compiled modules (`COMPILED_MODULES`, beside this file)?"""
    path = Path(os.path.abspath(py_file))
    return path.parent == Path(os.path.abspath(__file__)).parent and path.name in COMPILED_MODULES


def compiled() -> bool:
    """Is our compiled code on disk (a first call loads it in a fraction of a second instead of compiling it),
    or is this the process compiling it (`compiling_here`)?"""
    return _compiling_here.is_set() or compiled_stamp().exists()


_compiling_here = threading.Event()


def compiling_here() -> None:
    """This process compiles everything (`fast_collision.compile_all`): its code uses the compiled functions
    (compiling them) instead of their uncompiled stand-ins, and starts no compile elsewhere."""
    _compiling_here.set()
    _started.set()


def first_compile_notice() -> str:
    """What a first start says of the compile (`compiled()` false): that it happens once, what it costs,
    that nothing waits for it, and where it is kept."""
    return ("first start on this machine: the collision model compiles once, in the background (about a minute "
            "of one core); the lab does not wait for it: until then, robots and tdgen check collisions with "
            f"pybullet's exact test (the same answers, slower); kept in {compiled_code_dir()}")




COMPILING_LOCK = "twinmesh-compiling.lock"  # in compiled_code_dir(), held by the process compiling
LOCK_FD = "TWINMESH_COMPILING_LOCK_FD"  # the lock's descriptor handed to the background compile
BACKGROUND_NICE = 10  # the background compile's niceness: a lab starting beside it comes first


_compiler: list[ModuleType] = []  # the module whose main compiles every kernel: fast_collision, once imported


def compiles_everything(module: ModuleType) -> None:
    """`module`'s main compiles every kernel (`fast_collision.compile_all`): it says so when it is imported, so
    that the modules below it (kinematics) start the background compile without importing it."""
    if not _compiler:
        _compiler.append(module)


def compile_in_background(module: ModuleType | None = None, nice: int = BACKGROUND_NICE) -> None:
    """Compile everything (`module`'s main, by default the registered one: `fast_collision.compile_all`;
    nothing if no module of this process registered) in a process of its own, at low priority (`nice`
    added to this process's niceness), at most once per process; it goes on if this process ends (a `twinmesh tdgen` that was
    done first). Nothing starts if another process is at it: the lock is taken here and handed to the
    compiling process, so two processes of a lab starting at once cannot both start one."""
    import fcntl
    import subprocess

    module = module or (_compiler[0] if _compiler else None)
    if module is None or _started.is_set():  # no collision model loaded here: a process that has one starts it
        return
    _started.set()
    folder = compiled_code_dir()
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / COMPILING_LOCK, "w") as lock:  # closed here: the lock stays with the child's copy
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return
        main = (f"import os, runpy; os.nice({nice}); "
                f"runpy.run_module({module.__name__!r}, run_name='__main__', alter_sys=True)")
        # -P: the working directory does not go first on sys.path, so the compile is of the modules this process
        # runs (a lab started inside a checkout of twinmesh compiled the checkout's, not the installed ones)
        subprocess.Popen([sys.executable, "-P", "-c", main], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True, pass_fds=(lock.fileno(),),
                         env={**os.environ, LOCK_FD: str(lock.fileno())})
