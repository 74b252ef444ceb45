"""The tdgen pipeline: robot + scene -> sampled points -> workspace -> TD and its artefacts on disk.

One call, `generate(...)`, so the CLI and the mesh service (which caches results per robot and
scene) run exactly the same steps. Every input is checked before the sampling starts, so a bad
scene or calibration fails in a second, not after minutes.

Files written to `out_dir`: td.json (with a base URL: the TD the HTTP adapter serves there) or
tm.json (without: a Thing Model with `{{BASE_URL}}` open), robot-info.json, points.csv,
workspace.stl, workspace-concave.stl (with `concave`), scene.json (the scene used, robot pose
included) and calibration.json (with a calibration). `GenerationResult.td` is the TD a robot Thing
serves on the mesh (what the tdgen service hands to robots).
"""
from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Literal
from urllib.parse import urlsplit

import msgspec
import numpy as np

from mesh.messages.scene_description import DEFAULT_SAMPLES, CollisionModel
from mesh.wot.thing_description import NOSEC, Security
from tdgen.robot import points_csv
from tdgen.robot.calibration import Calibration, CalibrationError, Model, load_calibration
from tdgen.robot.collision import CollisionWorld, body_names
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import RobotPlacement, Surroundings, default_scene, encode_scene, load_scene
from tdgen.robot.workspace import WorkspaceError, alpha_shape, bounds, convex_hull, stl_bytes
from tdgen.robot_td import policy, robot_td, served_td, slug, thing_model
from tdgen.sampling import Samples, sample_workspace

log = logging.getLogger(__name__)

Frame = Literal["twin", "real"]
Writer = Callable[[Path, "bytes | bytearray | points_csv.Flags"], None]  # an artefact's path, its content


@dataclass(frozen=True)
class GenerationResult:
    out_dir: Path
    files: dict[str, Path]                 # "td" or "tm", "robot-info", "points", "workspace", "scene", ...
    volume_mm3: float                      # convex hull of the collision-free points
    concave_volume_mm3: float | None       # alpha shape, when asked for and not degenerate
    low_mm: tuple[float, float, float]     # bounds of the collision-free points (TD frame)
    high_mm: tuple[float, float, float]
    samples: int
    collision_free: int
    frame: str
    timings: dict[str, float] = field(default_factory=dict)  # seconds per step
    calibration: Calibration | None = None
    td: dict = field(default_factory=dict)  # the TD on the mesh (relative forms), as a robot Thing serves it
    warnings: list[str] = field(default_factory=list)  # for people: a workspace that is mostly collision
    sampled: Samples | None = field(default=None, repr=False, compare=False)  # the samples, kept for a live update
    points: bytes | bytearray | None = field(default=None, repr=False, compare=False)  # a generation's points.csv

    def summary(self) -> dict:
        """JSON-ready summary (paths as strings)."""
        return {"out_dir": str(self.out_dir), "files": {k: str(v) for k, v in self.files.items()},
                "volume_mm3": self.volume_mm3, "concave_volume_mm3": self.concave_volume_mm3,
                "low_mm": list(self.low_mm), "high_mm": list(self.high_mm), "samples": self.samples,
                "collision_free": self.collision_free, "frame": self.frame, "timings": self.timings}


def _robot(robot: Robot | str | Path, ee: str | None) -> Robot:
    return robot if isinstance(robot, Robot) else Robot.load(robot, ee=ee)


def _scene(scene: Surroundings | str | Path | None, mount: RobotPlacement | None, surface: bool,
           reach: float | None = None) -> Surroundings:
    """The scene as given (the robot moved to `mount` if given), else the robot on its mounting surface
    (wider than the arm's `reach`)."""
    if scene is None:
        return default_scene(mount, surface, reach)
    loaded = scene if isinstance(scene, Surroundings) else load_scene(scene)
    return msgspec.structs.replace(loaded, robot=mount) if mount is not None else loaded


def _calibration(calibration: Calibration | str | Path | None, model: Model, frame: Frame) -> Calibration | None:
    if frame not in ("twin", "real"):
        raise ValueError(f"frame must be 'twin' or 'real', not {frame!r}")
    if calibration is not None and not isinstance(calibration, Calibration):
        calibration = load_calibration(calibration, model)
    if frame == "real" and calibration is None:
        raise CalibrationError("the real frame needs a calibration (pairs of twin and real positions)")
    return calibration


def _description(robot: Robot, scene: Surroundings, samples: Samples, seed: int | None, volume: float,
                 calibration: Calibration | None, frame: Frame) -> str:
    pose = scene.robot
    tilt = f", roll {pose.roll:g} deg, pitch {pose.pitch:g} deg" if pose.roll or pose.pitch else ""
    where = (f"the robot's base frame (in scene '{scene.name}' the base stands at "
             f"{list(pose.position)} m, yaw {pose.yaw:g} deg{tilt})")
    if frame == "real" and calibration is not None:
        where = f"the real robot's frame, mapped from {where} by the {calibration.used} calibration"
    return (f"{robot.name}, generated by twinmesh tdgen from {robot.urdf_path.name}: {len(samples.q)} random "
            f"joint configurations (seed {seed}), {int((~samples.collision).sum())} free of self- and scene "
            f"collision. Cartesian positions are in mm in {where}. Workspace: convex hull of the "
            f"collision-free end-effector positions, {volume / 1e9:.4g} m^3. {policy()}")


def generate(robot: Robot | str | Path, scene: Surroundings | str | Path | None = None, samples: int = DEFAULT_SAMPLES,
             seed: int | None = 0, out_dir: str | Path = "td-out", base_url: str | None = None,
             calibration: Calibration | str | Path | None = None, frame: Frame = "twin", concave: bool = False,
             progress: bool = False, *, name: str | None = None, thing_id: str | None = None,
             ee: str | None = None, workers: int | None = None, calibration_model: Model = "auto",
             on_progress: Callable[[float], None] | None = None, security: Security = NOSEC,
             mount: RobotPlacement | None = None, surface: bool = True,
             collision_model: CollisionModel = "fast") -> GenerationResult:
    """Generate a robot's TD and workspace artefacts into `out_dir`.

    `robot` is a Robot or a URDF path (`ee` then picks the end-effector link); `scene` a Surroundings, a
    scene file or a shipped scene name (None: the robot on the surface it is mounted on, or alone
    without `surface`); `mount` places the robot elsewhere than the scene says; `calibration` a Calibration or a
    pairs CSV. `base_url` is the Thing's URL on an HTTP adapter (`http://host:8080/ur10`): its last
    segment is the Thing name, else `name` or the robot's name as a slug. `collision_model` "fast" (the
    sphere model, the exact test's answers; `tdgen.robot.fast_collision`) or "exact" (pybullet for every
    sample). Raises RobotError,
    SceneError, CalibrationError or WorkspaceError with a message for people, ValueError for a
    base URL that names no Thing.
    """
    thing = _thing_name(base_url, name)
    started = time.perf_counter()
    robot = _robot(robot, ee)
    scene = _scene(scene, mount, surface, robot.reach())
    thing = thing or slug(robot.name)
    calibration = _calibration(calibration, calibration_model, frame)
    timings: dict[str, float] = {}

    t = time.perf_counter()
    world = CollisionWorld(robot, scene)  # one for the sampling and the warnings: a scan is built into pybullet once
    try:
        sampled = sample_workspace(robot, scene, samples, seed, workers=workers, progress=progress,
                                   on_progress=on_progress, collision_model=collision_model, world=world)
        if frame == "real":
            assert calibration is not None, "_calibration refuses the real frame without a calibration"
            sampled = Samples(sampled.q, np.round(calibration.apply(sampled.positions), 3), sampled.collision)
        timings["sampling"] = time.perf_counter() - t
        return write_artefacts(robot, scene, sampled, out_dir, Naming(thing, thing_id, base_url, security), seed,
                               calibration, frame, concave, timings=timings, started=started, world=world)
    finally:
        world.close()


@dataclass(frozen=True)
class Naming:
    """What the TD is called and where it is served: the Thing's name and id, its base URL on the HTTP
    adapter (None: a Thing Model is written), its security."""

    thing: str
    thing_id: str | None = None
    base_url: str | None = None
    security: Security = NOSEC


def write_artefacts(robot: Robot, scene: Surroundings, sampled: Samples, out_dir: str | Path, naming: Naming,
                    seed: int | None, calibration: Calibration | None = None, frame: Frame = "twin",
                    concave: bool = False, points: bytes | bytearray | points_csv.Flags | None = None,
                    timings: dict[str, float] | None = None, started: float | None = None,
                    warnings: list[str] | None = None, write: Writer | None = None,
                    world: CollisionWorld | None = None) -> GenerationResult:
    """The workspace, the TD and the files of samples taken in `scene` (positions already in the TD's
    frame). `points`: the points.csv of exactly these samples when it is at hand (a live update's), else
    it is written from them; `warnings`: `collision_warnings` of them, if known. A generation and a live
    update of the same samples write the same bytes. `write(path, content)` (default: into the file) is
    handed each file instead: a live update keeps them in memory and serves them before they are on disk.
    `world`: a collision world of `scene` already open, to ask what collides."""
    timings = {} if timings is None else timings
    started = time.perf_counter() if started is None else started
    warnings = collision_warnings(robot, scene, sampled, world=world) if warnings is None else warnings

    t = time.perf_counter()
    free = sampled.free
    try:
        low, high = bounds(free)
        hull = convex_hull(free)
    except WorkspaceError as e:
        if float(sampled.collision.mean()) > 0.99:
            raise WorkspaceError(f"{e}{start_pose_hint(robot, scene)}") from None
        raise
    timings["hull"] = time.perf_counter() - t
    concave_solid = None
    if concave:
        t = time.perf_counter()
        concave_solid = alpha_shape(free)
        timings["concave"] = time.perf_counter() - t

    t = time.perf_counter()
    out = Path(out_dir)
    if write is None:
        out.mkdir(parents=True, exist_ok=True)
        write = write_file
    base_url = naming.base_url
    kind = "td" if base_url else "tm"
    files = {key: out / file for key, file in ((kind, f"{kind}.json"), ("robot-info", "robot-info.json"),
                                                ("points", "points.csv"), ("workspace", "workspace.stl"),
                                                ("scene", "scene.json"))}
    description = _description(robot, scene, sampled, seed, hull.volume, calibration, frame)
    description += "".join(f" Warning: {w}." for w in warnings)  # a lab's user reads it in the TD
    td = robot_td(robot, low, high, name=naming.thing, frame=frame, thing_id=naming.thing_id, description=description)
    write(files[kind], _json(served_td(td, base_url, naming.security) if base_url
                             else thing_model(td, naming.thing, naming.security)))
    write(files["robot-info"], _json(robot.info()))
    if points is None:
        points = points_csv.encode(robot, sampled.positions, sampled.collision, sampled.q)
    write(files["points"], points)
    write(files["workspace"], stl_bytes(hull))
    write(files["scene"], encode_scene(scene))
    if concave_solid is not None:
        files["workspace-concave"] = out / "workspace-concave.stl"
        write(files["workspace-concave"], stl_bytes(concave_solid))
    if calibration is not None:
        files["calibration"] = out / "calibration.json"
        write(files["calibration"], calibration.to_json())
    timings["writing"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - started

    return GenerationResult(
        out_dir=out, files=files, volume_mm3=hull.volume,
        concave_volume_mm3=concave_solid.volume if concave_solid is not None else None,
        low_mm=_triple(low), high_mm=_triple(high), samples=len(sampled.q), collision_free=len(free),
        frame=frame, timings=timings, calibration=calibration, td=td, warnings=warnings, sampled=sampled,
        points=None if isinstance(points, points_csv.Flags) else points)


def write_file(path: Path, content: bytes | bytearray | points_csv.Flags) -> None:
    """An artefact into its file (a points file re-flagged in memory: its bytes)."""
    path.write_bytes(content.data if isinstance(content, points_csv.Flags) else content)


MOSTLY_COLLIDING = 0.5  # share of colliding samples above which a workspace is worth a word (information)
TAKEN_AWAY = 0.9        # share above which it is worth a warning: the scene leaves the arm little room, likely a mistake
BY_DESIGN = 0.15        # share of all poses from which a pair of the robot's own links touching at rest overlaps by design
PAIR_SAMPLES = 200      # colliding samples asked which links touch


def start_pose_hint(robot: Robot, scene: Surroundings) -> str:
    """Why (nearly) every sample collides, when the robot collides already where it starts (every joint at
    0, within its limits): the pairs that touch there, and the option that allows exactly each pair."""
    world = CollisionWorld(robot, scene)
    try:
        pairs = world.what_collides(np.clip(np.zeros(len(robot.joints)), robot.lows(), robot.highs()))
    finally:
        world.close()
    if pairs:
        options = " ".join(f"--allow-collision {pair.replace(' / ', '/')}" for pair in pairs[:4])
        surface = (" (or, as its tip hangs below its base link at that pose, the base is not where it is mounted, "
                   "a humanoid's shoulder say: --no-surface)" if _hangs(robot) and any(
                       p.endswith(" / mounting-surface") for p in pairs) else "")
        return (f"; at its start pose (every joint at 0) it already collides: {', '.join(pairs[:4])}. If that "
                f"contact is by design, allow exactly that: {options}{surface}")
    if any(b.name == "mounting-surface" for b in scene.bodies):
        return ("; without a scene the robot stands on a surface through its base, across its z axis: "
                "--no-surface for an arm whose base link is not where it is mounted")
    return ""


def _hangs(robot: Robot) -> bool:
    """Is the tip below the base link at the start pose (an arm hanging from a shoulder, not standing)?"""
    from tdgen.robot.kinematics import ForwardKinematics

    return bool(ForwardKinematics(robot).positions(np.clip(np.zeros(len(robot.joints)), robot.lows(), robot.highs()))[2] < 0)


def collision_warnings(robot: Robot, scene: Surroundings, samples: Samples, at_rest: list[str] | None = None,
                       pairs: list[list[str]] | None = None, world: CollisionWorld | None = None) -> list[str]:
    """When most samples collide and the robot collides already at rest (joints at 0, within their limits:
    the URDF's collision meshes overlap by design, the usual cause), or nearly all collide (a scene that
    leaves the robot little room), say so and name the link pairs that collide most; most colliding
    otherwise is an arm among its scene's bodies, as designed: logged as information, not a warning.
    And whatever the share, a pair of the robot's own links that touches at rest and collides in BY_DESIGN
    of all samples or more, or in any share when only prismatic joints join the two (`Robot.slide_along`):
    parts that overlap by design (a telescoping arm's nested tubes, as convex hulls), with the option that
    allows exactly each. A pair that collides as often but not at rest is an arm folding into itself (a
    UR5's upper arm into its base in 37 % of its poses): not said. `at_rest`: `robot_at_rest(robot)`, if
    known; `pairs`: what collides in each of the first PAIR_SAMPLES
    colliding samples, if known (a live update's); `world`: a collision world of `scene` already open, else
    one is made when needed."""
    share = float(samples.collision.mean()) if len(samples.collision) else 0.0
    if share < BY_DESIGN:
        return []
    colliding = samples.q[samples.collision][:PAIR_SAMPLES]
    owned = world is None and pairs is None
    if owned:
        world = CollisionWorld(robot, scene)
    try:
        if pairs is None:
            assert world is not None, "made above when not given"
            pairs = [world.what_collides(q) for q in colliding]
        return _warnings(robot, scene, share, len(colliding), Counter(pair for found in pairs for pair in found),
                         at_rest, world, set(body_names(scene)))
    finally:
        if owned and world is not None:
            world.close()


def _warnings(robot: Robot, scene: Surroundings, share: float, asked: int, counts: Counter[str],
              at_rest: list[str] | None, world: CollisionWorld | None, bodies: set[str]) -> list[str]:
    """`collision_warnings`' words, from the pairs counted in `asked` colliding samples (`world`: one of the
    scene already open, if any, to ask what collides at rest)."""
    # ties by name: the text depends on the counts only, not on the order pybullet lists contacts in (a
    # world a live update keeps holds its bodies in another order than a new one)
    ranked = sorted(counts.items(), key=lambda item: (-item[1], item[0]))
    asked = max(asked, 1)
    out = []
    own_pairs = [(pair, n / asked * share) for pair, n in ranked if pair.partition(" / ")[2] not in bodies]
    often = [(pair, part) for pair, part in own_pairs
             if part >= BY_DESIGN or robot.slide_along(*pair.split(" / "))]
    if share > MOSTLY_COLLIDING or often:
        at_rest = robot_at_rest(robot, scene, world) if at_rest is None else at_rest
    if share > MOSTLY_COLLIDING:
        top = ", ".join(f"{pair} ({n * 100 // asked} %)" for pair, n in ranked[:5])
        said = (f"{share:.0%} of the samples collide (the workspace is made of the other {1 - share:.0%}); the "
                f"pairs that collide most: {top or 'none named'}")
        if at_rest or share > TAKEN_AWAY:  # likely a mistake: a warning
            out.append(said + ("" if at_rest else "; the scene leaves the robot little room: is it placed as meant?"))
        else:  # an arm among the bodies of its scene and folding into itself, as designed: information
            log.info("%s: %s", robot.name, said)
        if at_rest:
            out.append(f"{robot.name} collides at rest (every joint at 0): {', '.join(at_rest)}; its collision "
                       "meshes overlap by design, which a tool like MoveIt's SRDF disables per pair")
    own = [(pair, part) for pair, part in often if pair in (at_rest or ())]
    if own:
        out.append(f"{', '.join(f'{pair} ({_share(part)} of the samples)' for pair, part in own)}: {robot.name}'s own "
                   f"links, touching at rest and in that share of all poses; their collision meshes overlap by "
                   "design most likely (nested parts, or parts that touch as convex hulls): if so, allow exactly "
                   f"{'that pair' if len(own) == 1 else 'those pairs'}: "
                   + " ".join(f"--allow-collision {pair.replace(' / ', '/')}" for pair, _ in own))
    return out


def _share(part: float) -> str:
    return f"{part:.0%}" if part >= 0.01 else f"{part:.1%}"


def robot_at_rest(robot: Robot, scene: Surroundings, world: CollisionWorld | None = None) -> list[str]:
    """The robot's own colliding pairs with every joint at 0 (within its limits): its links' pairs, not
    those with the scene (in whose world it is asked: the robot's allowed pairs may name its bodies).
    `world`: one of `scene` already open, else one is made."""
    asked = world or CollisionWorld(robot, scene)
    try:
        pairs = asked.what_collides(np.clip(np.zeros(len(robot.joints)), robot.lows(), robot.highs()))
    finally:
        if world is None:
            asked.close()
    bodies = set(body_names(scene))
    return [pair for pair in pairs if pair.partition(" / ")[2] not in bodies]


def _thing_name(base_url: str | None, name: str | None) -> str | None:
    """The Thing's name: the base URL's last segment, else `name`; checked before any work is done."""
    if base_url:
        url = urlsplit(base_url)
        thing = url.path.rstrip("/").rpartition("/")[2]
        if not (url.scheme and url.netloc and thing) or url.query or url.fragment:
            raise ValueError(f"--base-url must be the Thing's URL on the adapter (http://HOST:PORT/<thing>), "
                             f"not {base_url!r}")
        if name and name != thing:
            raise ValueError(f"the base URL names the Thing {thing!r}, not {name!r}")
        return thing
    return name


def _triple(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


def _json(obj: object) -> bytes:
    return msgspec.json.format(msgspec.json.encode(obj), indent=2) + b"\n"

