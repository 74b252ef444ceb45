"""The first start on a fresh machine: `twinmesh up` to `twinmesh wait` success, cold then warm.

    python tests/bench/bench_first_start.py [--baseline COMMIT] [--venv-root DIR] [--scene iot-lab] [--reuse-venv VENV]

For this checkout (and, with --baseline, a `git worktree` of that commit beside it): a fresh venv with the
checkout pip-installed under .ci/constraints.txt (pip's wheel cache is used: the install is not what is
timed), empty cache and data directories (XDG_CACHE_HOME, XDG_DATA_HOME, TWINMESH_CACHE, HOME: no compiled
code, no TDs), then `twinmesh up` on free ports, timed until `twinmesh wait` succeeds: cold; then, once
the one-time compile that the cold start began in the background is done (its time from `up` is printed),
stopped and started again on the same caches: warm. Prints each figure and the load average (the machine
is shared: compare figures of one run only). --reuse-venv VENV: no install; each checkout runs from VENV with
PYTHONPATH set to it, numba's files beside its sources removed first (the code before kept them there).
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))  # waiting

from waiting import eventually  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _venv(checkout: Path, where: Path) -> Path:
    """A fresh venv with `checkout` installed (not editable: as a user installs it); its bin folder."""
    subprocess.run([sys.executable, "-m", "venv", str(where)], check=True)
    pip = [str(where / "bin" / "python"), "-m", "pip", "install", "-q"]
    t = time.perf_counter()
    subprocess.run([*pip, "--constraint", str(ROOT / ".ci" / "constraints.txt"), str(checkout)], check=True)
    print(f"  installed {checkout.name} in {time.perf_counter() - t:.0f} s (pip's wheel cache used)", flush=True)
    return where / "bin"


def _start(bin_dir: Path, env: dict[str, str], scene: str, log: Path) -> float:
    """Seconds from `twinmesh up` to `twinmesh wait` success; the lab stopped afterwards."""
    zenoh = f"tcp/127.0.0.1:{_free_port()}"
    up = [str(bin_dir / "twinmesh"), "up", scene, "--zenoh", zenoh, "--http", f"127.0.0.1:{_free_port()}",
          "--view", f"127.0.0.1:{_free_port()}"]
    with open(log, "ab") as out:
        t = time.perf_counter()
        lab = subprocess.Popen(up, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            waited = subprocess.run([str(bin_dir / "twinmesh"), "--connect", zenoh, "wait", "--timeout", "600"],
                                    env=env, stdout=out, stderr=subprocess.STDOUT)
            seconds = time.perf_counter() - t if waited.returncode == 0 else float("inf")  # not ready in 600 s: see log
        finally:
            os.killpg(lab.pid, signal.SIGINT)
            try:
                lab.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(lab.pid, signal.SIGKILL)
                lab.wait()
    return seconds


def _compile_done(numba_dir: Path) -> float:
    """When the compile that the cold start began in the background (`fast_collision.compile_all`) was done:
    its stamp (`cores.compiled_stamp`) on disk; perf_counter time. nan if none ran (code without one)."""
    if not (numba_dir / "twinmesh-compiling.lock").exists():
        return float("nan")
    try:
        eventually(lambda: any(numba_dir.glob("twinmesh-compiled-*")), timeout=900, interval=0.5, longest=1.0,
                   what="the background compile's stamp")
    except AssertionError as e:
        print(f"  {e}", flush=True)
        return float("nan")
    return time.perf_counter()


def measure(label: str, checkout: Path, root: Path, scene: str, reuse: Path | None) -> tuple[float, float, float]:
    print(f"{label}: {checkout}", flush=True)
    if reuse is None:
        bin_dir = _venv(checkout, root / "venv")
    else:
        bin_dir = reuse / "bin"
        for old in [*checkout.glob("tdgen/**/__pycache__/*.nbi"), *checkout.glob("tdgen/**/__pycache__/*.nbc")]:
            old.unlink()
    home = root / "home"
    home.mkdir()
    env = {**{k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "TWINMESH_", "XDG_", "VIRTUAL_ENV"))},
           "HOME": str(home), "XDG_CACHE_HOME": str(root / "xdg-cache"), "XDG_DATA_HOME": str(root / "xdg-data"),
           "TWINMESH_CACHE": str(root / "xdg-cache" / "twinmesh"), "PATH": f"{bin_dir}:{os.environ['PATH']}"}
    if reuse is not None:
        env["PYTHONPATH"] = str(checkout)
    began = time.perf_counter()
    cold = _start(bin_dir, env, scene, root / "lab.log")
    print(f"  cold {cold:6.1f} s (load average {os.getloadavg()[0]:.1f})", flush=True)
    compiled = _compile_done(root / "xdg-cache" / "twinmesh" / "numba") - began
    print(f"  compiled in the background {compiled:6.1f} s after `up` (load average {os.getloadavg()[0]:.1f})", flush=True)
    warm = _start(bin_dir, env, scene, root / "lab.log")
    print(f"  warm {warm:6.1f} s (load average {os.getloadavg()[0]:.1f}; log {root / 'lab.log'})", flush=True)
    return cold, compiled, warm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", metavar="COMMIT", help="also the code of COMMIT (a git worktree), measured first")
    parser.add_argument("--venv-root", type=Path, help="where the venvs and caches go [default: a temporary folder]")
    parser.add_argument("--scene", default="iot-lab")
    parser.add_argument("--reuse-venv", type=Path, metavar="VENV", help="run each checkout from this venv, no install")
    args = parser.parse_args()
    root = Path(args.venv_root or tempfile.mkdtemp(prefix="first-start-"))
    root.mkdir(parents=True, exist_ok=True)
    try:
        run(args, root)
    finally:
        if not args.venv_root:  # a temporary folder of about 1.5 GB per checkout: a --venv-root is kept
            shutil.rmtree(root, ignore_errors=True)


def run(args: argparse.Namespace, root: Path) -> None:
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; scene {args.scene}; in {root}", flush=True)
    results = {}
    if args.baseline:
        tree = root / "baseline-tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--quiet", "--detach", str(tree), args.baseline],
                       check=True)
        try:
            (root / "baseline").mkdir()
            results[f"baseline {args.baseline}"] = measure(f"baseline {args.baseline}", tree, root / "baseline",
                                                          args.scene, args.reuse_venv)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)
    (root / "this").mkdir()
    results["this checkout"] = measure("this checkout", ROOT, root / "this", args.scene, args.reuse_venv)
    print("\nfirst start, `twinmesh up` to `twinmesh wait` (s):")
    for label, (cold, compiled, warm) in results.items():
        print(f"  {label:24} cold {cold:6.1f}   compiled {compiled:6.1f}   warm {warm:6.1f}")


if __name__ == "__main__":
    main()
