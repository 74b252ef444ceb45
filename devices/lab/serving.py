"""Lab assembly for guarded devices: the platform's devices served each on its own session, those with a
real device behind their twin (`devices.things.guard`), and a guarded robot; each real device also on the
mesh as `<slug>-real`."""
from __future__ import annotations

import threading
from contextlib import ExitStack
from typing import TYPE_CHECKING

from devices.sim.dobot import Dobot
from devices.sim.layouts.platform_layout import IotPlatform
from devices.sim.uarm import Uarm
from devices.things.binding import serve
from devices.things.guard import Frame, Guard, RealDevice, RobotMirror, UarmMirror, dobot_guard, robot_guard, uarm_guard
from devices.things.platform_things import PLATFORM_DEVICES, bind_device, platform_thing, twin_td
from mesh.bridge.bridged import BridgedThing
from mesh.bridge.remote import RemoteThing
from mesh.bridge.run import Access
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from mesh.http.http_client import HttpClient

if TYPE_CHECKING:  # the platform's process has no robot: it need not load the robot Thing's code (numba)
    from devices.things.robot_thing import RobotThing


def guard_robot(stack: ExitStack, settings: MeshSettings, robot: RobotThing, device: RealDevice, access: Access,
                stopping: threading.Event) -> None:
    """Put the real robot `device` behind the robot Thing `robot` (before it is exposed), mirror it, and
    serve it on the mesh as `<name>-real`."""
    client = access.client()
    stack.callback(client.close)
    remote = RemoteThing(device.td, client, device.url)
    guard = robot_guard(robot, remote)
    guard.install(set(robot.thing.td.actions))
    RobotMirror(robot.twin, remote, guard, stopping).start()
    session = stack.enter_context(open_session(settings, thing=f"{device.slug}-real"))
    stack.enter_context(BridgedThing(session, f"{device.slug}-real", remote, device.td, settings.keys))


def serve_platform(stack: ExitStack, settings: MeshSettings, platform: IotPlatform, real: list[RealDevice],
                   access: Access | None,
                   stopping: threading.Event) -> None:
    """Expose every device of `platform` on its own session (entered on `stack`); those in `real` guarded,
    each with its real device also on the mesh as `<slug>-real` (the recorder, the live view and the
    control page show real and twin side by side)."""
    guarded = {r.slug: r for r in real if r.slug in PLATFORM_DEVICES}
    client = access.client() if guarded and access is not None else HttpClient()
    stack.callback(client.close)
    for slug in PLATFORM_DEVICES:
        session = stack.enter_context(open_session(settings, thing=slug))
        device = guarded.get(slug)
        thing = platform_thing(session, slug, settings.keys, real_td=None if device is None else device.td)
        cleanup = bind_device(thing, platform.devices[slug])
        if device is not None:
            remote = RemoteThing(device.td, client, device.url)
            twin = platform.devices[slug]
            frame = Frame(device.calibration)
            if isinstance(twin, Uarm):
                guard = uarm_guard(thing, remote, twin, frame)
                UarmMirror(twin, remote, guard, frame, stopping).start()
            elif isinstance(twin, Dobot):
                guard = dobot_guard(thing, remote, twin)
            else:
                guard = Guard(thing, remote, {})
            guard.install(set(twin_td(slug).actions))
            real_session = stack.enter_context(open_session(settings, thing=f"{slug}-real"))
            stack.enter_context(BridgedThing(real_session, f"{slug}-real", remote, device.td, settings.keys))
        serve(stack, thing, cleanup)
