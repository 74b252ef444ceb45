"""A fleet's devices without a physics world: a belt with its beam and colour sensor, and a climate sensor.

A *station* is what a belt of the iot-platform is with its sensors, reduced to what a client can
observe: a belt carries parcels (30 mm long, one every 150 mm, colours in turn) past an infrared
beam and a colour sensor while it runs, as fast as its `speed` says (the lab's mapping: 100 % =
60 mm/s); the beam reports presence and its changes, the colour sensor what lies under it. A
*climate* sensor drifts around 21 °C and 45 % with noise and publishes a reading every `interval`
seconds. The models offer the interfaces of `devices.sim.belt.Belt` and `devices.sim.sensors`,
so the lab's bindings serve them and a fleet's devices answer as the lab's do.

One `Ticker` thread per process drives every model (no thread per device): it advances the
running belts every `TICK` seconds and calls what is due.
"""
from __future__ import annotations

import heapq
import itertools
import random
import threading
import time
from typing import Callable

from devices.sim.belt_rules import DEFAULT_SPEED, MAX_SPEED_MM_S, STARTED, STOPPED, belt_speed
from devices.sim.colour_reading import NO_OBJECT, ColorReading, reading_of
from devices.sim.listeners import Listeners
from mesh.wot.problem import BadInput

TICK = 0.05  # s between two advances of the running belts
PARCEL_MM, SPACING_MM = 30.0, 150.0
PARCEL_COLOURS = ((0.8, 0.1, 0.1), (0.1, 0.6, 0.2), (0.1, 0.2, 0.8), (0.9, 0.8, 0.1))


class Ticker:
    """One thread that calls `every(period, fn)` functions when due, and `tick(dt)` functions each TICK."""

    def __init__(self) -> None:
        self._ticking: list[Callable[[float], None]] = []
        self._due: list[tuple[float, int, float, Callable[[], float | None]]] = []
        self._order = itertools.count()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fleet-ticker", daemon=True)

    def on_tick(self, fn: Callable[[float], None]) -> None:
        with self._lock:
            self._ticking.append(fn)

    def every(self, period: float, fn: Callable[[], float | None], first: float | None = None) -> None:
        """Call `fn()` every `period` s (first after `first` s); a number it returns is the next period."""
        with self._lock:
            heapq.heappush(self._due, (time.monotonic() + (period if first is None else first),
                                       next(self._order), period, fn))

    def start(self) -> "Ticker":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(TICK):
            now = time.monotonic()
            dt, last = now - last, now
            with self._lock:
                ticking = list(self._ticking)
                due = []
                while self._due and self._due[0][0] <= now:
                    due.append(heapq.heappop(self._due))
            for fn in ticking:
                fn(dt)
            for _, order, period, call in due:
                try:
                    nxt = call()
                except Exception:  # a failing device must not stop the others' clocks
                    nxt = None
                period = nxt if isinstance(nxt, (int, float)) and nxt > 0 else period
                with self._lock:
                    heapq.heappush(self._due, (now + period, order, period, call))


class Station:
    """A belt (`start_forward`, `start_backward`, `stop`, `speed`), its beam and its colour sensor."""

    def __init__(self, name: str, ticker: Ticker, offset_mm: float = 0.0):
        self.name = name
        self._direction = 0
        self._speed = DEFAULT_SPEED
        self._position = offset_mm % SPACING_MM  # of the parcel train, relative to the beam
        self._presence = False
        self._parcel = 0  # the parcel at (or last at) the beam: its colour
        self._listeners: Listeners[bool] = Listeners()
        self.belt = self  # the interfaces the lab's bindings expect
        self.infrared = _Beam(self)
        self.color_sensor = _Colour(self)
        ticker.on_tick(self._advance)

    # --- the belt -------------------------------------------------------------------------------
    def start_forward(self) -> str:
        self._direction = 1
        return STARTED

    def start_backward(self) -> str:
        self._direction = -1
        return STARTED

    def stop(self) -> str:
        self._direction = 0
        return STOPPED

    @property
    def speed(self) -> int:
        return self._speed

    @speed.setter
    def speed(self, value: int) -> None:
        self._speed = belt_speed(self.name, value)

    @property
    def running(self) -> bool:
        return self._direction != 0

    # --- what moves -----------------------------------------------------------------------------
    def _advance(self, dt: float) -> None:  # ticker thread
        if not self._direction:
            return
        self._position += self._direction * self._speed / 100 * MAX_SPEED_MM_S * dt
        present = self._position % SPACING_MM < PARCEL_MM
        if present:
            self._parcel = int(self._position // SPACING_MM)
        if present != self._presence:
            self._presence = present
            for cb in self._listeners.now():
                cb(present)

    def reading(self) -> ColorReading:
        if not self._presence:
            return NO_OBJECT
        return reading_of(PARCEL_COLOURS[self._parcel % len(PARCEL_COLOURS)])


class _Beam:
    """The station's light barrier, as `devices.sim.sensors.InfraredSensor` offers it."""

    def __init__(self, station: Station):
        self._station = station

    @property
    def object_presence(self) -> bool:
        return self._station._presence

    def on_change(self, callback: Callable[[bool], None]) -> Callable[[], None]:
        return self._station._listeners.add(callback)


class _Colour:
    """The station's colour sensor, as `devices.sim.sensors.ColorSensor` offers it."""

    def __init__(self, station: Station):
        self._station = station

    @property
    def color(self) -> list[int]:
        return self._station.reading().color

    @property
    def lux(self) -> float:
        return self._station.reading().lux

    @property
    def temperature(self) -> float:
        return self._station.reading().temperature


MIN_INTERVAL, MAX_INTERVAL = 0.1, 3600.0


class Climate:
    """A temperature (°C) and relative humidity (%) sensor: a slow random walk plus noise, published every
    `interval` seconds to `on_reading(temperature, humidity)`."""

    def __init__(self, name: str, ticker: Ticker, on_reading: Callable[[float, float], None],
                 seed: int | None = None, interval: float = 1.0):
        self.name = name
        self._random = random.Random(seed)
        self._base_t = 21.0 + self._random.uniform(-2, 2)
        self._base_h = 45.0 + self._random.uniform(-8, 8)
        self._interval = interval
        self._on_reading = on_reading
        self.temperature, self.humidity = self._sample()
        ticker.every(interval, self._publish, first=self._random.uniform(0, interval))  # spread over the second

    @property
    def interval(self) -> float:
        return self._interval

    @interval.setter
    def interval(self, value: float) -> None:
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not MIN_INTERVAL <= value <= MAX_INTERVAL:
            raise BadInput(f"{self.name}: interval must be a number of seconds from {MIN_INTERVAL:g} to "
                           f"{MAX_INTERVAL:g}, got {value!r}")
        self._interval = float(value)

    def _sample(self) -> tuple[float, float]:
        r = self._random
        self._base_t = min(max(self._base_t + r.gauss(0, 0.02), 15.0), 30.0)
        self._base_h = min(max(self._base_h + r.gauss(0, 0.1), 20.0), 80.0)
        return round(self._base_t + r.gauss(0, 0.05), 2), round(self._base_h + r.gauss(0, 0.3), 1)

    def _publish(self) -> float:  # ticker thread
        self.temperature, self.humidity = self._sample()
        self._on_reading(self.temperature, self.humidity)
        return self._interval
