"""Scene `iot-platform`: the lab's IoT platform on one table, built in one pybullet world.

All positions are in ONE place, `Layout`, in the real uArm frame (mm; z = 0 is the table top),
because that is the frame the lab's client scripts use: a cube stopped at the end of the right
belt is gripped at (192, 192, 52), the colour check point is (180, 0, 60), cubes go down on the
left belt at (200, -200, 70). The scene frame (m) has the floor at z = 0 and the table top at
0.75 m, centred on the table; the uArm stands unrotated at `UARM_BASE`, so the calibration is
`real = 1000 * twin - 1000 * UARM_BASE` per axis.

Looking from the uArm (x forward): the belts run along x, the right belt (`conveyor-belt-2`) at
y = +192 carrying forward (-x) from the Dobot to the uArm, the left belt (`conveyor-belt-1`) at
y = -200 carrying backward (+x) to the Dobot. The Dobot's track runs along y behind the belts'
far ends (l = 450 mm at y = 0), the Dobot facing the uArm; the warehouse queue lies between the
belts' far ends, slot 0 next to the right belt.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from devices.sim.belt import Belt
from devices.sim.bodies import box, pose
from devices.sim.compensation import DOBOT_URDF, MODELS, UARM_URDF
from devices.sim.dobot import CUBE_SIZE, Cube, Dobot, Warehouse, make_cube
from devices.sim.pybullet_world import DEFAULT_DT, Snapshot, World, body_pose, place, static_box
from devices.sim.sensors import ColorSensor, InfraredSensor
from devices.sim.uarm import Uarm, write_calibration_csv
from devices.sim.vec import Vec
from mesh.messages.scene_description import Body, RobotModel, SceneDescription
from tdgen.robot.surroundings import SCENES_DIR

TABLE_HEIGHT = 0.75
UARM_BASE = (-0.375, 0.0, TABLE_HEIGHT)   # scene frame, m: the real uArm frame's origin (origin=0)

CUBE_COLORS: dict[str, tuple[float, float, float]] = {
    "red": (0.86, 0.12, 0.10), "green": (0.12, 0.66, 0.22),
    "blue": (0.12, 0.28, 0.86), "yellow": (0.95, 0.82, 0.10),
}


@dataclass(frozen=True)
class Layout:
    """The platform in the real uArm frame, mm (z = 0 the table top)."""

    table_x: tuple[float, float] = (-250.0, 1000.0)
    table_y: tuple[float, float] = (-550.0, 550.0)
    belt_top: float = 38.0              # a 28 mm cube on it has its centre at z = 52, the grip height
    belt_width: float = 60.0
    belt_uarm_end: float = 174.0        # x of the surface's end stops; a stopped cube rests at x >= 188.5
    belt_dobot_end: float = 674.0
    right_belt_y: float = 192.0         # conveyor-belt-2
    left_belt_y: float = -200.0         # conveyor-belt-1
    ir2_x: float = 182.0                # beam across the right belt: sees a cube whose centre is at x <= 196
    ir1_x: float = 666.0                # beam across the left belt: sees a cube whose centre is at x >= 652
    ir_height: float = 10.0             # beam above the belt surface
    color_sensor: tuple[float, float, float] = (180.0, 0.0, 30.0)  # looks up at the check point (180, 0, 60)
    drop_on_right_belt: tuple[float, float] = (640.0, 192.0)        # where getCube puts a cube
    pickup_on_left_belt: tuple[float, float] = (656.0, -200.0)      # where returnCube expects it
    warehouse_x: float = 640.0
    warehouse_slots_y: tuple[float, ...] = (100.0, 60.0, 20.0, -20.0, -60.0, -100.0)
    warehouse_floor: float = 10.0
    track_x: float = 860.0
    track_y0: float = -450.0            # l = 0; l = 900 at y = +450
    track_top: float = 40.0
    dobot_travel_z: float = 130.0       # suction cup height while carrying along the track
    cube: float = CUBE_SIZE * 1000.0


LAYOUT = Layout()
# where reset(cubes=n) sets spare cubes aside: on the table left of conveyor belt 1, real uArm frame (mm)
ASIDE_XY = [(x, y) for y in (-440.0, -490.0) for x in (380.0, 420.0, 460.0)]


class IotPlatform:
    """The scene's world and its devices (behaviour objects the mesh layer exposes).

    `origin` shifts the whole table in the world (the iot-lab places it in a room); `floor=False`
    leaves the floor to whoever builds the room around it.
    """

    name = "iot-platform"

    def __init__(self, world: World, origin: Vec = (0.0, 0.0, 0.0), layout: Layout = LAYOUT,
                 colors: dict[str, tuple[float, float, float]] = CUBE_COLORS, floor: bool = True):
        self.world, self.layout = world, layout
        self.uarm_base = np.asarray(origin, float) + UARM_BASE
        L, c, w = layout, world.client, self.w
        self.fixtures: dict[str, int] = {}  # static furniture by name (for drawing the scene)
        self._build_furniture(floor)
        half = L.cube / 2000.0
        slots = [w(L.warehouse_x, y, L.warehouse_floor) + [0, 0, half] for y in L.warehouse_slots_y]
        if len(colors) > len(slots):
            raise ValueError(f"{len(colors)} cubes do not fit the warehouse's {len(slots)} slots")
        self.cubes: list[Cube] = [make_cube(c, f"cube-{name}", rgb, slot)
                                  for (name, rgb), slot in zip(colors.items(), slots)]
        self.warehouse = Warehouse(slots, list(self.cubes))
        self.belts = {
            "conveyor-belt-1": self._belt("conveyor-belt-1", L.left_belt_y),
            "conveyor-belt-2": self._belt("conveyor-belt-2", L.right_belt_y),
        }
        ir_z = L.belt_top + L.ir_height
        reach = L.belt_width / 2 + 15.0
        self.infrared = {
            "infrared-sensor-1": InfraredSensor(world, "infrared-sensor-1", w(L.ir1_x, L.left_belt_y - reach, ir_z),
                                                w(L.ir1_x, L.left_belt_y + reach, ir_z)),
            "infrared-sensor-2": InfraredSensor(world, "infrared-sensor-2", w(L.ir2_x, L.right_belt_y + reach, ir_z),
                                                w(L.ir2_x, L.right_belt_y - reach, ir_z)),
        }
        self.color_sensor = ColorSensor(world, "color-sensor", w(*L.color_sensor))
        self.uarm = Uarm(world, self.uarm_base, lambda: [cube.body for cube in self.cubes])
        self.dobot = Dobot(world, track_start=w(L.track_x, L.track_y0, L.track_top), track_axis=(0, 1, 0),
                           yaw=math.pi, warehouse=self.warehouse,
                           drop_point=w(*L.drop_on_right_belt, L.belt_top) + [0, 0, half],
                           pickup_point=w(*L.pickup_on_left_belt, L.belt_top) + [0, 0, half],
                           cubes=lambda: self.cubes, travel_z=float(w(0, 0, L.dobot_travel_z)[2]))
        world.add_snapshot_source(self._fill)

    def w(self, x: float, y: float, z: float) -> np.ndarray:
        """Scene position (m) of a point given in the real uArm frame (mm)."""
        return self.uarm_base + np.array([x, y, z]) / 1000.0

    @property
    def devices(self) -> dict[str, Any]:
        """Thing name (SPEC §3) -> behaviour object."""
        return {"dobot": self.dobot, **self.belts, **self.infrared, "color-sensor": self.color_sensor,
                "uarm": self.uarm}

    def cube(self, name: str) -> Cube:
        return next(c for c in self.cubes if c.name == name or c.name == f"cube-{name}")

    @property
    def cube_count(self) -> int:
        return len(self.cubes)

    def robot_urdfs(self) -> dict[str, Path]:
        """Robot (Thing name) -> its URDF file; the world Thing serves it as `<robot>.urdf`."""
        return {"uarm": UARM_URDF, "dobot": DOBOT_URDF}

    def reset(self, cubes: int | None = None) -> None:
        """All cubes back in the warehouse (original order), robots home, belts stopped; with
        `cubes`, only the first that many stay in the queue and the others are set aside on the
        table, out of every device's reach.

        Running motions are cancelled (their callers get MotionCancelled); then each device's lock
        is taken so no action is half-way while the state is put back.
        """
        self.world.cancel_motions()
        with self.uarm.lock, self.dobot.lock:
            self.world.run(lambda: self._reset(cubes))

    def _reset(self, keep: int | None) -> None:  # stepping thread
        for belt in self.belts.values():
            belt.reset()
        self.uarm.reset_state()
        self.dobot.reset_state(self.cubes)
        if keep is not None:
            queue = self.warehouse.queue
            self.warehouse.queue, aside = queue[:keep], queue[keep:]
            for cube, (x, y) in zip(aside, ASIDE_XY):
                place(self.world.client, cube.body, self.w(x, y, cube.size * 500.0))
        for sensor in self.infrared.values():
            sensor.refresh()

    def describe(self) -> SceneDescription:
        """Robots, static and moving bodies as they stand now (stepping thread, or before the world starts)."""
        c = self.world.client
        named = dict(self.fixtures)
        for name, belt in self.belts.items():
            named[name] = belt.body
            for i, stop in enumerate(belt.end_stops):
                named[f"{name}-end-stop-{i + 1}"] = stop
        for name, infrared in self.infrared.items():
            named[name] = infrared.body
        named["color-sensor"] = self.color_sensor.body
        bodies: list[Body] = [box(c, name, body) for name, body in named.items()]
        bodies += [box(c, cube.name, cube.body, moving=True) for cube in self.cubes]
        robots = [RobotModel(name=robot, urdf=f"{robot}.urdf", base=pose(body_pose(c, self.devices[robot].arm.body)),
                             urdf_dir=str(path.resolve().parent))
                  for robot, path in self.robot_urdfs().items()]
        return SceneDescription(name=self.name, robots=robots, bodies=bodies)

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> "IotPlatform":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- building -------------------------------------------------------------------------------
    def _belt(self, name: str, y: float) -> Belt:
        L, w = self.layout, self.w
        return Belt(self.world, name, back_end=w(L.belt_dobot_end, y, 0), front_end=w(L.belt_uarm_end, y, 0),
                    top_z=float(w(0, 0, L.belt_top)[2]), width=L.belt_width / 1000.0,
                    base_z=float(w(0, 0, 0)[2]), stop_margin=(L.cube / 2 + 0.5) / 1000.0)

    def _build_furniture(self, with_floor: bool) -> None:
        L, c, w = self.layout, self.world.client, self.w
        floor = self.uarm_base - [0, 0, TABLE_HEIGHT]
        if with_floor:
            self.fixtures["floor"] = static_box(c, [3, 3, 0.01], floor - [0, 0, 0.01], rgba=(0.5, 0.5, 0.5, 1))
        (x0, x1), (y0, y1) = L.table_x, L.table_y
        centre = w((x0 + x1) / 2, (y0 + y1) / 2, -15)
        self.fixtures["table"] = static_box(c, [(x1 - x0) / 2000, (y1 - y0) / 2000, 0.015], centre,
                                            rgba=(0.78, 0.7, 0.58, 1))
        legs = [(sx, sy) for sx in (x0 + 40, x1 - 40) for sy in (y0 + 40, y1 - 40)]
        for i, (sx, sy) in enumerate(legs, 1):
            leg = w(sx, sy, 0)
            self.fixtures[f"table-leg-{i}"] = static_box(c, [0.025, 0.025, (TABLE_HEIGHT - 0.03) / 2],
                                                         [leg[0], leg[1], floor[2] + (TABLE_HEIGHT - 0.03) / 2],
                                                         rgba=(0.3, 0.3, 0.3, 1), collide=False)
        # warehouse tray: floor, long walls, end walls
        ys = L.warehouse_slots_y
        ymid, ylen = (max(ys) + min(ys)) / 2, max(ys) - min(ys) + L.cube + 20
        self.fixtures["warehouse"] = static_box(c, [0.025, ylen / 2000, L.warehouse_floor / 2000],
                                                w(L.warehouse_x, ymid, L.warehouse_floor / 2), rgba=(0.35, 0.4, 0.5, 1))
        for dx, side in ((-1, "front"), (1, "back")):
            self.fixtures[f"warehouse-wall-{side}"] = static_box(
                c, [0.002, ylen / 2000, 0.011], w(L.warehouse_x + dx * 25, ymid, 11), rgba=(0.35, 0.4, 0.5, 1))
        for dy, side in ((-1, "right"), (1, "left")):
            self.fixtures[f"warehouse-wall-{side}"] = static_box(
                c, [0.027, 0.002, 0.011], w(L.warehouse_x, ymid + dy * (ylen / 2 + 2), 11), rgba=(0.35, 0.4, 0.5, 1))
        # Dobot track; colour sensor post
        self.fixtures["dobot-track"] = static_box(c, [0.06, 0.5, L.track_top / 2000], w(L.track_x, 0, L.track_top / 2),
                                                  rgba=(0.2, 0.2, 0.22, 1))
        sx, sy, sz = L.color_sensor
        self.fixtures["color-sensor-post"] = static_box(c, [0.01, 0.01, (sz - 6) / 2000], w(sx, sy, (sz - 6) / 2),
                                                        rgba=(0.25, 0.25, 0.25, 1))

    def _fill(self, snap: Snapshot) -> None:
        for cube in self.cubes:
            snap.bodies[cube.name] = body_pose(self.world.client, cube.body)
        snap.bodies["uarm"] = body_pose(self.world.client, self.uarm.arm.body)


def build_platform(*, speed: float | None = 1.0, dt: float = DEFAULT_DT, snapshot_hz: float = 30.0,
                   origin: Vec = (0.0, 0.0, 0.0),
                   colors: dict[str, tuple[float, float, float]] = CUBE_COLORS, start: bool = True) -> IotPlatform:
    """A new world with the iot-platform scene in it, stepping (`start=True`) at `speed`.

    `colors` names the cubes (queue order) and gives their sRGB colour; at most 6 fit the warehouse.
    """
    world = World(dt=dt, speed=speed, snapshot_hz=snapshot_hz)
    try:
        platform = IotPlatform(world, origin, colors=colors)
    except BaseException:
        world.close()
        raise
    if start:
        world.start()
    return platform


def write_scene_json(path: Path) -> None:
    """The platform's scene as its world Thing serves it (`files/scene.json`), for `tdgen --scene`, less
    where this machine keeps the URDFs (a shipped file holds no path of the machine that wrote it)."""
    platform = build_platform(start=False)
    try:
        scene = platform.describe()
        scene.robots = [msgspec.structs.replace(r, urdf_dir=None) for r in scene.robots]
        path.write_bytes(msgspec.json.format(msgspec.json.encode(scene), indent=1) + b"\n")
    finally:
        platform.close()


if __name__ == "__main__":  # regenerate the shipped data from the model
    out = MODELS / "uarm-calibration.csv"
    write_calibration_csv(out, UARM_BASE)
    print(f"wrote {out}")
    scene = SCENES_DIR / "iot-platform.json"
    write_scene_json(scene)
    print(f"wrote {scene}")
