"""What drawing a scene's scan or CAD mesh costs the recorder: reading a served file for the view.

    python tests/bench/bench_scene_assets.py [--points 300000] [--rounds 5]

A random cloud of N points written as PCD (binary, binary_compressed, ascii) and as PLY, and a mesh of
about 200,000 triangles as binary STL; for each, the file's size, the CPU seconds of reading its bytes
from disk as a Thing serves them (`SceneAsset.read`, the baseline) and of `read_asset` (what the
recorder's fetcher does before the drawer logs it: parse, drop NaN points, keep at most 100,000),
median of the rounds. CPU seconds, not wall time: the machine is shared.
"""
from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from devices.things.scene_files import SceneAssets  # noqa: E402
from mesh.recorder.scene_assets import read_asset  # noqa: E402


def _cpu(fn, rounds: int) -> float:
    times = []
    for _ in range(rounds):
        started = time.process_time()
        fn()
        times.append(time.process_time() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=300_000)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    import trimesh
    from pypcd4 import Encoding, PointCloud

    folder = Path(tempfile.mkdtemp(prefix="bench-scene-assets-"))
    xyz = np.random.default_rng(0).uniform(-2, 2, (args.points, 3)).astype(np.float32)
    files: list[tuple[str, Path]] = []
    for encoding in ("binary", "binary_compressed", "ascii"):
        path = folder / f"scan-{encoding}.pcd"
        PointCloud.from_xyz_points(xyz).save(path, encoding=Encoding(encoding))
        files.append(("points", path))
    trimesh.PointCloud(xyz).export(str(folder / "scan.ply"), encoding="binary")
    files.append(("points", folder / "scan.ply"))
    trimesh.creation.icosphere(subdivisions=7).export(str(folder / "sphere.stl"))  # 327,680 triangles
    files.append(("mesh", folder / "sphere.stl"))
    assets = SceneAssets()
    assets.add([{"type": kind, "file": str(path)} for kind, path in files])
    print(f"{'file':28} {'MB':>6} {'read (baseline)':>16} {'read_asset':>11}  drawn")
    try:
        _measure(files, assets, args.rounds)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _measure(files: list[tuple[str, Path]], assets: SceneAssets, rounds: int) -> None:
    served = {asset.path: asset for asset in assets.assets()}
    for kind, path in files:
        asset = served[path]
        data = asset.read()
        made = read_asset(kind, asset.name, data)
        drawn = f"{len(made.points):,} of {made.total:,} points" if kind == "points" else \
            f"{len(made.triangles):,} triangles"
        print(f"{path.name:28} {len(data) / 1e6:6.1f} {_cpu(asset.read, rounds) * 1e3:13.1f} ms "
              f"{_cpu(lambda: read_asset(kind, asset.name, data), rounds) * 1e3:8.0f} ms  {drawn}")


if __name__ == "__main__":
    main()
