"""A headless Chromium for the browser tests, driven by Playwright (`from browser import chromium`).

Playwright's own browser download needs the internet; the system's Chromium (Debian's `chromium`
package) does not. It is installed on first use with apt-get when it is missing and this process
may (root, apt-get present), like node-wot's npm install; where it cannot be, the test is skipped
with the reason. Chromium starts with the flags this machine's closed network needs (no background
networking, no component updates).
"""
from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

ARGS = ["--no-sandbox", "--disable-quic", "--no-first-run", "--disable-background-networking",
        "--disable-component-update", "--disable-sync",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]  # WebGL for the 3D view
INSTALL_TIMEOUT = 900


def chromium_path() -> str:
    """The system Chromium, installed now if it is missing and can be; skips the test otherwise."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found:
        return found
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        pytest.skip("no Chromium on this machine, and no way to install it here (needs root and apt-get): "
                    "install the `chromium` package to run the browser tests")
    with open(Path(tempfile.gettempdir()) / "twinmesh-chromium.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # parallel sessions install once
        if not shutil.which("chromium"):
            env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
            done = subprocess.run(["apt-get", "install", "-y", "-q", "--no-install-recommends", "chromium"],
                                  capture_output=True, text=True, timeout=INSTALL_TIMEOUT, env=env)
            if done.returncode != 0:
                pytest.skip(f"could not install Chromium with apt-get (exit {done.returncode}): "
                            f"{(done.stderr or done.stdout)[-500:]}")
    found = shutil.which("chromium")
    if not found:
        pytest.skip("apt-get installed no `chromium` command")
    return found


@contextmanager
def chromium() -> Iterator[object]:
    """A headless Chromium browser (Playwright's `Browser`), closed afterwards."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="the browser tests need the `playwright` package "
                                   "(pip install -e '.[test]')")
    path = chromium_path()
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=path, args=ARGS)
        try:
            yield browser
        finally:
            browser.close()
