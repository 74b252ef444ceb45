"""Repair a recording cut short (a recorder killed with SIGKILL writes no footer, so `rerun rrd verify`
fails): Rerun's own `rrd optimize` reads what was written and writes a complete file."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path


class RepairError(Exception):
    """The recording cannot be repaired; the message says why."""


def rerun_cli() -> str:
    """The `rerun` command of the rerun-sdk beside this interpreter (or on the PATH)."""
    beside = Path(sys.executable).with_name("rerun")
    found = str(beside) if beside.exists() else shutil.which("rerun")
    if not found:
        raise RepairError("the `rerun` command of rerun-sdk is not installed")
    return found


def repair_recording(path: str | Path) -> str:
    """Rewrite `path` as a valid recording (the original moves to `<path>.broken`); returns a summary."""
    path = Path(path)
    if not path.is_file():
        raise RepairError(f"{path}: no such recording")
    rerun = rerun_cli()
    fixed = path.with_name(path.name + ".repairing")
    env = {**os.environ, "CI": "1"}  # Rerun's analytics off (mesh.recorder.replay.NO_USAGE_DATA)
    done = subprocess.run([rerun, "rrd", "optimize", str(path), "-o", str(fixed)], capture_output=True, text=True,
                          env=env)
    if done.returncode != 0 or not fixed.exists():
        fixed.unlink(missing_ok=True)
        raise RepairError(f"{path}: rerun could not read it ({(done.stderr or done.stdout).strip()[-300:]})")
    verified = subprocess.run([rerun, "rrd", "verify", str(fixed)], capture_output=True, text=True, env=env)
    if verified.returncode != 0:
        fixed.unlink(missing_ok=True)
        raise RepairError(f"{path}: the repaired file does not verify ({verified.stderr.strip()[-300:]})")
    broken = path.with_name(path.name + ".broken")
    path.replace(broken)
    fixed.replace(path)
    return f"repaired {path} ({path.stat().st_size} bytes; the original is {broken})"
