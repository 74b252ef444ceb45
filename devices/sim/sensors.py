"""Infrared sensors (`infrared-sensor-1`, `-2`) and the colour sensor (`color-sensor`), as ray tests.

Rays ignore the robots (their links are in no collision group), so a gripper passing through a
beam is not an object; a cube it holds is.

Colour sensor readings are derived from the visual colour of what the ray hits, like the lab's
TCS34725 with its white LED: `color` = the surface RGB scaled to 0..255 ([0,0,0] when nothing is
in range), `lux` = 100 + 13900 * relative luminance (100 when nothing is there), `temperature` =
the correlated colour temperature of that RGB (McCamy's formula on sRGB -> CIE xy), clamped to
the sensor's 1000..20000 K (6500 K, the LED itself, when nothing is there).
"""
from __future__ import annotations

from typing import Callable

import pybullet as pb

from devices.sim.colour_reading import NO_OBJECT, ColorReading, reading_of
from devices.sim.listeners import Listeners
from devices.sim.pybullet_world import Snapshot, World, static_box
from devices.sim.vec import Vec

__all__ = ["NO_OBJECT", "ColorReading", "ColorSensor", "InfraredSensor", "reading_of"]

RAY_MASK = 1  # pybullet's default collision group; robot links are in none


class InfraredSensor:
    """`object_presence` (bool) of a light barrier, with callbacks on every change (`detectedObject`).

    An object is present as soon as it cuts the beam, and gone once the beam has stayed clear for
    `release` seconds: a cube resting right at the beam's edge (the belt stops the moment it is
    seen) must not flicker when a gripper takes hold of it.
    """

    def __init__(self, world: World, name: str, ray_from: Vec, ray_to: Vec,
                 release: float = 0.1):
        self.world, self.name = world, name
        self.ray_from, self.ray_to = list(ray_from), list(ray_to)
        self.release = release
        self._clear_for = 0.0
        self._presence = False
        self._listeners: Listeners[bool] = Listeners()
        self.body = static_box(world.client, [0.008, 0.008, 0.012],
                               [ray_from[0], ray_from[1], ray_from[2]], rgba=(0.1, 0.1, 0.1, 1), collide=False)
        world.add_post_step(self._sense)
        world.add_snapshot_source(self._fill)

    @property
    def object_presence(self) -> bool:
        return self._presence

    def on_change(self, callback: Callable[[bool], None]) -> Callable[[], None]:
        """`callback(presence)` on the world's notifier thread at each change; returns an unsubscribe."""
        return self._listeners.add(callback)

    def refresh(self) -> None:
        """Take the beam's state at once, without waiting out `release` (after a scene reset; stepping thread)."""
        self._sense(None)

    def _sense(self, dt: float | None) -> None:
        hit = pb.rayTest(self.ray_from, self.ray_to, collisionFilterMask=RAY_MASK,
                         physicsClientId=self.world.client)[0][0] >= 0
        self._clear_for = 0.0 if hit else self._clear_for + (dt if dt is not None else self.release)
        present = hit or (self._presence and self._clear_for < self.release)
        if present != self._presence:
            self._presence = present
            for cb in self._listeners.now():
                self.world.notify(cb, present)

    def _fill(self, snap: Snapshot) -> None:
        snap.states[self.name] = {"objectPresence": self._presence}


class ColorSensor:
    """Looks along a short ray (up, from below the check point) and reports what it sees."""

    def __init__(self, world: World, name: str, origin: Vec, reach: float = 0.035):
        self.world, self.name = world, name
        self.ray_from = [origin[0], origin[1], origin[2] + 0.001]
        self.ray_to = [origin[0], origin[1], origin[2] + reach]
        self._rgb: dict[int, tuple[float, float, float] | None] = {}
        self.body = static_box(world.client, [0.012, 0.012, 0.003], [origin[0], origin[1], origin[2] - 0.003],
                               rgba=(0.2, 0.45, 0.25, 1), collide=False)  # the sensor board
        world.add_snapshot_source(self._fill)

    @property
    def color(self) -> list[int]:
        return self.read().color

    @property
    def lux(self) -> float:
        return self.read().lux

    @property
    def temperature(self) -> float:
        return self.read().temperature

    def read(self) -> ColorReading:
        """All three values from one look (from any thread)."""
        return self.world.run(self._read)

    def _read(self) -> ColorReading:
        c = self.world.client
        body = pb.rayTest(self.ray_from, self.ray_to, collisionFilterMask=RAY_MASK, physicsClientId=c)[0][0]
        if body < 0:
            return NO_OBJECT
        if body not in self._rgb:
            shapes = pb.getVisualShapeData(body, physicsClientId=c)
            self._rgb[body] = tuple(shapes[0][7][:3]) if shapes else None
        rgb = self._rgb[body]
        return NO_OBJECT if rgb is None else reading_of(rgb)

    def _fill(self, snap: Snapshot) -> None:
        r = self._read()
        snap.states[self.name] = {"color": r.color, "lux": r.lux, "temperature": r.temperature}
