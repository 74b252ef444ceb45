"""A 300,000-point scan in a scene: what it adds to a whole `twinmesh tdgen`, side by side in one run.

    python tests/bench/bench_scan_scene.py [--samples 20000] [--size 640x480]
    python tests/bench/bench_scan_scene.py --figures [--samples 1000]

A depth camera renders the floor and the wall of table-and-wall (the robot's table is known, not
scanned), with noise and holes; the organized cloud is written as a binary_compressed PCD. Then the
whole command (a fresh process: imports, scene, model, sampling, files) for the UR10 with 20,000
samples: in the scene without the scan, with it the first time (the scan read and voxelized into an
empty cache), and with it again (from the cache). The issue asks <= 1 s added.

With --figures, the safety figures per scene instead (the docs' table): a UR10 on its known table in
table-and-wall and in cluttered-lab, everything else known only from a 160x120 scan; of N random
configurations, those whose robot geometry comes within 5 mm of a scanned point (none may be called
free) and those 5 cm from every point and otherwise free (>= 99 % must be), through the exact test,
the fast model and the twin's target check (`MovePlanner.collides`).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgspec

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: tests.scans

from tdgen.robot.surroundings import load_scene  # noqa: E402
from tests.scans import render_scan, write_pcd  # noqa: E402


def _command(args: list[str], env: dict[str, str]) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "devices", "tdgen", *args, "--no-progress"], check=True, env=env,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


VIEWS = {"table-and-wall": ((1.6, -1.4, 1.7), (0.0, 0.3, 0.6)), "cluttered-lab": ((-1.2, -1.3, 2.0), (0.6, 0.4, 0.8))}


def figures(n: int) -> None:
    import numpy as np

    from devices.planning.moves import MovePlanner, TdFrame
    from tdgen.robot.collision import CollisionWorld
    from tdgen.robot.fast_collision import FastCollision
    from tdgen.robot.model import Robot
    from tests.scans import Truth

    robot = Robot.load("ur10.urdf")
    print(f"UR10, {n} random configurations per scene; near: within 5 mm of a scanned point (called free: must be 0); "
          "far: >= 5 cm from every point and otherwise free (called free: >= 99 %)")
    for name, (eye, target) in VIEWS.items():
        base = load_scene(name)
        table = [b for b in base.bodies if b.name == "table"]
        room = msgspec.structs.replace(base, bodies=[b for b in base.bodies if b.name != "table"])
        with tempfile.TemporaryDirectory() as tmp:
            scan = render_scan(room, eye=eye, target=target, size=(160, 120), fov=80.0)
            write_pcd(scan, Path(tmp) / "scan.pcd")
            body = {"type": "points", "name": "scan", "file": "scan.pcd", "position": list(scan.position),
                    "rpy": list(scan.rpy)}
            (Path(tmp) / "scene.json").write_text(json.dumps({"name": f"{name}-scanned",
                "robot": msgspec.to_builtins(base.robot), "bodies": [*map(msgspec.to_builtins, table), body]}))
            scene = load_scene(Path(tmp) / "scene.json")
            truth = Truth(robot, scene, scan.world(), msgspec.structs.replace(scene, bodies=scene.bodies[:1]))
            qs = np.random.default_rng(1).uniform(robot.lows(), robot.highs(), (n, len(robot.lows())))
            world = CollisionWorld(robot, scene)
            planner = MovePlanner(robot, "ur10", scene, TdFrame(), peak_speed=1.5)
            called = {"exact test": world.colliding(qs), "fast model": FastCollision(world).colliding(qs),
                      "twin's target check": np.array([planner.collides(q) for q in qs])}
            for label, hit in called.items():
                f = truth.figures(qs, hit)
                print(f"  {name} ({len(scan.finite()):,} points), {label}: near {f.near}, called free "
                      f"{f.near_free}; far {f.far}, called free {f.far_free} ({100 * f.far_share:.1f} %)")
            planner.close()
            world.close()
            truth.close()


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--samples", type=int, default=None)
    parser.add_argument("--size", default="640x480", help="the depth image, pixels (640x480: ~300,000 points)")
    parser.add_argument("--figures", action="store_true", help="the safety figures per scene instead")
    args = parser.parse_args()
    if args.figures:
        figures(args.samples or 1000)
        return
    args.samples = args.samples or 20000
    width, height = (int(v) for v in args.size.split("x"))
    base = load_scene("table-and-wall")
    table = [b for b in base.bodies if b.name == "table"]
    room = msgspec.structs.replace(base, bodies=[b for b in base.bodies if b.name != "table"])
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        t = time.perf_counter()
        scan = render_scan(room, eye=(1.6, -1.4, 1.7), target=(0.0, 0.3, 0.6), size=(width, height), fov=90.0,
                           holes=0.01, far=4.0)
        write_pcd(scan, folder / "room.pcd")
        print(f"scan: {len(scan.finite()):,} points ({width}x{height}), rendered in {time.perf_counter() - t:.1f} s")
        head = {"name": "scanned", "robot": {"position": list(base.robot.position)}}
        bodies = [msgspec.to_builtins(b) for b in table]
        (folder / "without.json").write_text(json.dumps({**head, "bodies": bodies}))
        scan_body = {"type": "points", "name": "scan", "file": "room.pcd", "position": list(scan.position),
                     "rpy": list(scan.rpy)}
        (folder / "with.json").write_text(json.dumps({**head, "bodies": [*bodies, scan_body]}))
        env = {**os.environ, "TWINMESH_CACHE": str(folder / "cache")}
        common = ["ur10.urdf", "--samples", str(args.samples), "--seed", "1"]
        runs: dict[str, list[float]] = {"without the scan": [], "with the scan, first": [], "with the scan, cached": []}
        for k in range(2):
            runs["without the scan"].append(_command([*common, "--scene", str(folder / "without.json"),
                                                      "--out", str(folder / f"a{k}")], env))
            label = "with the scan, first" if k == 0 else "with the scan, cached"
            runs[label].append(_command([*common, "--scene", str(folder / "with.json"), "--out", str(folder / f"b{k}")],
                                        env))
        runs["with the scan, cached"].append(_command([*common, "--scene", str(folder / "with.json"),
                                                       "--out", str(folder / "b2")], env))
        print(f"whole `twinmesh tdgen ur10.urdf --samples {args.samples}` (s; best of the runs; the issue asks <= 1 s "
              "added):")
        best = {label: min(times) for label, times in runs.items()}
        for label, seconds in best.items():
            print(f"  {label:24s} {seconds:6.2f}  ({', '.join(f'{s:.2f}' for s in runs[label])})")
        print(f"added by the scan: {best['with the scan, cached'] - best['without the scan']:+.2f} s cached, "
              f"{best['with the scan, first'] - best['without the scan']:+.2f} s the first time")


if __name__ == "__main__":
    main()
