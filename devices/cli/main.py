"""The `twinmesh` command: the one composition root (it alone may import devices and tdgen)."""
from __future__ import annotations

import json
import logging
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import click
import msgspec

from devices.lab import entries
from devices.lab.supervisor import ProcessSpec, Supervisor, die_with_parent, follows_its_starter
from mesh.cli import commands, completion, replay
from mesh.cli.commands import AUTH_HELP, checked_auth, echo_json, host_port, parse_json
from mesh.cli.consumers import mesh_client
from mesh.cli.exits import UNREACHABLE, CommandFailed, usage_exit
from mesh.cli.native_output import quiet_pybullet_import, separate_native_stdout
from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.settings import DEFAULT_ENDPOINT, MeshSettings, router_listen
from mesh.messages.scene_description import DEFAULT_SAMPLES
from mesh.process import SHOW_NATIVE, set_title
from mesh.wot.problem import Problem
from tdgen.cli.counts import SampleCount

if TYPE_CHECKING:
    from devices.lab.scenes import Scene


class LazyGroup(click.Group):
    """Loads heavy subcommands (pybullet, trimesh) only when they are used: `twinmesh read` stays fast."""

    lazy: dict[str, Callable[[], click.Command]] = {
        "tdgen": lambda: _tdgen_cli().tdgen_command,
        "check": lambda: _tdgen_cli().check_command,
        "ik": lambda: _ik_cli().ik_command,
        "workflow": lambda: _workflow_cli().workflow_command,
        "robot": lambda: _robot_cli().robot_command,
        "eval": lambda: _eval_cli().eval_command,
        "scene": lambda: _scene_cli().scene_group,
    }

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted([*super().list_commands(ctx), *self.lazy])

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        cmd = self.lazy[name]() if name in self.lazy else super().get_command(ctx, name)
        if cmd is not None and name in LAB_COMMANDS and CONNECT_NOTE not in (cmd.epilog or ""):
            cmd.epilog = f"{cmd.epilog}\n\n{CONNECT_NOTE}" if cmd.epilog else CONNECT_NOTE
        return cmd


def _tdgen_cli():
    from tdgen.cli import tdgen

    return tdgen


def _ik_cli():
    from tdgen.cli import ik

    return ik


def _scene_cli():
    from tdgen.cli import scene

    return scene


def _workflow_cli():
    from devices.cli import workflow

    return workflow


def _robot_cli():
    from devices.cli import robot_command as robot

    return robot


def _eval_cli():
    from devices.cli import evaluate

    return evaluate


# commands that talk to a running lab: their help says where they find it
LAB_COMMANDS = {"things", "td", "read", "write", "invoke", "observe", "subscribe", "wait", "workflow", "eval",
                "robot", "record", "adapter", "plan"}
CONNECT_NOTE = ("The lab: --connect ENDPOINT before the command (twinmesh --connect tcp/HOST:PORT COMMAND ...), "
                f"or the environment variable TWINMESH_CONNECT; default {DEFAULT_ENDPOINT}.")


@click.group(cls=LazyGroup, context_settings={"auto_envvar_prefix": "TWINMESH", "help_option_names": ["-h", "--help"]})
@click.option("--prefix", default="wot", show_default=True, show_envvar=True, help="Key-expression prefix of the lab.")
@click.option("--connect", multiple=True, metavar="ENDPOINT", show_envvar=True,
              help=f"Zenoh endpoint of the lab to connect to (repeatable; in the variable, space-separated) "
                   f"[default: {DEFAULT_ENDPOINT}].")
@click.option("--listen", multiple=True, metavar="ENDPOINT", show_envvar=True,
              help="Zenoh endpoint to listen on (repeatable).")
@click.option("--mode", type=click.Choice(["peer", "client", "router"]), show_envvar=True,
              help="Zenoh mode [default: client: every process reaches the others through the lab's router; "
                   "peer: links to every other peer too (the old topology, N²/2 links)].")
@click.option("--multicast/--no-multicast", default=False, show_default=True, show_envvar=True,
              help="Multicast scouting.")
@click.option("--shared-memory/--no-shared-memory", default=False, show_default=True, show_envvar=True,
              help="Zenoh shared memory between the processes of a host (pays for large payloads only; each "
                   "link then costs segments and descriptors).")
@click.option("--secure", is_flag=True, show_envvar=True,
              help="A secure lab: Zenoh over TLS with mutual authentication and access control, HTTP with a token. "
                   "`twinmesh --secure up` makes the lab's secrets on first use; other commands find them (same account).")
@click.option("--secrets", type=click.Path(file_okay=False), metavar="DIR", show_envvar=True,
              help="Where a secure lab's secrets are (implies --secure) [default: $XDG_DATA_HOME/twinmesh/secrets, "
                   "else ~/.local/share/twinmesh/secrets].")
@click.option("--config", "zenoh_config", type=click.Path(dir_okay=False), metavar="FILE", show_envvar=True,
              help="A Zenoh configuration file (JSON5, Zenoh's own keys) applied over twinmesh's settings in every "
                   "process of the lab: limits, lease, keep-alives, buffers (see the docs' scale page).")
@click.option("-v", "--verbose", count=True,
              help="More logging (-vv for debug); also shows pybullet's own messages (on stderr).")
@click.version_option(package_name="twinmesh", message="twinmesh %(version)s")
@click.pass_context
def main(ctx: click.Context, prefix, connect, listen, mode, multicast, shared_memory, secure, secrets,
         zenoh_config, verbose) -> None:
    """twinmesh: a digital-twin lab for the Web of Things."""
    separate_native_stdout(show=verbose > 0)  # pybullet's C prints never mix into what a command prints
    if verbose:
        os.environ[SHOW_NATIVE] = "1"  # for this process and every one it starts (tdgen's workers too)
    quiet_pybullet_import()
    logging.basicConfig(level=[logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)],
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    secrets_dir = _secrets_dir(ctx, secure, secrets)
    ctx.obj = MeshSettings(prefix=prefix, mode=mode or "client", connect=tuple(connect) or (DEFAULT_ENDPOINT,),
                           listen=tuple(listen), multicast=multicast, shared_memory=shared_memory,
                           secrets=secrets_dir, overrides=_overrides(zenoh_config))


def _overrides(path: str | None) -> tuple[tuple[str, str], ...]:
    """`--config FILE`, read and tried (a key Zenoh does not know, a wrong type: exit 2 here)."""
    if path is None:
        return ()
    from mesh.fabric.settings import ConfigFileError, config_overrides

    try:
        return config_overrides(path)
    except ConfigFileError as e:
        raise usage_exit(str(e)) from None


def _secrets_dir(ctx: click.Context, secure: bool, secrets: str | None) -> str | None:
    """The secrets directory of a secure lab (None: not secure). Commands other than `up` need it made."""
    if not (secure or secrets):
        return None
    from mesh.fabric.secrets import default_secrets_dir

    folder = Path(secrets) if secrets else default_secrets_dir()
    # `up` makes them; `wait` may be started beside `up` and waits for them too
    if ctx.invoked_subcommand not in ("up", "wait", None) and not (folder / "ca.pem").exists():
        raise usage_exit(f"no lab secrets in {folder} (no ca.pem): start the lab with `twinmesh --secure up` "
                         f"on this account, or give --secrets DIR (a copy of the lab's)")
    return str(folder)


# --- running a lab ----------------------------------------------------------------------------
READY_TIMEOUT = 600.0  # s `up` waits for every Thing of its scene before it gives up, and per Thing:
READY_TIMEOUT_PER_THING = 0.06  # a lab's router takes sessions ever more slowly (10,000 devices: 340 s)


# A host joining a lab waits longer: the lab's router takes the sessions of every host joining, and
# it takes them ever more slowly (9 hosts of 1,000 devices joining a lab of 1,000: all 10,000 sessions
# open after 22 minutes on a 2-core machine).
JOIN_READY_TIMEOUT = 1800.0
STARTER_GONE_GRACE = 6.0  # s `up` has, once its starter died, to stop its processes before it ends itself


def _ready_timeout(things: list[str]) -> float:
    return READY_TIMEOUT + READY_TIMEOUT_PER_THING * len(things)


@main.command()
@click.argument("scene", required=False)
@click.option("--zenoh", "zenoh_endpoint", metavar="ENDPOINT",
              help="Zenoh endpoint of the lab's router: it listens there and every process of the lab connects "
                   f"there [default: the global --connect, env TWINMESH_CONNECT, else {DEFAULT_ENDPOINT}].")
@click.option("--http", "http", default="127.0.0.1:8080", show_default=True, help="Adapter address HOST:PORT.")
@click.option("--no-http", is_flag=True, help="Do not start the HTTP adapter.")
@click.option("--auth", envvar="TWINMESH_HTTP_AUTH", metavar="SCHEME:CREDENTIALS", help=AUTH_HELP)
@click.option("--record", type=click.Path(dir_okay=False), help="Also record the lab to this .rrd file.")
@click.option("--view", "view", default="127.0.0.1:9090", show_default=True,
              help="Serve the live 3D view (a Rerun web viewer) at HOST:PORT; its stream uses the next free port.")
@click.option("--no-view", is_flag=True, help="Do not serve the live 3D view.")
@click.option("--speed", default="1", show_default=True, help="Simulation speed factor, or 'max'.")
@click.option("--samples", type=SampleCount(100), metavar="N",
              help=f"Random configurations each robot's workspace is sampled with [default: {DEFAULT_SAMPLES}; fewer start "
                   "faster, e.g. for a class on small machines].")
@click.option("--tdgen-cache", type=click.Path(file_okay=False),
              help="Where the tdgen service caches generated robot TDs [default: $TWINMESH_CACHE/tdgen, "
                   "else ~/.cache/twinmesh/tdgen].")
@click.option("--tdgen-live/--tdgen-from-scratch", default=True, show_default=True,
              help="Follow a robot's changing surroundings (a box put down or taken away) by re-checking only "
                   "the samples the change can touch, or generate every new scene from scratch.")
@click.option("--fleet", "fleet", type=click.IntRange(min=1, max=100_000), metavar="N",
              help="The fleet scene's number of virtual devices [default: 100].")
@click.option("--fleet-first", type=click.IntRange(min=1), default=1, show_default=True, metavar="K",
              help="The fleet's first station number (devices are named <kind>-<station>): give each host "
                   "that joins a lab its own range.")
@click.option("--join", "join", metavar="ENDPOINT",
              help="Run only the scene's devices, for the lab whose router listens at ENDPOINT (another host's "
                   "`twinmesh --listen tcp/0.0.0.0:7447 up`): this host's gateway links to it; no adapter, "
                   "tdgen, recorder or view here.")
@click.option("--direct", is_flag=True,
              help="With --join: no gateway on this host; each device links straight to the lab's router "
                   "(its router then holds a link per device). A cut cable is then seen after 60 s instead of 1.5 s.")
@click.option("--real", "real", multiple=True, metavar="DEVICE=URL",
              help="Guard the real DEVICE whose TD is at URL with its twin (repeatable; iot-platform and iot-lab): "
                   "every action is checked on the twin first and only then sent to the real device; the real "
                   "device is also on the mesh as DEVICE-real.")
@click.option("--real-auth", envvar="TWINMESH_REAL_AUTH", metavar="SCHEME:CREDENTIALS",
              help="Credentials of the real devices: basic:USER:PASS or bearer:TOKEN.")
@click.option("--real-ca", type=click.Path(dir_okay=False, exists=True), help=commands.CA_HELP)
@click.option("--real-insecure", is_flag=True, help=commands.INSECURE_HELP)
@click.option("--real-calibration", multiple=True, metavar="DEVICE=CSV",
              help="Twin-to-real calibration pairs of a guarded device (twin_x,twin_y,twin_z,real_x,real_y,real_z "
                   "in mm) [default: the identity].")
@click.option("--thing", "virtual_things", multiple=True, metavar="NAME=TD",
              help="Add a virtual Thing served from the TD in a file or at an http(s) URL (repeatable; see "
                   "`twinmesh virtual`).")
@click.option("--scans", type=click.Path(file_okay=False, exists=True), envvar="TWINMESH_SCANS", show_envvar=True,
              metavar="DIR", help="The only folder the iot-lab's world takes the files of mesh and scan obstacles "
              "from (addObstacle; relative paths are relative to it), since it then serves them to anyone who may "
              "read it [default: $XDG_DATA_HOME/twinmesh/scans, else ~/.local/share/twinmesh/scans].")
@click.option("--outlive-parent", is_flag=True,
              help="Keep the lab running when the process that started `up` ends. Without it a lab started by a "
                   "script, a test or an editor stops when its starter dies, however it dies (a terminal's shell, "
                   "`nohup` and a service manager keep it as long as they run).")
@click.pass_obj
def up(settings: MeshSettings, scene: str | None, zenoh_endpoint: str | None, http: str, no_http: bool,
       auth: str | None, record: str | None, view: str, no_view: bool, speed: str, samples: int | None,
       tdgen_cache: str | None, tdgen_live: bool, fleet: int | None, fleet_first: int, join: str | None, direct: bool,
       real: tuple[str, ...], real_auth: str | None, real_ca: str | None, real_insecure: bool,
       real_calibration: tuple[str, ...], virtual_things: tuple[str, ...], scans: str | None,
       outlive_parent: bool) -> None:
    """Start a lab: router, the TD generator, the scene's devices, the HTTP adapter (and the recorder).

    Scenes: iot-lab (default), iot-platform, ur10, lights, fleet (--fleet N virtual devices for load tests).
    Prints one line with the word `ready` once every Thing answers (scripts: `twinmesh wait`).
    Ctrl-C stops it all."""
    if not outlive_parent and follows_its_starter():
        die_with_parent(os.getppid(), grace=STARTER_GONE_GRACE)
    from devices.lab.scenes import DEFAULT_SCENE, FLEET, LabOptions, find_scene

    try:
        the_scene = find_scene(scene or DEFAULT_SCENE)
    except KeyError as e:
        raise usage_exit(str(e.args[0])) from None
    if the_scene.name != FLEET and (fleet is not None or fleet_first != 1):
        raise usage_exit(f"--fleet and --fleet-first are for the fleet scene (`twinmesh up fleet --fleet N`), "
                         f"not for {the_scene.name!r}")
    if not real and (real_calibration or real_auth or real_ca or real_insecure):
        raise usage_exit("--real-auth, --real-ca, --real-insecure and --real-calibration go with --real DEVICE=URL")
    speed_factor = _speed(speed)
    access = commands.remote_access(real_auth, real_ca, real_insecure) if real else None
    guarded = _guard_real(the_scene, real, access, real_calibration) if real else ()
    options = LabOptions(speed=speed_factor, samples=samples, fleet=fleet, fleet_first=fleet_first, real=guarded,
                         access=access, scans=str(Path(scans).resolve()) if scans else None)
    specs, things = the_scene.processes(options), the_scene.things(options)
    things += [f"{d.slug}-real" for d in guarded]
    scene = the_scene.name
    things += _add_virtual(scene, specs, things, virtual_things)
    if direct and not join:
        raise usage_exit("--direct is for --join ENDPOINT (this host's devices linked straight to that lab's router)")
    if zenoh_endpoint:
        settings = msgspec.structs.replace(settings, connect=(zenoh_endpoint,))
    token = _prepare_secrets(settings, things, joining=bool(join))
    if join:
        _join_lab(settings, scene, specs, things, join, direct)
        return
    address = None if no_http else host_port(http)
    view_address = None if no_view else host_port(view)
    services, adapter, view_url = _lab_services(settings, address, view_address,
                                                checked_auth(auth or (f"bearer:{token}" if token else None)),
                                                record, tdgen_cache, tdgen_live)
    url = None if address is None else f"http://{address[0]}:{address[1]}/"
    _run_lab(settings, scene, [*services, *specs, *adapter], things, url, view_url, record)


def _add_virtual(scene: str, specs: list[ProcessSpec], things: list[str], virtual_things: tuple[str, ...]) -> list[str]:
    """The process of the virtual Things (`--thing NAME=TD`), added to the scene's `specs`; returns the
    names of the Things it adds (usage errors exit before anything starts)."""
    if not virtual_things:
        return []
    specs_v = _virtual_specs(virtual_things, commands.remote_access(None, None, False))
    taken = {v.name for v in specs_v} & set(things)
    if taken:
        raise usage_exit(f"--thing {sorted(taken)[0]}: the scene {scene!r} already has a Thing of that name "
                         f"({'a guarded real device' if sorted(taken)[0].endswith('-real') else 'a twin'})")
    specs.append(ProcessSpec("virtual", entries.virtual, {"specs": specs_v}, role="virtual"))
    return [v.name for v in specs_v]


def _lab_services(settings: MeshSettings, address: tuple[str, int] | None, view_address: tuple[str, int] | None,
                  auth: Any, record: str | None, tdgen_cache: str | None, tdgen_live: bool
                  ) -> tuple[list[ProcessSpec], list[ProcessSpec], str | None]:
    """The lab's own processes: those that start before the devices (router, tdgen, recorder, 3D view),
    the HTTP adapter (after them), and the view's URL. A port that is taken is said before anything starts."""
    from devices.lab.readiness import PortTaken, free_or_problem, free_port_near, view_free_or_problem
    from mesh.recorder.view import view_url as make_view_url
    from tdgen.service import default_cache_dir

    listen = router_listen(settings.listen, settings.connect)
    view_url, viewer = None, []
    try:
        free_or_problem(listen, address)
        if view_address is not None:
            view_free_or_problem(view_address)
            grpc_port = free_port_near(view_address[0], view_address[1] + 1)
            view_url = make_view_url(view_address, grpc_port)
            viewer = [ProcessSpec("view", entries.view, {"address": view_address, "grpc_port": grpc_port})]
    except PortTaken as e:
        raise click.ClickException(e.detail) from None
    router = ProcessSpec("router", entries.router, {"listen": listen})
    recorder = [ProcessSpec("recorder", entries.recorder, {"path": record})] if record else []
    tdgen = ProcessSpec("tdgen", entries.tdgen, {"cache_dir": str(tdgen_cache or default_cache_dir()),
                                                      "live": tdgen_live})
    http_adapter = [] if address is None else [ProcessSpec("adapter", entries.adapter, {"address": address, "auth": auth,
                                                                                 "view": view_url})]
    return [router, tdgen, *recorder, *viewer], http_adapter, view_url


def _run_lab(settings: MeshSettings, scene: str, specs: list[ProcessSpec], things: list[str], url: str | None,
             view_url: str | None, record: str | None) -> None:
    """Start every process, say `ready` once every Thing answers, serve the lab's status until Ctrl-C."""
    from devices.lab.readiness import serve_status
    from mesh.fabric.session import one_shot_session
    from mesh.messages.lab import LabStatus
    from tdgen.service import THING as TDGEN_THING

    things = [TDGEN_THING, *things]
    peers = msgspec.structs.replace(settings, listen=())  # the router alone listens; the others connect to it
    sup = Supervisor(peers, specs)
    set_title(f"up {scene}")
    sup.start()
    _until_ready(sup, peers, things, _ready_timeout(things), http=url,
                 died="while the lab was starting (its log is above); stopped the lab", failed="; stopped the lab")
    status = LabStatus(ready=True, scene=scene, things=things, http=url, zenoh=", ".join(settings.endpoints))
    with one_shot_session(peers, service=True) as session:
        queryable = serve_status(session, peers, status)
        click.echo(f"twinmesh lab '{scene}' ready: {len(things)} Things on Zenoh {status.zenoh}"
                   + ("" if url is None else f", HTTP {url}") + ("" if view_url is None else f", 3D view {view_url}")
                   + (f", recorder writing {record}" if record else "")
                   + (f", secure (secrets in {settings.secrets})" if settings.secrets else "")
                   + "  (Ctrl-C to stop)")
        code = sup.run_until_stopped()
        queryable.undeclare()
    sys.exit(code)


def _virtual_specs(given: tuple[str, ...], access: Any) -> list[Any]:
    """Every NAME=TD taken in and checked, each value it needs drawn once: one that cannot be served
    starts none of them (exit code 2, one line naming the first problem)."""
    from devices.things.virtual import VirtualSpec, prepare
    from mesh.bridge.intake import IntakeError, take_in
    from mesh.fabric.keys import check_slug
    from mesh.wot.schema_values import NoValue

    specs: list[Any] = []
    client = access.client()
    try:
        for item in given:
            name, sep, source = item.partition("=")
            if not sep or not source:
                raise usage_exit(f"{item!r} is not NAME=TD (a file or an http(s) URL)")
            try:
                check_slug(name)
            except ValueError as e:
                raise usage_exit(str(e)) from None
            if name in {s.name for s in specs}:
                raise usage_exit(f"{name}: the same NAME given twice")
            try:
                specs.append(VirtualSpec(name, source, take_in(source, client)))
            except IntakeError as e:
                raise usage_exit(str(e)) from None
    finally:
        client.close()
    try:
        prepare(specs, seed=0)
    except NoValue as e:
        raise usage_exit(f"cannot serve {e}") from None
    return specs


@main.command()
@click.argument("given", nargs=-1, required=True, metavar="NAME=TD...")
@click.option("--seed", type=int, help="Draw the same values on every run (default: different each run).")
@click.option("--drift", is_flag=True, help="Let read-only numeric properties drift within their bounds.")
@click.option("--events-every", type=click.FloatRange(min=0), default=5.0, show_default=True, metavar="S",
              help="Fire every event every S seconds with valid data (0: never).")
@click.option("--auth", "auth", metavar="SCHEME:CREDENTIALS", help="Credentials for TD URLs that need them.")
@click.option("--ca", type=click.Path(dir_okay=False, exists=True), help=commands.CA_HELP)
@click.option("--insecure", is_flag=True, help=commands.INSECURE_HELP)
@click.pass_obj
def virtual(settings: MeshSettings, given: tuple[str, ...], seed: int | None, drift: bool, events_every: float,
            auth: str | None, ca: str | None, insecure: bool) -> None:
    """Serve Things from their TDs alone (TD: a file or an http(s) URL) on a running lab, until Ctrl-C:
    every value they give is valid by the TD's schemas; writes are kept, events fire, actions answer."""
    from devices.things.virtual import run

    specs = _virtual_specs(given, commands.remote_access(auth, ca, insecure))
    with mesh_client(settings) as c:
        for spec in specs:
            if c.is_alive(spec.name, timeout=2.0):
                try:
                    title = json.loads(c.td_bytes(spec.name)).get("title")
                except (Problem, ValueError):
                    title = None
                there = f" as {title!r}" if title and title != spec.name else ""
                raise CommandFailed(f"{spec.name}: a Thing of that name is already on the mesh{there} (a device, a "
                                    f"bridged remote Thing or another virtual one); give {spec.source} another NAME")
    stop = commands.install_stop_handlers()

    def ready() -> None:
        click.echo(f"virtual Things ready: {', '.join(s.name for s in specs)}")

    run(settings, stop, specs, seed=seed, drift=drift, events_every=events_every, ready=ready)


def _guard_real(scene: Scene, real: tuple[str, ...], access: Any, calibrations: tuple[str, ...]) -> tuple[Any, ...]:
    """Every real device's TD taken in (one that cannot be had starts nothing), for the scene's devices that
    can guard one: the `RealDevice`s its world process gets."""
    from devices.things.guard import RealDevice
    from mesh.bridge.intake import IntakeError
    from mesh.bridge.run import parse_remote, take_in_all

    if not scene.guardable:
        guarding = sorted(n for n, s in _scenes().items() if s.guardable)
        raise usage_exit(f"--real is for the scenes with devices that can guard a real one ({', '.join(guarding)}), "
                         f"not {scene.name!r}")
    try:
        remotes = [parse_remote(r) for r in real]
        pairs = dict(c.split("=", 1) for c in calibrations if "=" in c)
    except ValueError as e:
        raise usage_exit(f"--real: {e}") from None
    if len(pairs) != len(calibrations):
        raise usage_exit(f"--real-calibration takes DEVICE=CSV, not {[c for c in calibrations if '=' not in c][0]!r}")
    for remote in remotes:
        if remote.name not in scene.guardable:
            raise usage_exit(f"--real {remote.name}: in the scene {scene.name!r} the devices that can guard a real "
                             f"one are {', '.join(sorted(scene.guardable))}")
    if "ur10" in pairs:
        raise usage_exit("--real-calibration ur10: a robot Thing's moves go to the real arm in its TD's frame, which "
                         "is the real robot's when the twin has a calibration (twinmesh robot --calibration CSV)")
    unknown = sorted(set(pairs) - {r.name for r in remotes})
    if unknown:
        raise usage_exit(f"--real-calibration {unknown[0]}: no --real {unknown[0]}=URL to calibrate")
    for device, path in pairs.items():
        from tdgen.robot.calibration import CalibrationError, load_calibration

        try:
            load_calibration(path)
        except (CalibrationError, OSError, ValueError) as e:
            raise usage_exit(f"--real-calibration {device}={path}: {e}") from None
    client = access.client()
    try:
        found = take_in_all(remotes, client)
    except IntakeError as e:
        raise CommandFailed(f"--real: {e}", UNREACHABLE if e.unreachable else 2) from None
    finally:
        client.close()
    return tuple(RealDevice(remote.name, remote.url, td, pairs.get(remote.name)) for remote, _, td in found)


def _scenes() -> dict[str, Scene]:
    from devices.lab.scenes import SCENES

    return SCENES


def _prepare_secrets(settings: MeshSettings, things: list[str], joining: bool) -> str | None:
    """For a secure lab: its secrets made (or, joining another host's lab, found: they are the lab's
    copy), a credential for each of the scene's Things issued before the router starts (so that its
    access rules know them); the HTTP token, None when the lab is not secure."""
    if settings.secrets is None:
        return None
    from mesh.fabric.secrets import LabSecrets, SecretsError

    secrets = LabSecrets(settings.secrets)
    try:
        if joining and not secrets.ca.exists():
            raise SecretsError(f"no lab secrets in {secrets.dir}: copy the lab's secrets directory from the lab's "
                               "host (at least ca.pem, ca-key.pem, router.pem, router-key.pem) and give it with "
                               "--secrets DIR")
        secrets.ensure()
        for thing in things:
            secrets.credential(f"device:{thing}")
        return secrets.http_token()
    except (SecretsError, OSError) as e:
        raise click.ClickException(str(e)) from None


def _join_lab(settings: MeshSettings, scene: str, specs: list[ProcessSpec], things: list[str], join: str,
              direct: bool = False) -> None:
    """`up SCENE --join ENDPOINT`: this host's gateway (listening where this host's devices connect; one client
    of the lab's router at ENDPOINT, its devices a region south of it: `MeshSettings.as_gateway`), and the
    scene's devices; ready once the lab sees them all. `direct`: no gateway here, the devices are clients of
    the lab's router."""
    from devices.lab.readiness import PortTaken, free_or_problem

    lab = msgspec.structs.replace(settings, listen=(), connect=(join,))
    if direct:
        listen: list[str] = []
        sup = Supervisor(lab, specs)  # the devices' 60 s lease: the lab's router, busy, must not drop them
    else:
        listen = router_listen(settings.listen, settings.connect)
        try:
            free_or_problem(listen, None)
        except PortTaken as e:
            raise click.ClickException(e.detail) from None
        router = ProcessSpec("router", entries.router, {"listen": listen, "connect": [join], "gateway": True},
                             role=f"gateway (joins {join})")
        sup = Supervisor(msgspec.structs.replace(settings, listen=()), [router, *specs])
    set_title(f"up {scene} --join {join}")
    sup.start()
    _until_ready(sup, lab, things, max(JOIN_READY_TIMEOUT, _ready_timeout(things)), follow=False,
                 died="while joining the lab (its log is above); stopped",
                 failed=f" (is the lab at {join} running and listening there?); stopped")
    where = f"this host's gateway on {', '.join(listen)}" if listen else "linked straight to the lab's router"
    click.echo(f"twinmesh '{scene}' joined the lab at {join}, ready: {len(things)} Things, {where}  (Ctrl-C to stop)")
    sys.exit(sup.run_until_stopped())


def _until_ready(sup: Supervisor, settings: MeshSettings, things: list[str], timeout: float, died: str, failed: str,
                 **wait: Any) -> None:
    """Wait until the lab's Things answer, saying meanwhile what it waits for; a part that dies, or a
    timeout, stops the lab with one line (`died`, `failed` end it); Ctrl-C meanwhile is a clean exit."""
    from devices.lab.readiness import LabDied, wait_ready

    try:
        wait_ready(settings, lambda: _lab_client(settings), things, timeout,
                   alive=lambda: "stopped" if sup.stop.is_set() else sup.dead(),
                   progress=lambda text: click.echo(f"twinmesh up: {text}", err=True), **wait)
    except LabDied as e:
        sup.shutdown()
        if e.detail == "stopped":
            sys.exit(0)
        raise click.ClickException(f"{e.detail} {died}") from None
    except Problem as e:
        sup.shutdown()
        raise click.ClickException(f"{e.detail}{failed}") from None


@contextmanager
def _lab_client(settings: MeshSettings):
    from mesh.fabric.session import one_shot_session

    with one_shot_session(settings) as session:
        yield MeshClient(session, settings)


@main.command()
@click.option("--timeout", type=click.FloatRange(min=0), default=120.0, show_default=True, metavar="S",
              help="Give up after this many seconds.")
@click.option("--thing", "things", multiple=True, metavar="NAME",
              help="Wait for these Things to answer their TD instead (repeatable; for a mesh not started by "
                   "`twinmesh up`).")
@click.pass_obj
def wait(settings: MeshSettings, timeout: float, things: tuple[str, ...]) -> None:
    """Exit 0 as soon as the lab at --connect (env TWINMESH_CONNECT) is ready; 1 with the reason on timeout.

    For scripts: `twinmesh up & twinmesh wait && twinmesh workflow cube`."""
    from devices.lab.readiness import wait_ready

    try:
        status = wait_ready(settings, lambda: _lab_client(settings), list(things) or None, timeout)
    except Problem as e:
        raise CommandFailed(f"no ready lab at {', '.join(settings.connect)}: {e.detail}", UNREACHABLE) from None
    if status is None:
        click.echo(f"ready: {', '.join(things)}")
    else:
        click.echo(f"ready: lab '{status.scene}', {len(status.things)} Things on Zenoh {status.zenoh}"
                   + ("" if status.http is None else f", HTTP {status.http}"))


def _speed(value: str) -> float | None:
    from devices.sim.pybullet_world import parse_speed

    try:
        return parse_speed(value)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None


@main.command(context_settings={"ignore_unknown_options": True})  # lets X Y Z be negative
@click.argument("thing", shell_complete=completion.things)
@click.argument("xyz", nargs=-1, type=float, metavar="[X Y Z]")
@click.option("--joints", metavar="JSON", help="Plan to these joint values instead ('{\"joint\": deg, ...}').")
@click.pass_obj
def plan(settings: MeshSettings, thing: str, xyz: tuple[float, ...], joints: str | None) -> None:
    """Dry-run a robot move to X Y Z (mm, the robot TD's frame) or to --joints: print the path the move
    would take, moving nothing. Exit 0 when the move would be accepted, 1 with the reason when refused."""
    if (len(xyz) == 3) == (joints is not None) or len(xyz) not in (0, 3):
        raise click.UsageError("give X Y Z, or --joints JSON")
    request = {"joints": parse_json(joints, "--joints")} if joints else dict(zip("xyz", xyz))
    with mesh_client(settings) as c:
        echo_json(c.invoke(thing, "planMove", request))


for _command in (commands.router, commands.adapter, commands.record, commands.things, commands.td, commands.read,
                 commands.write, commands.invoke, commands.observe, commands.subscribe, commands.bridge):
    main.add_command(_command)
main.add_command(replay.replay)
