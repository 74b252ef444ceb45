"""The `twinmesh` command: the one composition root (it alone may import devices and tdgen)."""
from __future__ import annotations

import json
import logging
import sys
from contextlib import contextmanager
from typing import Any

import click
import msgspec

from mesh.consumer import NOTHING, MeshClient
from mesh.problem import Problem
from mesh.processes import ProcessSpec, Supervisor
from mesh.settings import DEFAULT_ENDPOINT, MeshSettings

ADAPTER = "mesh.http.server:run"
RECORDER = "mesh.recorder:run"
TDGEN_SERVICE = "tdgen.service:run"


class LazyGroup(click.Group):
    """Loads heavy subcommands (pybullet, trimesh) only when they are used: `twinmesh read` stays fast."""

    lazy = {
        "tdgen": "tdgen.commands:tdgen_command",
        "check": "tdgen.commands:check_command",
        "ik": "tdgen.commands_ik:ik_command",
        "workflow": "devices.workflow:workflow_command",
        "robot": "devices.robot_thing:robot_command",
        "eval": "devices.evaluation:eval_command",
    }

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted([*super().list_commands(ctx), *self.lazy])

    def get_command(self, ctx: click.Context, name: str):
        if name in self.lazy:
            from mesh.processes import resolve

            return resolve(self.lazy[name])
        return super().get_command(ctx, name)


@click.group(cls=LazyGroup, context_settings={"auto_envvar_prefix": "TWINMESH", "help_option_names": ["-h", "--help"]})
@click.option("--prefix", default="wot", show_default=True, help="Key-expression prefix of the lab.")
@click.option("--connect", multiple=True, metavar="ENDPOINT",
              help=f"Zenoh endpoint to connect to (repeatable) [default: {DEFAULT_ENDPOINT}].")
@click.option("--listen", multiple=True, metavar="ENDPOINT", help="Zenoh endpoint to listen on (repeatable).")
@click.option("--mode", type=click.Choice(["peer", "client", "router"]),
              help="Zenoh mode [default: peer for devices and services, client for one-shot commands].")
@click.option("--multicast/--no-multicast", default=False, show_default=True, help="Multicast scouting.")
@click.option("-v", "--verbose", count=True, help="More logging (-vv for debug).")
@click.pass_context
def main(ctx: click.Context, prefix, connect, listen, mode, multicast, verbose) -> None:
    """twinmesh: a digital-twin lab for the Web of Things."""
    logging.basicConfig(level=[logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)],
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    ctx.obj = MeshSettings(prefix=prefix, mode=mode or "peer", connect=tuple(connect) or (DEFAULT_ENDPOINT,),
                           listen=tuple(listen), multicast=multicast)


def _auth(value: str | None) -> str | None:
    """Check `--auth` early (a typo must not start an open adapter); the string goes to the adapter."""
    from mesh.http.auth import parse_auth

    try:
        parse_auth(value)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--auth") from None
    return value or None


AUTH_HELP = "HTTP security: bearer:TOKEN or basic:USER:PASS [env TWINMESH_HTTP_AUTH]."


def _host_port(value: str) -> tuple[str, int]:
    host, _, port = value.rpartition(":")
    if not host or not port.isdigit():
        raise click.BadParameter(f"{value!r} is not HOST:PORT")
    return host, int(port)


# --- running a lab ----------------------------------------------------------------------------
@main.command()
@click.argument("scene", required=False)
@click.option("--http", "http", default="127.0.0.1:8080", show_default=True, help="Adapter address HOST:PORT.")
@click.option("--no-http", is_flag=True, help="Do not start the HTTP adapter.")
@click.option("--auth", envvar="TWINMESH_HTTP_AUTH", metavar="SCHEME:CREDENTIALS", help=AUTH_HELP)
@click.option("--record", type=click.Path(dir_okay=False), help="Also record the lab to this .rrd file.")
@click.option("--speed", default="1", show_default=True, help="Simulation speed factor, or 'max'.")
@click.option("--samples", type=click.IntRange(min=100), metavar="N",
              help="Random configurations each robot's workspace is sampled with [default: 80000; fewer start "
                   "faster, e.g. for a class on small machines].")
@click.option("--tdgen-cache", type=click.Path(file_okay=False),
              help="Where the tdgen service caches generated robot TDs [default: $TWINMESH_CACHE/tdgen, "
                   "else ~/.cache/twinmesh/tdgen].")
@click.pass_obj
def up(settings: MeshSettings, scene: str | None, http: str, no_http: bool, auth: str | None, record: str | None,
       speed: str, samples: int | None, tdgen_cache: str | None) -> None:
    """Start a lab: router, the TD generator, the scene's devices, the HTTP adapter (and the recorder).
    Ctrl-C stops it all."""
    from devices.scenes import DEFAULT_SCENE, scene_specs
    from tdgen.service import default_cache_dir

    try:
        specs = scene_specs(scene or DEFAULT_SCENE, speed=_speed(speed), samples=samples)
    except KeyError as e:
        raise click.ClickException(str(e.args[0])) from None
    router = ProcessSpec("router", "mesh.session:run_router_process",
                         {"listen": list(settings.listen) + [e for e in settings.connect if e not in settings.listen]})
    recorder = [ProcessSpec("recorder", RECORDER, {"path": record})] if record else []
    tdgen = ProcessSpec("tdgen", TDGEN_SERVICE, {"cache_dir": str(tdgen_cache or default_cache_dir())})
    http_adapter = [] if no_http else [ProcessSpec("adapter", ADAPTER,
                                                   {"address": _host_port(http), "auth": _auth(auth)})]
    # the router alone listens; every other process connects to it
    peers = msgspec.structs.replace(settings, listen=())
    sup = Supervisor(peers, [router, tdgen] + recorder + specs + http_adapter)
    sup.start()
    click.echo(f"twinmesh lab '{scene or DEFAULT_SCENE}' on {', '.join(settings.connect)}"
               + ("" if no_http else f"; HTTP adapter on http://{http}/") + "  (Ctrl-C to stop)")
    sys.exit(sup.run_until_stopped())


def _speed(value: str) -> float | None:
    from mesh.settings import parse_speed

    try:
        return parse_speed(value)
    except ValueError as e:
        raise click.BadParameter(str(e)) from None


def _run_foreground(settings: MeshSettings, target: str, **kwargs: Any) -> None:
    from mesh.processes import install_stop_handlers, resolve

    resolve(target)(settings, install_stop_handlers(), **kwargs)


@main.command()
@click.pass_obj
def router(settings: MeshSettings) -> None:
    """Run the lab's Zenoh router (where peers connect; listens on --listen or the --connect endpoints)."""
    listen = list(settings.listen) or list(settings.connect)
    _run_foreground(settings, "mesh.session:run_router_process", listen=listen)


@main.command()
@click.option("--http", "http", default="127.0.0.1:8080", show_default=True, help="Listen on HOST:PORT.")
@click.option("--auth", envvar="TWINMESH_HTTP_AUTH", metavar="SCHEME:CREDENTIALS", help=AUTH_HELP)
@click.pass_obj
def adapter(settings: MeshSettings, http: str, auth: str | None) -> None:
    """Run the WoT HTTP adapter for every Thing on the mesh."""
    _run_foreground(settings, ADAPTER, address=_host_port(http), auth=_auth(auth))


@main.command()
@click.argument("path", required=False, type=click.Path(dir_okay=False))
@click.pass_obj
def record(settings: MeshSettings, path: str | None) -> None:
    """Record the mesh to a Rerun .rrd file until Ctrl-C [default: recordings/twinmesh-DATE-TIME.rrd]."""
    _run_foreground(settings, RECORDER, path=path)


# --- consuming, as a plain Zenoh peer --------------------------------------------------------
@contextmanager
def _client(settings: MeshSettings):
    """A one-shot consumer; Problems (no lab, Thing gone, refused) become CLI messages."""
    from mesh.session import one_shot_session

    try:
        with one_shot_session(settings, _mode_given()) as session:
            yield MeshClient(session, settings)
    except Problem as p:
        raise click.ClickException(str(p)) from None


def _mode_given() -> bool:
    return click.get_current_context().find_root().params.get("mode") is not None


def _parse_json(text: str, what: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise click.BadParameter(f"{what} is not valid JSON ({e.msg} at column {e.colno}): {text!r}") from None


def _echo(value: Any) -> None:
    click.echo(msgspec.json.encode(value).decode())


@main.command()
@click.pass_obj
def things(settings: MeshSettings) -> None:
    """List the Things alive on the mesh."""
    with _client(settings) as c:
        for name in c.things():
            click.echo(name)


@main.command()
@click.argument("thing")
@click.pass_obj
def td(settings: MeshSettings, thing: str) -> None:
    """Print a Thing's TD (with its Zenoh forms)."""
    with _client(settings) as c:
        click.echo(json.dumps(json.loads(c.td_bytes(thing)), indent=2))


@main.command()
@click.argument("thing")
@click.argument("prop")
@click.pass_obj
def read(settings: MeshSettings, thing: str, prop: str) -> None:
    """Read a property."""
    with _client(settings) as c:
        _echo(c.read(thing, prop))


@main.command()
@click.argument("thing")
@click.argument("prop")
@click.argument("value")
@click.pass_obj
def write(settings: MeshSettings, thing: str, prop: str, value: str) -> None:
    """Write a property (VALUE is JSON, e.g. true, 42, '[1,0,0]')."""
    data = _parse_json(value, "VALUE")
    with _client(settings) as c:
        c.write(thing, prop, data)


@main.command()
@click.argument("thing")
@click.argument("action")
@click.argument("input", required=False)
@click.pass_obj
def invoke(settings: MeshSettings, thing: str, action: str, input: str | None) -> None:
    """Invoke an action (INPUT is JSON) and print its output."""
    data = NOTHING if input is None else _parse_json(input, "INPUT")
    with _client(settings) as c:
        out = c.invoke(thing, action, data)
        if out is not None:
            _echo(out)


def _follow(settings: MeshSettings, subscribe_name: str, thing: str, name: str, count: int | None) -> None:
    import queue

    q: queue.Queue = queue.Queue()
    with _client(settings) as c:
        sub = getattr(c, subscribe_name)(thing, name, q.put)
        click.echo(f"{subscribe_name} {thing}/{name}: waiting for changes (Ctrl-C to stop)", err=True)
        seen = 0
        try:
            while count is None or seen < count:
                try:
                    _echo(q.get(timeout=0.5))
                    seen += 1
                except queue.Empty:
                    continue
        except KeyboardInterrupt:
            pass
        finally:
            sub.undeclare()


@main.command()
@click.argument("thing")
@click.argument("prop")
@click.option("--count", type=int, help="Stop after this many changes.")
@click.pass_obj
def observe(settings: MeshSettings, thing: str, prop: str, count: int | None) -> None:
    """Print each change of a property (one JSON value per line) until Ctrl-C."""
    _follow(settings, "observe", thing, prop, count)


@main.command()
@click.argument("thing")
@click.argument("event")
@click.option("--count", type=int, help="Stop after this many events.")
@click.pass_obj
def subscribe(settings: MeshSettings, thing: str, event: str, count: int | None) -> None:
    """Print each event (one JSON value per line) until Ctrl-C."""
    _follow(settings, "subscribe", thing, event, count)
