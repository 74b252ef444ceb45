"""The pybullet world of one scene, stepped at a fixed step by the one thread that owns the client.

pybullet is not thread-safe and device behaviours are called from RPC handler threads, so one
stepping thread owns the client: between two steps it runs the commands other threads submitted,
advances the running motions by one step of simulated time, steps the physics and runs the
sensors. Other threads wait on futures. Motions advance with simulated time: the speed factor
(1.0 = real time, N = N times faster, None = as fast as the CPU allows) changes how long they
take on the wall clock, never what they do. At speed None an idle world (no motion playing and
no activity check saying something moves, e.g. a running belt) steps in real time instead of
spinning a core; simulated physics is the same either way.

An idle world whose bodies have all been still for `REST_AFTER` simulated seconds rests: its steps go on
(simulated time, the hooks, sensors and snapshots) but the physics engine is not asked to step bodies that
do not move, most of what an idle lab costs. A motion, an activity, or a command that changes the physical
state (a body added, removed or moved, a joint set: compared before and after it) wakes it at once; a
command that only reads, or changes what has no physics (a lamp's colour), leaves it resting.

Callbacks for the outside (sensor events, pose snapshots for a recorder) run on a separate
notifier thread, in order, so a slow subscriber never stalls the physics.
"""
from __future__ import annotations

import functools
import logging
import queue
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, TypeVar

import numpy as np
import pybullet as pb

from devices.sim.vec import Vec
from mesh.wot.invocation import ActionCancelled, current_cancellation
from mesh.wot.problem import Unavailable

MIN_SPEED, MAX_SPEED = 0.01, 1000.0  # sane simulation speed factors: slower freezes a lab, faster is `max`


def parse_speed(value: str) -> float | None:
    """A simulation speed factor from the command line: a positive number, or 'max' (None)."""
    if value == "max":
        return None
    try:
        f = float(value)
    except ValueError:
        raise ValueError(f"speed must be a positive number or 'max', not {value!r}") from None
    if not MIN_SPEED <= f <= MAX_SPEED:
        raise ValueError(f"speed must be within {MIN_SPEED:g}..{MAX_SPEED:g}, or 'max', not {value!r}")
    return f


log = logging.getLogger(__name__)

T = TypeVar("T")
Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Pose = tuple[Vec3, Quat]
Hook = Callable[[float], None]

DEFAULT_DT = 1.0 / 240.0
MAX_LAG = 0.25  # s of wall time; a world further behind real time stops trying to catch up
REST_AFTER = 0.5  # s of simulated time with every body still before an idle world rests (`_still`)
REST_CHECK = 0.1  # s of simulated time between two looks at the bodies' velocities
STILL_LINEAR, STILL_ANGULAR = 1e-3, 1e-2  # m/s and rad/s (bodies and joints): below these a body is still
REST_BATCH = 0.025  # s of wall time a resting world's steps are run together in, rather than one wake-up each
PEAK_SPEED = 1.5  # an Interpolation's top speed over its mean speed (smoothstep)


class WorldClosed(Unavailable):
    slug, title = "world-closed", "Simulation not running"


class MotionCancelled(Unavailable):
    """A motion was interrupted (the scene was reset); the device did not finish its action."""

    slug, title = "motion-cancelled", "Motion cancelled"


@dataclass
class Snapshot:
    """Poses of what moves, at one instant of simulated time (for a recorder).

    joints: robot -> joint -> value (rad or m); bodies: name -> world pose ((x,y,z), (qx,qy,qz,qw));
    states: device -> small state (belt direction and speed, sensor readings...).
    """

    time: float
    joints: dict[str, dict[str, float]] = field(default_factory=dict)
    bodies: dict[str, Pose] = field(default_factory=dict)
    states: dict[str, dict[str, Any]] = field(default_factory=dict)


class Motion(Protocol):
    def advance(self, dt: float) -> bool:
        """Apply the state `dt` later (stepping thread); True once the motion is over."""


class Interpolation:
    """Values from `start` (read when the motion begins) to `goal` over `duration` s, eased in and out."""

    def __init__(self, start: Callable[[], np.ndarray], goal: Vec, duration: float,
                 apply: Callable[[np.ndarray], None]):
        self._start_fn, self.goal, self.duration, self._apply = start, np.asarray(goal, float), duration, apply
        self._start: np.ndarray | None = None
        self._t = 0.0

    def advance(self, dt: float) -> bool:
        if self._start is None:
            self._start = np.asarray(self._start_fn(), float)
        self._t += dt
        u = 1.0 if self.duration <= 0 else min(self._t / self.duration, 1.0)
        s = u * u * (3.0 - 2.0 * u)  # smoothstep: zero velocity at both ends
        self._apply(self._start + (self.goal - self._start) * s)
        return u >= 1.0


class PathMotion:
    """Through joint-space waypoints, each segment eased in and out (smoothstep: it stops at every
    waypoint, so it never leaves the straight segments a planner checked), in the durations given.
    `stop()` halts it where it is at the next step; `stopped` then says so."""

    def __init__(self, waypoints: np.ndarray, durations: Vec, apply: Callable[[np.ndarray], None]):
        self.waypoints, self.durations, self._apply = np.asarray(waypoints, float), list(durations), apply
        self._segment, self._t = 0, 0.0
        self.stopped = False
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    def advance(self, dt: float) -> bool:
        if self._stop.is_set():
            self.stopped = True
            return True
        self._t += dt
        while self._segment < len(self.durations):
            d = self.durations[self._segment]
            if self._t < d:
                u = self._t / d
                a, b = self.waypoints[self._segment], self.waypoints[self._segment + 1]
                self._apply(a + (b - a) * (u * u * (3.0 - 2.0 * u)))
                return False
            self._t -= d
            self._segment += 1
        self._apply(self.waypoints[-1])
        return True


class Delay:
    """Nothing happens for `duration` simulated seconds (lets a caller wait on simulated time)."""

    def __init__(self, duration: float):
        self._left = duration

    def advance(self, dt: float) -> bool:
        self._left -= dt
        return self._left <= 1e-12


class World:
    """One pybullet world (DIRECT) and its stepping thread. Build the scene, then `start()`.

    Before `start()` the caller may use `client` directly (scene building); afterwards only
    through `submit`/`run`/`play`, which are safe from any thread.
    """

    def __init__(self, *, dt: float = DEFAULT_DT, speed: float | str | None = 1.0, gravity: float = -9.81,
                 snapshot_hz: float = 30.0):
        self.dt = dt
        self.speed = speed
        self.snapshot_period = 1.0 / snapshot_hz if snapshot_hz > 0 else float("inf")
        self.client = pb.connect(pb.DIRECT)
        pb.setGravity(0, 0, gravity, physicsClientId=self.client)
        pb.setPhysicsEngineParameter(fixedTimeStep=dt, physicsClientId=self.client)
        self.held: set[int] = set()  # bodies attached to a robot: belts leave them alone
        self._time = 0.0
        self._steps = 0
        self.physics_steps = 0  # the steps the physics engine stepped (not while resting)
        self.rest = True  # may an idle world rest (False: the physics steps as long as the world does)
        self._resting: tuple | None = None  # the physical state it rests in (`_physical_state`), or None
        self._still_for = 0.0  # s of simulated time every body has been still, looked at every REST_CHECK
        self._next_check = 0.0
        self._commands: queue.SimpleQueue[tuple[Callable[[], Any], Future]] = queue.SimpleQueue()
        self._wake = threading.Event()
        self._motions: list[tuple[Motion, Future]] = []
        self._pre: list[Hook] = []
        self._post: list[Hook] = []
        self._post_physics: list[Hook] = []
        self._activity: list[Callable[[], bool]] = []
        self._sources: list[Callable[[Snapshot], None]] = []
        self._subscribers: list[Callable[[Snapshot], None]] = []
        self._next_snapshot = 0.0
        self._notes: queue.SimpleQueue[tuple[Callable[..., None], tuple] | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._notifier: threading.Thread | None = None
        self._setup_lock = threading.RLock()
        self._queue_lock = threading.Lock()  # no command slips in after the queue was drained
        self._stop = False
        self._closed = False
        self._death_hooks: list[Callable[[], None]] = []

    @property
    def speed(self) -> float | None:
        """Simulated seconds per wall second; None = as fast as possible. May change while running."""
        return self._speed

    @speed.setter
    def speed(self, value: float | str | None) -> None:
        if value == "max":
            value = None
        if value is not None and not (isinstance(value, (int, float)) and not isinstance(value, bool)
                                      and MIN_SPEED <= value <= MAX_SPEED):
            raise ValueError(f"speed must be within {MIN_SPEED:g}..{MAX_SPEED:g}, or None / 'max' for as fast as "
                             f"possible; got {value!r}")
        self._speed = None if value is None else float(value)

    @property
    def stepping(self) -> bool:
        """Whether the simulation steps (its thread runs): a health check for the world's Thing."""
        return self._thread is not None and self._thread.is_alive() and not self._stop

    def on_death(self, hook: Callable[[], None]) -> None:
        """`hook()` if the stepping thread ever dies (on that thread): e.g. end the process so that the
        supervisor sees it, rather than a process that answers 503 forever."""
        self._death_hooks.append(hook)

    # --- lifecycle ----------------------------------------------------------------------------
    def start(self) -> "World":
        if self._thread is None:
            self._notifier = threading.Thread(target=self._notify_loop, name="world-notify", daemon=True)
            self._notifier.start()
            self._thread = threading.Thread(target=self._loop, name="world-step", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop stepping, fail what is pending, disconnect. Idempotent."""
        if self._closed:
            return
        self._closed = True
        with self._queue_lock:
            self._stop = True
        self._wake.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=10)
        self._fail_pending(WorldClosed("the simulation was shut down"))
        if self._notifier is not None:
            self._notes.put(None)
            if self._notifier is not threading.current_thread():
                self._notifier.join(timeout=5)
        try:
            pb.disconnect(physicsClientId=self.client)
        except pb.error:
            pass

    def __enter__(self) -> "World":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def time(self) -> float:
        """Simulated seconds since the world was created."""
        return self._time

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def resting(self) -> bool:
        """Whether the physics engine is left alone (an idle world whose bodies are all still)."""
        return self._resting is not None

    @property
    def running(self) -> bool:
        return self._thread is not None and not self._stop

    def on_stepping_thread(self) -> bool:
        return threading.current_thread() is self._thread

    # --- talking to the stepping thread -----------------------------------------------------
    def submit(self, fn: Callable[[], T]) -> "Future[T]":
        """Run `fn()` on the stepping thread between two steps; its result or exception in the future."""
        fut: Future = Future()
        if self._thread is None or self.on_stepping_thread():
            if self._closed:
                fut.set_exception(WorldClosed("the simulation was shut down"))
            else:
                with self._setup_lock:  # not started yet (scene building) or re-entrant: run here
                    _settle(fut, fn)
            return fut
        with self._queue_lock:
            if self._stop:
                fut.set_exception(WorldClosed("the simulation is not running"))
            else:
                self._commands.put((fn, fut))
        self._wake.set()
        return fut

    def run(self, fn: Callable[[], T], timeout: float | None = None) -> T:
        """`submit` and wait for the result."""
        return self.submit(fn).result(timeout)

    def play(self, motion: Motion) -> Future:
        """Start a motion; the future completes when it is over (in simulated time).

        Played for an asynchronous invocation (`mesh.wot.invocation`), the motion stops where it
        is when the invocation is cancelled: its future fails with ActionCancelled."""
        fut: Future = Future()

        def add() -> None:
            if fut.set_running_or_notify_cancel():  # from now on the caller cannot cancel it
                self._motions.append((motion, fut))

        token = current_cancellation()
        if token is not None:
            forget = token.on_cancel(functools.partial(self._cancel_soon, motion, fut))
            fut.add_done_callback(lambda _: forget())
        started = self.submit(add)
        if started.done() and started.exception() is not None:
            fut.set_exception(started.exception())
        elif self._thread is None:  # not started: nothing steps it, so finish it now
            while not fut.done():
                self._advance_motions(self.dt)
        return fut

    def wait(self, seconds: float) -> None:
        """Block until `seconds` of simulated time have passed."""
        self.play(Delay(seconds)).result()

    def _cancel_soon(self, motion: Motion, fut: Future) -> None:  # the cancelling thread: never block
        self.submit(lambda: self._cancel(motion, fut))

    def _cancel(self, motion: Motion, fut: Future) -> None:  # stepping thread
        self._motions = [(m, f) for m, f in self._motions if f is not fut]
        if not fut.done():
            fut.set_exception(ActionCancelled("the action was cancelled; the motion stopped where it was"))

    def cancel_motions(self, reason: str = "the scene was reset") -> None:
        """Fail every running motion with MotionCancelled (their callers get the error)."""
        def cancel() -> None:
            motions, self._motions = self._motions, []
            for _, fut in motions:
                fut.set_exception(MotionCancelled(reason))
        self.run(cancel)

    def add_pre_step(self, hook: Hook) -> None:
        """`hook(dt)` on the stepping thread before every physics step (belts set velocities here)."""
        self._pre.append(hook)

    def add_post_step(self, hook: Hook, physics: bool = False) -> None:
        """`hook(dt)` on the stepping thread after every step (sensors look here); `physics`: only after the
        steps the physics engine stepped (what puts bodies back after gravity moved them: nothing to do while
        the world rests)."""
        (self._post_physics if physics else self._post).append(hook)

    def add_activity(self, active: Callable[[], bool]) -> None:
        """`active()` (stepping thread) says whether something moves besides the motions (a running belt)."""
        self._activity.append(active)

    def idle(self) -> bool:
        """Nothing moves: no motion playing, no activity check true (stepping thread)."""
        return not self._motions and not any(active() for active in self._activity)

    def notify(self, fn: Callable[..., None], *args: Any) -> None:
        """Call `fn(*args)` on the notifier thread (for callbacks that leave the simulation)."""
        if self._notifier is None:
            _call_logged(fn, args)
        elif not self._closed:
            self._notes.put((fn, args))

    # --- snapshots --------------------------------------------------------------------------
    def add_snapshot_source(self, fill: Callable[[Snapshot], None]) -> None:
        """`fill(snapshot)` adds what one device knows (stepping thread, so it may use pybullet)."""
        self._sources.append(fill)

    def on_snapshot(self, callback: Callable[[Snapshot], None]) -> Callable[[], None]:
        """`callback(snapshot)` every `1/snapshot_hz` simulated seconds, on the notifier thread.

        Returns a function that unsubscribes.
        """
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback) if callback in self._subscribers else None

    def snapshot(self) -> Snapshot:
        """A snapshot now (from any thread)."""
        return self.run(self._take_snapshot)

    def _take_snapshot(self) -> Snapshot:
        snap = Snapshot(time=self._time)
        for fill in self._sources:
            fill(snap)
        return snap

    # --- the stepping thread ----------------------------------------------------------------
    def _loop(self) -> None:
        next_wall = time.monotonic()
        try:
            while not self._stop:
                self._run_commands()
                idle = self.idle()
                self._settle(idle)
                self._step()
                speed = self._speed
                if speed is None and not idle:
                    time.sleep(0)  # let waiting threads have the GIL between steps
                    next_wall = time.monotonic()
                    continue
                next_wall += self.dt / (speed or 1.0)  # an idle world at speed None: real time
                now = time.monotonic()
                if now - next_wall > MAX_LAG:
                    next_wall = now
                # resting, the steps of REST_BATCH run together: one wake-up for them, not one each
                until = next_wall + (REST_BATCH if self._resting is not None else 0.0)
                while not self._stop and (left := until - time.monotonic()) > 0:
                    if self._wake.wait(min(left, 0.25)):  # short waits: no timeout ever overflows
                        self._wake.clear()
                        self._run_commands()
                        moving = not self.idle()
                        if self._resting is None or moving:
                            until = min(until, next_wall)  # woken, or a motion added: one step at a time again
                        if self._speed is None and moving:
                            break  # a motion started: full speed from now on
        except BaseException as exc:  # a broken world must not leave callers waiting forever
            log.exception("stepping thread died")
            with self._queue_lock:
                self._stop = True
            self._fail_pending(WorldClosed(f"the simulation stopped: {exc}"))
            for hook in self._death_hooks:
                _call_logged(hook, ())

    def _run_commands(self) -> None:
        ran = False
        while True:
            try:
                fn, fut = self._commands.get_nowait()
            except queue.Empty:
                break
            if fut.set_running_or_notify_cancel():
                _settle(fut, fn)
                ran = True
        if ran and self._resting is not None and self._physical_state() != self._resting:
            self._wake_physics()

    # --- resting ------------------------------------------------------------------------------
    def _settle(self, idle: bool) -> None:
        """Rest once an idle world's bodies have been still for REST_AFTER; wake when it is idle no more."""
        if not idle or not self.rest:
            if self._resting is not None or self._still_for:
                self._wake_physics()
            return
        if self._resting is not None or self._time + 1e-9 < self._next_check:
            return
        self._next_check = self._time + REST_CHECK
        state = self._physical_state()
        self._still_for = self._still_for + REST_CHECK if _still(state) else 0.0
        if self._still_for + 1e-9 >= REST_AFTER:
            self._resting = state

    def _wake_physics(self) -> None:
        self._resting, self._still_for = None, 0.0
        self._next_check = self._time + REST_CHECK

    def _physical_state(self) -> tuple:
        """Per body: its id, pose, velocity (linear, angular) and its joints' (position, velocity): what a
        command that changes the physics changes, and what says whether anything moves (`_still`)."""
        c = self.client
        state = []
        for i in range(pb.getNumBodies(physicsClientId=c)):
            body = pb.getBodyUniqueId(i, physicsClientId=c)
            joints = pb.getNumJoints(body, physicsClientId=c)
            state.append((body, pb.getBasePositionAndOrientation(body, physicsClientId=c),
                          pb.getBaseVelocity(body, physicsClientId=c),
                          tuple(j[:2] for j in pb.getJointStates(body, range(joints), physicsClientId=c))
                          if joints else ()))
        return tuple(state)

    def _step(self) -> None:
        dt = self.dt
        self._advance_motions(dt)
        for hook in self._pre:
            hook(dt)
        if self._resting is None:
            pb.stepSimulation(physicsClientId=self.client)
            self.physics_steps += 1
            for hook in self._post_physics:
                hook(dt)
        self._time += dt
        self._steps += 1
        for hook in self._post:
            hook(dt)
        if self._subscribers and self._time + 1e-9 >= self._next_snapshot:
            self._next_snapshot = self._time + self.snapshot_period
            snap = self._take_snapshot()
            for cb in list(self._subscribers):
                self.notify(cb, snap)

    def _advance_motions(self, dt: float) -> None:
        if not self._motions:
            return
        keep = []
        for motion, fut in self._motions:
            try:
                done = motion.advance(dt)
            except Exception as exc:
                fut.set_exception(exc)
                continue
            if done:
                fut.set_result(None)
            else:
                keep.append((motion, fut))
        self._motions = keep

    def _fail_pending(self, exc: Exception) -> None:
        motions, self._motions = self._motions, []
        for _, fut in motions:
            if not fut.done():
                fut.set_exception(exc)
        while True:
            try:
                _, fut = self._commands.get_nowait()
            except queue.Empty:
                break
            if not fut.done():
                fut.set_exception(exc)

    def _notify_loop(self) -> None:
        while (item := self._notes.get()) is not None:
            _call_logged(*item)


def _still(state: tuple) -> bool:
    """Every body and joint of a `World._physical_state` moves slower than STILL_LINEAR / STILL_ANGULAR."""
    for _, _, (linear, angular), joints in state:
        if max(map(abs, linear)) > STILL_LINEAR or max(map(abs, angular)) > STILL_ANGULAR:
            return False
        if any(abs(velocity) > STILL_ANGULAR for _, velocity in joints):
            return False
    return True


def _settle(fut: Future, fn: Callable[[], Any]) -> None:
    try:
        fut.set_result(fn())
    except BaseException as exc:  # the caller gets it, the stepping thread goes on
        fut.set_exception(exc)


def _call_logged(fn: Callable[..., None], args: tuple) -> None:
    try:
        fn(*args)
    except Exception:
        log.exception("callback %r failed", fn)


# --- pybullet helpers shared by the devices ---------------------------------------------------
def attach(client: int, body: int, link: int, child: int, max_force: float = 50.0) -> int:
    """A fixed constraint holding `child` where it is now, relative to `body`'s `link`."""
    if link >= 0:
        state = pb.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=client)
        ppos, porn = state[0], state[1]  # centre-of-mass frame, as createConstraint expects
    else:
        ppos, porn = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    cpos, corn = pb.getBasePositionAndOrientation(child, physicsClientId=client)
    ipos, iorn = pb.invertTransform(ppos, porn)
    rpos, rorn = pb.multiplyTransforms(ipos, iorn, cpos, corn)
    cid = pb.createConstraint(body, link, child, -1, pb.JOINT_FIXED, [0, 0, 0], rpos, [0, 0, 0],
                              parentFrameOrientation=rorn, physicsClientId=client)
    pb.changeConstraint(cid, maxForce=max_force, physicsClientId=client)
    return cid


def static_box(client: int, half: Vec, pos: Vec, orn: Vec = (0, 0, 0, 1),
               rgba: Vec = (0.6, 0.6, 0.6, 1), collide: bool = True) -> int:
    """A static box (mass 0), the building block of tables, belts and trays."""
    col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=list(half), physicsClientId=client) if collide else -1
    vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=list(half), rgbaColor=list(rgba), physicsClientId=client)
    return pb.createMultiBody(0, col, vis, list(pos), list(orn), physicsClientId=client)


def body_pose(client: int, body: int) -> Pose:
    pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    return tuple(pos), tuple(orn)


def place(client: int, body: int, pos: Vec, orn: Vec = (0, 0, 0, 1)) -> None:
    """Teleport a body and stop it."""
    pb.resetBasePositionAndOrientation(body, list(pos), list(orn), physicsClientId=client)
    pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=client)
