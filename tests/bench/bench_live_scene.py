"""A TD that follows its lab: how long from `addObstacle` / `removeObstacle` to the UR10's new TD.

    python tests/bench/bench_live_scene.py [--samples 80000] [--rounds 10]

Starts `twinmesh up` (the iot-lab at its real speed, a fresh tdgen cache) twice in the same run: with
`--tdgen-from-scratch` (the baseline: every new scene generated again, as before live updates) and
with the default `--tdgen-live`. For each, `rounds` times: a box put on the UR10's table
(`addObstacle`) and taken away again (`removeObstacle`); each time the figure is the wall time
from sending the action to the HTTP adapter serving the UR10's TD of the new scene version (polled
every 2 ms, so a figure is up to ~3 ms late), and, before and right after the add, the collision
probability a Cartesian plan to the box's centre is answered with (from the workspace it was
checked against). Medians and maxima,
baseline beside live, with the ratio. The issue's goal: within 100 ms.

    python tests/bench/bench_live_scene.py --scan [--samples 80000] [--rounds 3]

tdgen's part of a live update in one process, no lab: the UR10 on its table in table-and-wall without the
wall, its samples generated, then round by round, each body replacing the one before: a box put on the
table; a new 300,000-point scan of the room (a `points` body, another random thinning of one rendered
depth image each time: a file never seen, read and voxelized in the update); a box again; the same scan
again; and another new scan whose cache entry is on disk (as in a lab, where the world Thing reads a scan
before it changes the scene). Wall and CPU ms of the re-check (`LiveSamples.rescene`) and of the whole
update (its warnings and files, `write_artefacts`), each row and the medians per kind side by side; then the
CPU ms of each step of a new scan measured alone: what no update can skip (hashing, reading, placing,
voxelizing the points) and what is built from them.
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs
sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/bench: bench_scan_scene
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: tests.scans

from labs import start_lab  # noqa: E402

from mesh.messages.relations import POINTS  # noqa: E402


def crate(k: int) -> dict:
    """Round k's box: on the UR10's table, each round 2 cm further along (a new scene each time, never a
    scene the tdgen cache holds; taking it away goes back to the first scene, which the cache holds)."""
    return {"name": "crate", "size": [0.3, 0.3, 0.3], "position": [2.3, -0.42 - 0.02 * k, 0.9]}


def ur10_version(http: httpx.Client) -> str:
    return http.get("/ur10").json().get("version", {}).get("instance", "")


def until_version(http: httpx.Client, version: int, started: float, limit: float = 120.0) -> float:
    while ur10_version(http) != str(version):
        if time.perf_counter() - started > limit:
            raise SystemExit(f"no UR10 TD of version {version} within {limit} s")
        time.sleep(0.002)
    return time.perf_counter() - started


def box_probability(http: httpx.Client, box: dict) -> float:
    """The collision probability a Cartesian plan to the box's centre is answered with (UR10 frame: base
    at (2.3, 0, 0.75), turned 180 deg): the share of colliding samples near it in the workspace the
    plan was checked against."""
    x, y, z = box["position"]
    target = {"x": (2.3 - x) * 1000, "y": -y * 1000, "z": (z - 0.75) * 1000}
    answer = http.post("/ur10/actions/planMove", json=target).json()
    answer = answer.get("extra", answer)  # refused (422) or planned
    return float(answer.get("collision_probability") or 0.0)


def run(samples: int, rounds: int, live: bool) -> dict[str, list[float]]:
    with tempfile.TemporaryDirectory() as tmp:
        lab = start_lab(Path(tmp), None, http=True, things={"ur10", "world", "tdgen"},
                        extra_args=("--samples", str(samples), "--tdgen-cache", f"{tmp}/cache",
                                    "--tdgen-live" if live else "--tdgen-from-scratch"))
        try:
            with httpx.Client(base_url=lab.http, timeout=120) as http:
                until_version(http, 0, time.perf_counter())
                while POINTS not in {link["rel"] for link in http.get("/ur10").json().get("links", [])}:
                    time.sleep(0.05)
                figures: dict[str, list[float]] = {"add": [], "remove": [], "before": [], "after": []}
                version = 0
                for k in range(rounds):
                    box = crate(k)
                    figures["before"].append(box_probability(http, box))
                    started = time.perf_counter()
                    r = http.post("/world/actions/addObstacle", json=box)
                    assert r.status_code in (200, 204), r.text
                    version += 1
                    figures["add"].append(until_version(http, version, started))
                    figures["after"].append(box_probability(http, box))
                    started = time.perf_counter()
                    r = http.post("/world/actions/removeObstacle", json={"name": box["name"]})
                    assert r.status_code == 200, r.text
                    version += 1
                    figures["remove"].append(until_version(http, version, started))
                return figures
        finally:
            lab.stop()


def scan_against_box(samples: int, rounds: int) -> None:
    """tdgen's live update in one process, round by round: a box put down, a new 300,000-point scan added
    (its file never seen before), a box again, the same scan added again, and another new scan whose cache
    entry is on disk (as in a lab, where the world Thing reads a scan before it changes the scene)."""
    import msgspec
    from bench_scan_scene import POINTS, VIEW  # tests/bench, beside this file

    from tdgen.generate import Naming, write_artefacts
    from tdgen.live import LiveSamples
    from tdgen.robot import points_csv, scan_bodies
    from tdgen.robot.model import Robot
    from tdgen.robot.surroundings import BoxBody, PointsBody, load_scene, prepare
    from tdgen.sampling import sample_workspace
    from tests.scans import render_scan, thinned, write_pcd

    with tempfile.TemporaryDirectory() as tmp:
        os.environ["TWINMESH_CACHE"] = f"{tmp}/cache"  # the scans' (the compiled code stays where it is: cores)
        full = load_scene("table-and-wall")
        base = msgspec.structs.replace(full, bodies=[b for b in full.bodies if b.name == "table"])
        room = msgspec.structs.replace(full, bodies=[b for b in full.bodies if b.name != "table"])
        rendered = render_scan(room, size=(960, 720), **VIEW)  # type: ignore[arg-type]
        robot = Robot.load("ur10.urdf")
        sampled = sample_workspace(robot, base, samples, 4)
        held = LiveSamples(robot, base, sampled, points_csv.encode(robot, sampled.positions, sampled.collision,
                                                                   sampled.q))
        held.prepare()
        print(f"UR10 in table-and-wall without its wall, {samples} samples ({int((~sampled.collision).sum())} free); "
              f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
        print(f"{'added':34} {'re-check, wall (CPU)':>22} {'whole update, wall (CPU)':>26}")
        figures: dict[str, list[tuple[float, float, float, float]]] = {"box": [], "first": [], "lab": [], "again": []}

        def update(label: str, kind: str, body) -> None:
            wall, cpu = time.perf_counter(), time.process_time()
            live, _ = held.rescene(msgspec.structs.replace(base, bodies=[*base.bodies, body]))
            check = (time.perf_counter() - wall, time.process_time() - cpu)
            write_artefacts(robot, live.scene, live.samples, Path(tmp), Naming("ur10"), 4, points=live.flags,
                            warnings=live.warnings(), write=lambda path, content: None)
            whole = (time.perf_counter() - wall, time.process_time() - cpu)
            figures[kind].append((*check, *whole))
            print(f"{label:34} {check[0] * 1000:>12.0f} ({check[1] * 1000:.0f}) ms "
                  f"{whole[0] * 1000:>16.0f} ({whole[1] * 1000:.0f}) ms")

        for k in range(rounds):
            scan = write_pcd(thinned(rendered, POINTS, seed=k), Path(tmp) / f"room-{k}.pcd")  # a new cloud each round
            body = PointsBody(name="scan", file=str(scan), position=rendered.position, rpy=rendered.rpy)
            update(f"box, round {k}", "box", BoxBody(name="crate", size=(0.3, 0.3, 0.3),
                                                     position=(0.5, -0.3 - 0.02 * k, 0.8)))
            update(f"new 300,000-point scan, round {k}", "first", body)
            update(f"box, round {k}b", "box", BoxBody(name="crate", size=(0.3, 0.3, 0.3),
                                                      position=(0.5, -0.31 - 0.02 * k, 0.8)))
            update(f"the same scan again, round {k}", "again", body)
            made = write_pcd(thinned(rendered, POINTS, seed=100 + k), Path(tmp) / f"room-lab-{k}.pcd")
            other = PointsBody(name="scan", file=str(made), position=rendered.position, rpy=rendered.rpy)
            prepare(other)  # as in a lab: the world Thing reads a scan before it changes the scene, and its
            scan_bodies._MEMORY.pop(prepare(other).key)  # cache entry is on disk, not in this process's memory
            update(f"new scan, its cache entry made, round {k}", "lab", other)
        held.close()
        print(f"\nmedians, ms: wall (CPU)       {'re-check':>18} {'whole update':>18}")
        for kind, label in (("box", "a box"), ("first", "a new scan"), ("lab", "a new scan, cache entry made"),
                            ("again", "the same scan again")):
            rows = figures[kind]
            med = [statistics.median(r[i] for r in rows) * 1000 for i in range(4)]
            print(f"{label:30} {med[0]:>10.0f} ({med[1]:.0f}) {med[2]:>12.0f} ({med[3]:.0f})")
        scan_floor(Path(tmp) / "room-floor.pcd", thinned(rendered, POINTS, seed=rounds), rendered, robot, base,
                   sampled.q[~sampled.collision])


def scan_floor(path: Path, cloud, rendered, robot, base, q, repeats: int = 3) -> None:
    """CPU ms of each step a new scan's first update takes, measured alone on a cloud never seen (each step
    `repeats` times, what it keeps forgotten in between; the median): what no update can skip (its file
    hashed, read, placed and put into voxels) and what it builds from them."""
    import msgspec

    from tdgen.robot import scan_bodies, scan_io
    from tdgen.robot.collision import CollisionWorld
    from tdgen.robot.fast_collision import FastCollision, ScanClearance
    from tdgen.robot.surroundings import PointsBody, prepare
    from tests.scans import write_pcd

    write_pcd(cloud, path)
    steps: list[tuple[str, float]] = []

    def step(label: str, do, forget=lambda: None):
        times = []
        for _ in range(repeats):
            forget()
            cpu = time.process_time()
            out = do()
            times.append(time.process_time() - cpu)
        steps.append((label, statistics.median(times) * 1000))
        return out

    def unprepared() -> None:  # neither in memory nor on disk
        scan_io._DIGESTS.clear()
        scan_bodies._MEMORY.clear()
        shutil.rmtree(scan_bodies.cache_dir(), ignore_errors=True)

    step("its file hashed (sha256)", lambda: scan_io.content_digest(path), scan_io._DIGESTS.clear)
    points = step("read (binary_compressed PCD)", lambda: scan_io.read_cloud(path))
    placed = step("placed by the sensor's pose",
                  lambda: scan_bodies.placed(points, rendered.position, rendered.rpy))
    cells = np.floor(placed / scan_bodies.DEFAULT_VOXEL).astype(np.int64)
    step("its occupied voxels (sorted, unique)", lambda: np.unique(scan_bodies._packed(cells - cells.min(axis=0))))
    step("voxels merged into padded boxes and faces", lambda: scan_bodies._voxels(placed, scan_bodies.DEFAULT_VOXEL))
    body = PointsBody(name="scan", file=str(path), position=rendered.position, rpy=rendered.rpy)
    prepared = step("all of these at once, its cache entry written", lambda: prepare(body), unprepared)
    world = CollisionWorld(robot, msgspec.structs.replace(base, bodies=[]), part=True)
    try:
        empty = FastCollision(world)  # the robot's part, made once per robot (before any update)
        step("built into a pybullet world (lists, shapes)", lambda: world.set_bodies([body]),
             lambda: world.set_bodies([]))
        within = step("where the robot reaches (2,000 poses)", lambda: ScanClearance.reach(world, empty.spheres))
        step("distance field there", lambda: scan_bodies.clearance(prepared, within), prepared.fields.clear)
        fast = step("fast model of it (tables)", lambda: FastCollision(world))
        step(f"{len(q)} base-free samples checked", lambda: fast.colliding(q))
    finally:
        world.close()
    print(f"\na new scan's steps alone, CPU ms (median of {repeats}; the first four are the floor: no update skips "
          "them):")
    for label, ms in steps:
        print(f"  {label:46} {ms:>6.0f}")
    floor = sum(ms for _, ms in steps[:4])
    print(f"  {'the floor':46} {floor:>6.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=80_000)
    parser.add_argument("--rounds", type=int, default=None)
    parser.add_argument("--scan", action="store_true", help="tdgen's live update in one process: a box, then a scan")
    args = parser.parse_args()
    if args.scan:
        scan_against_box(args.samples, args.rounds or 3)
        return
    args.rounds = args.rounds or 10
    print(f"iot-lab, UR10 with {args.samples} samples, {args.rounds} rounds; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    scratch = run(args.samples, args.rounds, live=False)
    live = run(args.samples, args.rounds, live=True)
    print(f"\n{'action -> new TD served':26} {'from scratch':>22} {'live':>22} {'ratio':>7}")
    for what in ("add", "remove"):
        a, b = scratch[what], live[what]
        print(f"{what + 'Obstacle':26} {_fig(a):>22} {_fig(b):>22} {statistics.median(a) / statistics.median(b):>6.1f}x")
    for what, label in (("before", "box centre, before"), ("after", "box centre, right after")):
        print(f"{label:26} {_p(scratch[what]):>22} {_p(live[what]):>22}")
    print(f"live addObstacle, round by round (ms): {', '.join(f'{v * 1000:.0f}' for v in live['add'])}")
    print("\n(median / max in ms; the goal: the new TD within 100 ms. Box centre: the collision probability a\n"
          "plan to it is answered with, median; right after the add it comes from the new workspace)")


def _fig(values: list[float]) -> str:
    return f"{statistics.median(values) * 1000:.0f} / {max(values) * 1000:.0f} ms"


def _p(values: list[float]) -> str:
    return f"p = {statistics.median(values):.2f}"


if __name__ == "__main__":
    main()
