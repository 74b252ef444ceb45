"""Robot Thing benchmark: time to a generated TD (cold and cached), and what a Cartesian move costs beyond the motion.

    python tests/bench/bench_robot.py [--robot ur10.urdf] [--samples 20000] [--moves 200] [--restarts 3]

On a `twinmesh up lights` lab (adapter, tdgen service with a fresh cache), `twinmesh robot ROBOT
--scene table-and-wall --speed max`:
- time to TD: from spawning the robot process to the adapter serving its provisional TD (joined),
  and its generated TD (workspace links): cold (nothing cached: the service samples), then after
  `--restarts` Ctrl-C + restart of the same robot (the service's cache answers);
- moveToCartesianPosition round trip at `--speed max` with tiny moves (1 mm back and forth between
  two checked targets), over Zenoh (MeshClient) and over HTTP (the adapter): the motion takes ~0 s
  of wall time there, so the round trip is the overhead (check, IK, configuration collision check,
  stepping, the mesh and the adapter). Beside it: the same check + IK + collision check timed
  in-process, and the motions' simulated duration (what speed 1 adds: joint-velocity-limited
  smoothstep, from the joints read before and after), and a few moves on a second robot at speed 1,
  whose wall time minus the simulated duration is the overhead in real time; and, for scale, moves
  between random safe targets (their simulated duration is what they take at speed 1).
Client, lab and robots share the machine's cores: figures are for comparison, not capacity.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs

from labs import start_lab, stop_process  # noqa: E402

from devices.sim.pybullet_world import PEAK_SPEED, World  # noqa: E402
from devices.sim.robot_twin import Base, RobotTwin, workspace_from_csv  # noqa: E402
from mesh.fabric.mesh_client import MeshClient  # noqa: E402
from mesh.fabric.session import open_session  # noqa: E402
from mesh.fabric.settings import MeshSettings  # noqa: E402
from tdgen.robot.model import Robot  # noqa: E402
from tdgen.robot.surroundings import build_into, load_scene  # noqa: E402


def poll_td(http: str, name: str, generated: bool, timeout: float = 600.0) -> float:
    """Monotonic time at which the adapter serves `name`'s TD (with workspace links if `generated`)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            r = httpx.get(f"{http}/{name}", timeout=5)
            if r.status_code == 200 and (not generated or any(
                    link.get("rel") == "workspace" for link in r.json().get("links", []))):
                return time.monotonic()
        except httpx.HTTPError:
            pass
        time.sleep(0.01)
    raise SystemExit(f"{name}: no {'generated ' if generated else ''}TD within {timeout} s")


def time_to_td(lab, args, name: str, log: Path) -> tuple[float, float, object]:
    t0 = time.monotonic()
    proc = lab.spawn(*robot_args(args, name, "max"), log=log)
    joined = poll_td(lab.http, name, generated=False) - t0
    generated = poll_td(lab.http, name, generated=True) - t0
    return joined, generated, proc


def robot_args(args, name: str, speed: str) -> tuple[str, ...]:
    return ("robot", args.robot, "--scene", "table-and-wall", "--name", name, "--samples", str(args.samples),
            "--speed", speed)


def two_targets(http: str, name: str) -> list[dict[str, float]]:
    """A safe target and one 1 mm beside it, both accepted by the robot's own check."""
    td = httpx.get(f"{http}/{name}").json()
    csv = httpx.get(next(link["href"] for link in td["links"] if link["rel"] == "dataset-points")).content
    ws = workspace_from_csv(csv)
    free = ws.positions[~ws.collision]
    for p in free[np.random.default_rng(0).permutation(len(free))]:
        q = p + np.array([1.0, 0.0, 0.0])
        checks = [ws.check(p), ws.check(q)]
        if all(c.ok and c.collision_probability == 0 and c.margin_mm > 30 for c in checks):
            return [dict(zip("xyz", map(float, p))), dict(zip("xyz", map(float, q)))]
    raise SystemExit("no safe pair of targets")


def safe_targets(ws, n: int) -> list[dict[str, float]]:
    free = ws.positions[~ws.collision]
    out = []
    for p in free[np.random.default_rng(1).permutation(len(free))]:
        c = ws.check(p)
        if c.ok and c.collision_probability == 0 and c.margin_mm > 30:
            out.append(dict(zip("xyz", map(float, p))))
            if len(out) == n:
                break
    return out


def ms(values) -> str:
    v = np.asarray(values) * 1e3
    return f"p50 {np.percentile(v, 50):7.2f} ms  p99 {np.percentile(v, 99):7.2f} ms  mean {v.mean():7.2f} ms"


def sim_duration(robot: Robot, before: dict, after: dict) -> float:
    q0 = robot.from_user_units([before[j.name] for j in robot.joints])
    q1 = robot.from_user_units([after[j.name] for j in robot.joints])
    vmax = np.array([j.max_velocity for j in robot.joints])
    return PEAK_SPEED * float(np.max(np.abs(q1 - q0) / vmax))


def moves_over(invoke, read, targets, n: int, robot: Robot) -> tuple[list[float], list[float]]:
    """Round trips and simulated durations of n moves alternating between the targets."""
    invoke(targets[0])
    rtt, sim = [], []
    for i in range(n):
        before = read()
        t0 = time.perf_counter()
        invoke(targets[(i + 1) % 2])
        rtt.append(time.perf_counter() - t0)
        sim.append(sim_duration(robot, before, read()))
    return rtt, sim


def in_process(args, targets, n: int) -> list[float]:
    """check_cartesian (hull, probability, IK, configuration collision) alone, in this process."""
    robot = Robot.load(args.robot)
    scene = load_scene("table-and-wall")
    world = World(speed=None)
    build_into(scene, world.client)
    world.start()
    try:
        twin = RobotTwin(world, robot, "bench", Base(tuple(scene.robot.position)), scene)
        twin.set_workspace(args.workspace)
        twin.move_to_cartesian([targets[0][a] for a in "xyz"])
        times = []
        for i in range(n):
            t = [targets[(i + 1) % 2][a] for a in "xyz"]
            t0 = time.perf_counter()
            twin.check_cartesian(t)
            times.append(time.perf_counter() - t0)
            twin.move_to_cartesian(t)
        twin.close()
        return times
    finally:
        world.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default="ur10.urdf")
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--moves", type=int, default=200)
    ap.add_argument("--restarts", type=int, default=3)
    ap.add_argument("--realtime-moves", type=int, default=5)
    ap.add_argument("--far-moves", type=int, default=20)
    ap.add_argument("--keep", action="store_true", help="keep the lab's files (logs, TD cache) at the end")
    args = ap.parse_args()
    robot = Robot.load(args.robot)
    tmp = Path(tempfile.mkdtemp(prefix="bench-robot-"))
    lab = start_lab(tmp, "lights", http=True, things={"tdgen"}, extra_args=("--tdgen-cache", str(tmp / "cache")))
    try:
        print(f"{robot.name} in table-and-wall, {args.samples} samples; lab {lab.http}")
        joined, generated, proc = time_to_td(lab, args, "bench", tmp / "robot.log")
        status = httpx.get(f"{lab.http}/tdgen/properties/robots").json()["bench"]
        print(f"cold   : joined (provisional TD) {joined:6.2f} s, generated TD {generated:6.2f} s "
              f"(the service's generation {status['seconds']:.2f} s)")
        for k in range(args.restarts):
            stop_process(proc)
            joined, generated, proc = time_to_td(lab, args, "bench", tmp / f"robot-{k}.log")
            status = httpx.get(f"{lab.http}/tdgen/properties/robots").json()["bench"]
            print(f"cached : joined (provisional TD) {joined:6.2f} s, generated TD {generated:6.2f} s "
                  f"(cache hit {status['seconds'] * 1e3:.1f} ms, cached={status['cached']})")

        targets = two_targets(lab.http, "bench")
        td = httpx.get(f"{lab.http}/bench").json()
        args.workspace = workspace_from_csv(httpx.get(
            next(link["href"] for link in td["links"] if link["rel"] == "dataset-points")).content)
        settings = MeshSettings(mode="client", connect=(lab.endpoint,))
        with open_session(settings) as session:
            c = MeshClient(session, settings)
            rtt, sim = moves_over(lambda t: c.invoke("bench", "moveToCartesianPosition", t),
                                  lambda: c.read("bench", "getJointposition"), targets, args.moves, robot)
        print(f"\nmoveToCartesianPosition, 1 mm moves at speed max ({args.moves} each):")
        print(f"  Zenoh round trip   {ms(rtt)}")
        with httpx.Client(base_url=lab.http, timeout=60) as h:
            rtt_http, _ = moves_over(
                lambda t: h.post("/bench/actions/moveToCartesianPosition", json=t).raise_for_status(),
                lambda: h.get("/bench/properties/getJointposition").json(), targets, args.moves, robot)
        print(f"  HTTP round trip    {ms(rtt_http)}")
        print(f"  check + IK + collision check in-process  {ms(in_process(args, targets, args.moves))}")
        print(f"  the motions' simulated duration (what speed 1 adds)  {ms(sim)}")
        far = safe_targets(args.workspace, args.far_moves)
        with open_session(settings) as session:
            c = MeshClient(session, settings)
            rtt_far, sim_far = [], []
            for t in far:
                before = c.read("bench", "getJointposition")
                t0 = time.perf_counter()
                c.invoke("bench", "moveToCartesianPosition", t)
                rtt_far.append(time.perf_counter() - t0)
                sim_far.append(sim_duration(robot, before, c.read("bench", "getJointposition")))
        print(f"\nbetween {args.far_moves} random safe targets at speed max: Zenoh round trip {ms(rtt_far)}")
        print(f"  simulated duration (wall time at speed 1)  {ms(sim_far)}")

        lab.spawn(*robot_args(args, "bench-rt", "1"), log=tmp / "robot-rt.log")
        poll_td(lab.http, "bench-rt", generated=True)
        with open_session(settings) as session:
            c = MeshClient(session, settings)
            rtt_rt, sim_rt = moves_over(lambda t: c.invoke("bench-rt", "moveToCartesianPosition", t),
                                        lambda: c.read("bench-rt", "getJointposition"), targets,
                                        args.realtime_moves, robot)
        over = np.asarray(rtt_rt) - np.asarray(sim_rt)
        print(f"\nat speed 1 ({args.realtime_moves} moves over Zenoh): wall {ms(rtt_rt)}")
        print(f"  simulated duration {ms(sim_rt)}")
        print(f"  wall - simulated   {ms(over)}")
    finally:
        lab.stop()
        if args.keep:
            print(f"lab files kept in {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
