"""Scene `iot-lab`: the whole room in one pybullet world, around the `iot-platform` table.

Surroundings frame (m): the floor at z = 0, the iot-platform table centred on the origin exactly as in
its own scene (so the uArm frame and every coordinate of the cube workflow are unchanged). Seen
from above, with x to the right and y up:

- the `ur10` stands on its own table at x = 2.3 (its base 0.75 m up, facing -x, towards the
  platform); a *virtual* safety wall at x = 1.45 stands between it and the other tables. The wall
  is not there physically (nothing bumps into it, it is drawn see-through) but it is part of the
  robot's scene, so sampled configurations that cross it collide and Cartesian targets beyond it
  are refused (`collision-risk`);
- the top table at y = 1.6 carries the two lights (`light-left` at -x, `light-right` at +x; each
  lamp's shade shows its colour when on) and the two pan-tilt units between them, looking towards
  -y, across the platform, at a colour chart on the far wall (red, green, blue, yellow cards high
  enough to be seen over the platform) that gives their colour sensors something to find;
- the room: a floor and four walls.

Obstacles (a box, a CAD mesh, a scan) can be added while the lab runs (`add_obstacle`): they are built into
the world and added to the UR10's scene (`RobotTwin.set_scene`), whose workspace and TD then follow; a scan
added again under its name replaces the previous one in one change (a depth camera's latest cloud).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pybullet as pb

from devices.sim.bodies import box, pose
from devices.sim.layouts.obstacles import Obstacle, build, described, scene_body
from devices.sim.layouts.platform_layout import IotPlatform
from devices.sim.pan_tilt import PAN_TILT_URDF, PanTilt
from devices.sim.pybullet_world import DEFAULT_DT, Snapshot, World, body_pose, static_box
from devices.sim.robot_twin import WORKSPACE_WAIT, Base, RobotTwin
from mesh.messages.scene_description import Body, RobotModel, SceneDescription
from mesh.wot.problem import Refused
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import BoxBody, Surroundings, build_into

TABLE_TOP = 0.75
OFF_RGB = (0.35, 0.35, 0.35)
CHART = {"red": (0.86, 0.12, 0.10), "green": (0.12, 0.66, 0.22), "blue": (0.12, 0.28, 0.86),
         "yellow": (0.95, 0.82, 0.10)}


@dataclass(frozen=True)
class LabLayout:
    """Where things stand in the room (scene frame, m; yaw in deg)."""

    room_x: tuple[float, float] = (-3.0, 4.0)
    room_y: tuple[float, float] = (-3.0, 3.0)
    wall_height: float = 2.6
    ur10_table: tuple[float, float, float, float] = (2.3, 0.0, 1.0, 1.2)   # centre x, y, size x, y
    ur10_base: tuple[float, float, float, float] = (2.3, 0.0, TABLE_TOP, 180.0)  # x, y, z, yaw
    safety_wall_x: float = 1.45
    safety_wall_width: float = 3.0
    safety_wall_height: float = 2.0
    top_table: tuple[float, float, float, float] = (0.0, 1.6, 1.8, 0.6)    # centre x, y, size x, y
    lights: tuple[tuple[str, float], ...] = (("light-left", -0.7), ("light-right", 0.7))  # x on the top table
    pan_tilts: tuple[tuple[str, float], ...] = (("pan-tilt-1", -0.25), ("pan-tilt-2", 0.25))
    pan_tilt_y: float = 1.45
    pan_tilt_yaw: float = -90.0          # looking towards -y, across the platform
    chart_xs: tuple[float, ...] = (-0.9, -0.3, 0.3, 0.9)
    chart_z: float = 1.6
    chart_card: float = 0.4              # square cards, m


LAB = LabLayout()


def robot_scene(layout: LabLayout = LAB) -> Surroundings:
    """The UR10's static surroundings (tdgen scene format): floor, its table, the safety wall."""
    (x0, x1), (y0, y1) = layout.room_x, layout.room_y
    tx, ty, sx, sy = layout.ur10_table
    return Surroundings(
        name="iot-lab-ur10",
        description="The UR10's corner of the iot-lab: the floor, its table (a solid stand, top at 0.75 m) and the "
                    f"virtual safety wall at x = {layout.safety_wall_x} m between it and the other tables.",
        bodies=[
            BoxBody(name="floor", size=(x1 - x0, y1 - y0, 0.02), position=((x0 + x1) / 2, (y0 + y1) / 2, -0.01),
                    rgba=(0.55, 0.55, 0.52, 1.0)),
            BoxBody(name="ur10-table", size=(sx, sy, TABLE_TOP), position=(tx, ty, TABLE_TOP / 2),
                    rgba=(0.45, 0.47, 0.5, 1.0)),
            BoxBody(name="safety-wall", size=(0.02, layout.safety_wall_width, layout.safety_wall_height),
                    position=(layout.safety_wall_x, 0.0, layout.safety_wall_height / 2), rgba=(1.0, 0.25, 0.2, 0.25)),
        ])


class Lamp:
    """A light's body on the top table: its shade shows the light's colour while it is on."""

    def __init__(self, world: World, name: str, x: float, y: float):
        c = world.client
        self.world, self.name = world, name
        self.post = static_box(c, [0.01, 0.01, 0.15], [x, y, TABLE_TOP + 0.15], rgba=(0.2, 0.2, 0.2, 1))
        self.shade = static_box(c, [0.06, 0.06, 0.03], [x, y, TABLE_TOP + 0.33], rgba=(*OFF_RGB, 1))
        self.on, self.color = False, [1.0, 1.0, 1.0]

    def show(self, on: bool, color: list[float]) -> None:
        """The light's new state (any thread)."""
        self.on, self.color = bool(on), list(color)
        rgb = self.color if self.on else OFF_RGB
        self.world.run(lambda: pb.changeVisualShape(self.shade, -1, rgbaColor=[*rgb, 1],
                                                    physicsClientId=self.world.client))

    def fill(self, snap: Snapshot) -> None:
        snap.states[self.name] = {"on": self.on, "color": self.color}


class IotLab:
    """The room, its tables and devices: the platform's, the UR10, the lights' lamps and the pan-tilts."""

    name = "iot-lab"

    def __init__(self, world: World, layout: LabLayout = LAB, *, max_collision_probability: float | None = None):
        self.world, self.layout = world, layout
        c = world.client
        self.fixtures: dict[str, int] = {}
        self._base_scene = robot_scene(layout)
        for body, body_id in zip(self._base_scene.bodies, build_into(self._base_scene, c)):
            self.fixtures[body.name] = body_id
        pb.setCollisionFilterGroupMask(self.fixtures["safety-wall"], -1, 0, 0, physicsClientId=c)  # virtual
        self._build_room()
        self._build_top_table()
        self.platform = IotPlatform(world, floor=False)
        self.lamps = {name: Lamp(world, name, x, layout.top_table[1]) for name, x in layout.lights}
        self.pan_tilts = {name: PanTilt(world, name, (x, layout.pan_tilt_y, TABLE_TOP), layout.pan_tilt_yaw,
                                        names=self.body_names)
                          for name, x in layout.pan_tilts}
        x, y, z, yaw = layout.ur10_base
        self.ur10 = RobotTwin(world, Robot.load("ur10.urdf"), "ur10", Base((x, y, z), yaw), self._base_scene,
                              max_collision_probability=max_collision_probability, workspace_wait=WORKSPACE_WAIT)
        self._obstacles: dict[str, tuple[Obstacle, int]] = {}
        self._names: dict[int, str] | None = None
        self._lock = threading.Lock()
        for lamp in self.lamps.values():
            world.add_snapshot_source(lamp.fill)

    # --- what the world Thing asks (devices.things.world_thing.SimulatedScene) ---------------------------
    @property
    def cube_count(self) -> int:
        return self.platform.cube_count

    def robot_urdfs(self) -> dict[str, Path]:
        return {**self.platform.robot_urdfs(), "ur10": self.ur10.robot.urdf_path,
                **{name: PAN_TILT_URDF for name in self.pan_tilts}}

    def describe(self) -> SceneDescription:
        """The platform's description plus the room, the UR10, the lamps, the pan-tilts, the obstacles."""
        c = self.world.client
        platform = self.platform.describe()
        bodies: list[Body] = [box(c, name, body) for name, body in self.fixtures.items()]
        for lamp in self.lamps.values():
            shade = msgspec.structs.replace(box(c, f"{lamp.name}-shade", lamp.shade), color=OFF_RGB, shows=lamp.name)
            bodies += [box(c, f"{lamp.name}-post", lamp.post), shade]
        bodies += [box(c, o.body_name, body) if o.type == "box" else described(o) for o, body in self._obstacles.values()]
        urdfs = self.robot_urdfs()
        robots = [RobotModel(name="ur10", urdf="ur10.urdf", base=self.ur10.base.pose(),
                             urdf_dir=str(urdfs["ur10"].resolve().parent))]
        robots += [RobotModel(name=name, urdf=f"{name}.urdf", base=pose(body_pose(c, unit.body)),
                              urdf_dir=str(urdfs[name].resolve().parent))
                   for name, unit in self.pan_tilts.items()]
        return SceneDescription(name=self.name, robots=platform.robots + robots, bodies=platform.bodies + bodies)

    def reset(self, cubes: int | None = None) -> None:
        """The platform's reset (cubes, belts, uArm, Dobot), the pan-tilts and the UR10 home. Obstacles stay."""
        self.platform.reset(cubes)  # cancels every motion under way, the UR10's and pan-tilts' too
        for unit in self.pan_tilts.values():
            unit.reset()
        self.ur10.reset()

    def close(self) -> None:
        self.ur10.close()
        self.world.close()

    def body_names(self) -> dict[int, str]:
        """pybullet body id -> name, for what the pan-tilts' colour sensors report seeing (kept until an
        obstacle comes or goes: the sensors ask on every look)."""
        names = self._names
        if names is None:
            names = self._names = self._all_body_names()
        return names

    def _all_body_names(self) -> dict[int, str]:
        names = {body: name for name, body in self.fixtures.items()}
        names.update({body: name for name, body in self.platform.fixtures.items()})
        names.update({cube.body: cube.name for cube in self.platform.cubes})
        names.update({belt.body: name for name, belt in self.platform.belts.items()})
        for lamp in self.lamps.values():
            names[lamp.post], names[lamp.shade] = lamp.name, lamp.name
        names.update({body: o.body_name for o, body in list(self._obstacles.values())})
        names[self.ur10.arm.body] = "ur10"
        names[self.platform.uarm.arm.body] = "uarm"
        names[self.platform.dobot.arm.body] = "dobot"
        return names

    # --- obstacles (devices.things.world_thing.ObstacleScene) --------------------------------------------
    def obstacles(self) -> list[Obstacle]:
        return [o for o, _ in self._obstacles.values()]

    def robot_scene(self) -> Surroundings:
        """The UR10's scene now: its static surroundings and every obstacle."""
        bodies = [*self._base_scene.bodies, *(scene_body(o) for o, _ in self._obstacles.values())]
        return Surroundings(name=self._base_scene.name, description=self._base_scene.description, bodies=bodies)

    def add_obstacle(self, obstacle: Obstacle) -> None:
        """Build the obstacle into the world and the UR10's scene; refused if the name is taken (but by a scan,
        which a scan replaces) or it hits the UR10."""
        with self._lock:
            before = self._obstacles.get(obstacle.name)
            if before is not None and not (before[0].type == obstacle.type == "points"):
                raise Refused(f"there is already an obstacle named {obstacle.name!r}; remove it first",
                              reason="obstacle-exists")
            if self.ur10.would_touch([scene_body(obstacle)]):
                raise Refused(f"obstacle {obstacle.name!r} would hit the ur10 where it stands; move the robot "
                              "away first or put it elsewhere", reason="obstacle-hits-robot")

            def swap() -> int:
                if before is not None:
                    pb.removeBody(before[1], physicsClientId=self.world.client)
                return build(self.world.client, obstacle)

            body = self.world.run(swap)
            self._obstacles[obstacle.name] = (obstacle, body)
            self._names = None
            self.ur10.set_scene(self.robot_scene())

    def remove_obstacle(self, name: str) -> Obstacle:
        with self._lock:
            if name not in self._obstacles:
                known = ", ".join(self._obstacles) or "none"
                raise Refused(f"no obstacle named {name!r} (obstacles: {known})", reason="no-such-obstacle")
            obstacle, body = self._obstacles.pop(name)
            self._names = None
            self.world.run(lambda: pb.removeBody(body, physicsClientId=self.world.client))
            self.ur10.set_scene(self.robot_scene())
            return obstacle

    # --- building ---------------------------------------------------------------------------------
    def _build_room(self) -> None:
        L, c = self.layout, self.world.client
        (x0, x1), (y0, y1) = L.room_x, L.room_y
        h, t = L.wall_height, 0.05
        walls = {"wall-south": ([(x1 - x0) / 2, t, h / 2], [(x0 + x1) / 2, y0 - t, h / 2]),
                 "wall-north": ([(x1 - x0) / 2, t, h / 2], [(x0 + x1) / 2, y1 + t, h / 2]),
                 "wall-west": ([t, (y1 - y0) / 2, h / 2], [x0 - t, (y0 + y1) / 2, h / 2]),
                 "wall-east": ([t, (y1 - y0) / 2, h / 2], [x1 + t, (y0 + y1) / 2, h / 2])}
        for name, (half, centre) in walls.items():
            self.fixtures[name] = static_box(c, half, centre, rgba=(0.9, 0.9, 0.86, 0.35))
        s = L.chart_card / 2
        for (color, rgb), x in zip(CHART.items(), L.chart_xs):
            self.fixtures[f"chart-{color}"] = static_box(c, [s, 0.005, s], [x, y0 + 0.006, L.chart_z], rgba=(*rgb, 1))

    def _build_top_table(self) -> None:
        L, c = self.layout, self.world.client
        cx, cy, sx, sy = L.top_table
        self.fixtures["top-table"] = static_box(c, [sx / 2, sy / 2, 0.015], [cx, cy, TABLE_TOP - 0.015],
                                                rgba=(0.78, 0.7, 0.58, 1))
        for i, (dx, dy) in enumerate([(dx, dy) for dx in (-1, 1) for dy in (-1, 1)], 1):
            self.fixtures[f"top-table-leg-{i}"] = static_box(
                c, [0.025, 0.025, (TABLE_TOP - 0.03) / 2],
                [cx + dx * (sx / 2 - 0.05), cy + dy * (sy / 2 - 0.05), (TABLE_TOP - 0.03) / 2],
                rgba=(0.3, 0.3, 0.3, 1), collide=False)


def build_lab(*, speed: float | None = 1.0, dt: float = DEFAULT_DT, snapshot_hz: float = 30.0,
              max_collision_probability: float | None = None, start: bool = True) -> IotLab:
    """A new world with the iot-lab in it, stepping (`start=True`) at `speed` (None: as fast as possible)."""
    world = World(dt=dt, speed=speed, snapshot_hz=snapshot_hz)
    try:
        lab = IotLab(world, max_collision_probability=max_collision_probability)
    except BaseException:
        world.close()
        raise
    if start:
        world.start()
    return lab
