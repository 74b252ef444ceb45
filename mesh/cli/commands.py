"""The mesh's commands: its router, the HTTP adapter, the recorder, and a mesh client's (things, td,
read, write, invoke, observe, subscribe). The root `twinmesh` group (devices.cli.main) adds them."""
from __future__ import annotations

import json
from typing import Any

import click
import msgspec

from mesh.cli import completion
from mesh.cli.consumers import mesh_client
from mesh.fabric.mesh_client import NOTHING
from mesh.fabric.settings import MeshSettings
from mesh.process import install_stop_handlers


def checked_auth(value: str | None) -> str | None:
    """Check `--auth` early (a typo must not start an open adapter); the string goes to the adapter."""
    from mesh.http.credentials import parse_auth

    try:
        parse_auth(value)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--auth") from None
    return value or None


AUTH_HELP = "HTTP security: bearer:TOKEN or basic:USER:PASS [env TWINMESH_HTTP_AUTH]."


def host_port(value: str) -> tuple[str, int]:
    host, _, port = value.rpartition(":")
    if not host or not port.isdigit():
        raise click.BadParameter(f"{value!r} is not HOST:PORT")
    return host, int(port)


@click.command()
@click.pass_obj
def router(settings: MeshSettings) -> None:
    """Run the lab's Zenoh router (where peers connect; listens on --listen or the --connect endpoints)."""
    from mesh.fabric.session import run_router_process

    listen = list(settings.listen) or list(settings.connect)
    run_router_process(settings, install_stop_handlers(), listen=listen)


@click.command()
@click.option("--http", "http", default="127.0.0.1:8080", show_default=True, help="Listen on HOST:PORT.")
@click.option("--auth", envvar="TWINMESH_HTTP_AUTH", metavar="SCHEME:CREDENTIALS", help=AUTH_HELP)
@click.pass_obj
def adapter(settings: MeshSettings, http: str, auth: str | None) -> None:
    """Run the WoT HTTP adapter for every Thing on the mesh (in a secure lab, with its token unless --auth)."""
    if settings.secrets is not None and not auth:
        from mesh.fabric.secrets import LabSecrets, SecretsError

        try:
            auth = f"bearer:{LabSecrets(settings.secrets).http_token()}"
        except SecretsError as e:
            raise click.ClickException(str(e)) from None
    from mesh.http.server import run

    run(settings, install_stop_handlers(), address=host_port(http), auth=checked_auth(auth))


@click.command()
@click.argument("path", required=False, type=click.Path(dir_okay=False))
@click.option("--repair", is_flag=True, help="Make the recording at PATH valid again (one cut short by a crash "
              "or kill -9 has no footer); the original is kept as PATH.broken.")
@click.pass_obj
def record(settings: MeshSettings, path: str | None, repair: bool) -> None:
    """Record the mesh to a Rerun .rrd file until Ctrl-C [default: recordings/twinmesh-DATE-TIME.rrd]."""
    if repair:
        from mesh.recorder.repair import RepairError, repair_recording

        if path is None:
            raise click.UsageError("--repair needs the PATH of the recording")
        try:
            click.echo(repair_recording(path))
        except RepairError as e:
            raise click.ClickException(str(e)) from None
        return
    from mesh.recorder.logger import run

    run(settings, install_stop_handlers(), path=path)


# --- consuming, as a plain Zenoh peer --------------------------------------------------------


def parse_json(text: str, what: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise click.BadParameter(f"{what} is not valid JSON ({e.msg} at column {e.colno}): {text!r}") from None


def echo_json(value: Any) -> None:
    click.echo(msgspec.json.encode(value).decode())


@click.command()
@click.option("--sort/--unsorted", "sort", default=True, show_default=True,
              help="Sorted by name, or each name as its answer arrives (a fleet of thousands starts printing at once).")
@click.pass_obj
def things(settings: MeshSettings, sort: bool) -> None:
    """List the Things alive on the mesh, one name per line, sorted."""
    with mesh_client(settings) as c:
        for name in (c.things() if sort else c.iter_things()):
            click.echo(name)


@click.command()
@click.argument("thing", shell_complete=completion.things)
@click.pass_obj
def td(settings: MeshSettings, thing: str) -> None:
    """Print a Thing's TD (with its Zenoh forms)."""
    with mesh_client(settings) as c:
        click.echo(json.dumps(json.loads(c.td_bytes(thing)), indent=2))


@click.command()
@click.argument("thing", shell_complete=completion.things)
@click.argument("prop", shell_complete=completion.properties)
@click.pass_obj
def read(settings: MeshSettings, thing: str, prop: str) -> None:
    """Read a property."""
    with mesh_client(settings) as c:
        echo_json(c.read(thing, prop))


@click.command()
@click.argument("thing", shell_complete=completion.things)
@click.argument("prop", shell_complete=completion.writable_properties)
@click.argument("value")
@click.pass_obj
def write(settings: MeshSettings, thing: str, prop: str, value: str) -> None:
    """Write a property (VALUE is JSON, e.g. true, 42, '[1,0,0]')."""
    data = parse_json(value, "VALUE")
    with mesh_client(settings) as c:
        c.write(thing, prop, data)


@click.command()
@click.argument("thing", shell_complete=completion.things)
@click.argument("action", shell_complete=completion.actions)
@click.argument("input", required=False)
@click.pass_obj
def invoke(settings: MeshSettings, thing: str, action: str, input: str | None) -> None:
    """Invoke an action (INPUT is JSON) and print its output."""
    data = NOTHING if input is None else parse_json(input, "INPUT")
    with mesh_client(settings) as c:
        out = c.invoke(thing, action, data)
        if out is not None:
            echo_json(out)


def _follow(settings: MeshSettings, subscribe_name: str, thing: str, name: str, count: int | None) -> None:
    import queue

    q: queue.Queue = queue.Queue()
    with mesh_client(settings) as c:
        found = c.check_affordance(thing, "properties" if subscribe_name == "observe" else "events", name)
        if subscribe_name == "observe" and not getattr(found, "observable", False):
            raise click.ClickException(f"property {name!r} of {thing} is not observable")
        sub = getattr(c, subscribe_name)(thing, name, q.put)
        click.echo(f"{subscribe_name} {thing}/{name}: waiting for changes (Ctrl-C to stop)", err=True)
        seen = 0
        try:
            while count is None or seen < count:
                try:
                    echo_json(q.get(timeout=0.5))
                    seen += 1
                except queue.Empty:
                    continue
        except KeyboardInterrupt:
            pass
        finally:
            sub.undeclare()


@click.command()
@click.argument("thing", shell_complete=completion.things)
@click.argument("prop", shell_complete=completion.observable_properties)
@click.option("--count", type=int, help="Stop after this many changes.")
@click.pass_obj
def observe(settings: MeshSettings, thing: str, prop: str, count: int | None) -> None:
    """Print each change of a property (one JSON value per line) until Ctrl-C."""
    _follow(settings, "observe", thing, prop, count)


@click.command()
@click.argument("thing", shell_complete=completion.things)
@click.argument("event", shell_complete=completion.events)
@click.option("--count", type=int, help="Stop after this many events.")
@click.pass_obj
def subscribe(settings: MeshSettings, thing: str, event: str, count: int | None) -> None:
    """Print each event (one JSON value per line) until Ctrl-C."""
    _follow(settings, "subscribe", thing, event, count)


# --- remote Things on the mesh -----------------------------------------------------------------


def remote_access(auth: str | None, ca: str | None, insecure: bool) -> Any:
    """The bridge's `Access` from its options: credentials checked early, certificate checks explicit."""
    from mesh.bridge.run import Access

    if ca and insecure:
        raise click.UsageError("--ca and --insecure contradict each other: give one")
    if insecure:
        click.echo("WARNING: --insecure: the remote Things' TLS certificates are NOT checked; anyone between "
                   "here and them can read the credentials and forge their answers", err=True)
    return Access(auth=checked_auth(auth), verify=False if insecure else (ca or True))


REMOTE_AUTH_HELP = "Credentials the remote Things want, sent with the TD fetch and every interaction: " \
                   "basic:USER:PASS or bearer:TOKEN."
CA_HELP = "Check the remote Things' TLS certificates against this CA file (a device with a self-signed " \
          "certificate at a bare IP address)."
INSECURE_HELP = "Do not check the remote Things' TLS certificates at all (says so on stderr)."


@click.command()
@click.argument("remotes", nargs=-1, required=True, metavar="NAME=URL...")
@click.option("--auth", "auth", metavar="SCHEME:CREDENTIALS", envvar="TWINMESH_REMOTE_AUTH", help=REMOTE_AUTH_HELP)
@click.option("--ca", type=click.Path(dir_okay=False, exists=True), help=CA_HELP)
@click.option("--insecure", is_flag=True, help=INSECURE_HELP)
@click.option("--poll", type=click.FloatRange(min=0), default=1.0, show_default=True, metavar="S",
              help="Read the properties the remote TD offers no http observation for every S seconds and publish "
                   "their changes (0: never).")
@click.pass_obj
def bridge(settings: MeshSettings, remotes: tuple[str, ...], auth: str | None, ca: str | None, insecure: bool,
           poll: float) -> None:
    """Put remote WoT Things on the mesh, each under its NAME, for as long as this runs: their TD is fetched
    from URL and every property, action and event is driven through its own http(s) forms."""
    from mesh.bridge.intake import IntakeError
    from mesh.bridge.run import parse_remote, serve, take_in_all
    from mesh.cli.exits import UNREACHABLE, CommandFailed, usage_exit

    try:
        parsed = [parse_remote(r) for r in remotes]
    except ValueError as e:
        raise usage_exit(str(e)) from None
    access = remote_access(auth, ca, insecure)
    client = access.client()
    try:
        found = take_in_all(parsed, client)
    except IntakeError as e:
        raise CommandFailed(str(e), UNREACHABLE if e.unreachable else 2) from None
    stop = install_stop_handlers()

    def ready() -> None:
        for remote, thing, _ in found:
            click.echo(f"bridged {remote.name} ({thing.title}) from {remote.url}", err=True)
        click.echo(f"bridge ready: {', '.join(r.name for r, _, _ in found)}")

    try:
        serve(settings, stop, found, poll=poll, ready=ready)
    except IntakeError as e:
        raise CommandFailed(str(e)) from None
    finally:
        client.close()
