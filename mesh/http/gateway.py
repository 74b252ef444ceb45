"""The adapter's view of the mesh: known Things, their TDs, last property values and observers.

Fed by two Zenoh subscriptions: the `Directory` (liveliness join/leave) and one subscriber on
`<prefix>/**` (property changes, events, TD updates). Their callbacks run on Zenoh threads and only
hop onto the event loop (`call_soon_threadsafe`); all state here is touched on the loop alone, so
it needs no locks. Blocking Zenoh queries run in worker threads (`anyio.to_thread`, a generous
limiter: an action may block for minutes while a robot moves).

Caching, and why it is safe: the last published value of an observable property is served
without a round trip while it is fresh, i.e. received while we were subscribed (an observable
property publishes every change) and younger than `max_age` (a safety net against lost samples).
A write or invoke through the adapter empties the Thing's cache when it answers: what was published
during it may be a motion's half-way state, and the samples of the final one may still be on their way
to the loop (the drain thread is slower than the reply's thread on a busy machine: a read right after
a robot's move was once served a position 684 mm short). Until every sample Zenoh had received by
the answer has reached the loop (a local barrier sample behind them, `_settle`), nothing is cached:
reads go to the Thing, whose answer is the truth. A read that raced with a publication does not
overwrite the published value.
"""
from __future__ import annotations

import asyncio
import functools
import itertools
import logging
import time
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

import anyio
import anyio.to_thread
import msgspec

from mesh.backoff import pauses
from mesh.fabric.directory import Directory
from mesh.fabric.drain import Drained
from mesh.fabric.mesh_client import MeshClient, Reply
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from mesh.http.observers import Change, Feed, Observers
from mesh.http.problems import unavailable
from mesh.http.tdrewrite import served_id, with_types
from mesh.wot.invocation import ActionStatus
from mesh.wot.payload import JSON_ERRORS, decode_json
from mesh.wot.problem import BadGateway, BadInput, NotFound, Problem, Unavailable
from mesh.wot.thing_description import ThingDescription, decode_td
from mesh.wot.validate import SourceSchemas, prepare, validate

log = logging.getLogger(__name__)
PUBLICATIONS_WAITING = 100_000  # samples the adapter holds before it drops the oldest (a burst, or an overload)
DIRECTORY = "/directory"  # the feeds of the directory's own notifications (never a Thing name: those are slugs)


@dataclass
class _Cached:
    payload: bytes
    at: float  # monotonic


@dataclass
class ThingEntry:
    name: str
    alive: bool = True
    td: ThingDescription | None = None
    td_error: str | None = None
    source: dict[str, Any] | None = None  # the TD as the Thing serves it: terms the model does not hold
    schemas: SourceSchemas = field(default_factory=lambda: SourceSchemas(None))  # values checked against these
    generation: int = 0  # bumped on each join: a stale TD fetch must not win
    fetch: asyncio.Task | None = None
    values: dict[str, _Cached] = field(default_factory=dict)
    samples: dict[str, int] = field(default_factory=dict)  # publications seen per property
    epoch: int = 0  # bumped around each write/invoke through the adapter
    rendered: dict[str, bytes] = field(default_factory=dict)  # HTTP TD JSON by base URL
    dropped: dict[str, int] = field(default_factory=dict)  # publications refused per affordance (forged, broken)
    refetching: bool = False  # a TD change was announced: readers wait for the Thing's own TD
    settling: set[int] = field(default_factory=set)  # barriers not yet through: cache nothing meanwhile


class Registry:
    """Start with `await start()` on the serving loop; `begin_shutdown()` ends every observer."""

    def __init__(self, session, settings: MeshSettings, *, presence=None, max_age: float = 5.0,
                 fetch_attempts: int = 8, threads: int = 256, feed_size: int = 256, shutdown_grace: float = 0.8):
        """`presence`: a second session for the liveliness tokens (joins and leaves), so that `session`,
        which takes every publication, holds none: a Zenoh client matches each sample it receives
        against every key it knows, and with 5,000 tokens that alone kept a core busy."""
        self.client = MeshClient(session, settings)
        self._presence = presence if presence is not None else session
        self.settings = settings
        self.keys = settings.keys
        self.max_age = max_age
        self.fetch_attempts = fetch_attempts
        self.threads = threads
        self.shutdown_grace = shutdown_grace
        self.closing = False
        self._things: dict[str, ThingEntry] = {}
        self.observers = Observers(feed_size)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._limiter: anyio.CapacityLimiter | None = None
        self._deadline: asyncio.Future[None] | None = None  # resolved `shutdown_grace` after shutdown began
        self._declared: list[Any] = []
        self._barrier_key = f"{self.keys.prefix}/_adapter/{id(self):x}/barrier"  # never leaves this session
        self._barriers = itertools.count()

    # --- lifecycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._deadline = self._loop.create_future()
        self._limiter = anyio.CapacityLimiter(self.threads)
        session = self.client.session
        # publications of every Thing, handed to the loop in batches by a thread of their own (fabric.drain)
        self._declared.append(await self.call(
            Drained, functools.partial(session.declare_subscriber, self.keys.everything()), self._samples,
            PUBLICATIONS_WAITING, True, "adapter-publications"))
        directory = await self.call(Directory, self._presence, self.keys, self._joined, self._left)
        self._declared.append(directory)
        self.client.presence = directory

    def begin_shutdown(self) -> None:
        """End long-polls and SSE streams now, so that the server can stop with them open."""
        if not self.closing and self._deadline is not None:
            self._loop.call_later(self.shutdown_grace, _resolve, self._deadline)  # type: ignore[union-attr]
        self.closing = True
        self.observers.close_all()

    async def close(self) -> None:
        for entry in self._things.values():
            if entry.fetch:
                entry.fetch.cancel()
        for d in reversed(self._declared):  # not via call(): its shutdown deadline has passed
            await anyio.to_thread.run_sync(_undeclare, d)
        self._declared.clear()

    async def call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Run a blocking (Zenoh) call in a worker thread.

        A cancelled request does not wait for its thread; once shutdown began, calls still running
        after `shutdown_grace` answer 503 (the thread is released when the session closes).
        """
        work = asyncio.ensure_future(anyio.to_thread.run_sync(
            functools.partial(fn, *args), limiter=self._limiter, abandon_on_cancel=True))
        # a caller cancelled meanwhile (a Thing that left while its TD was fetched) no longer reads the
        # outcome: it is read here, or asyncio logs "exception was never retrieved" for every such call
        work.add_done_callback(_outcome_read)
        assert self._deadline is not None, "start() first"
        try:
            await asyncio.wait({work, self._deadline}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            if not work.done():
                work.cancel()
        if not work.done() or work.cancelled():
            raise unavailable("the adapter is shutting down", retry_after=1)
        return work.result()

    # --- Zenoh threads: hop to the loop, never block -----------------------------------------
    def _soon(self, fn: Callable[..., None], *args: Any) -> None:
        try:
            self._loop.call_soon_threadsafe(fn, *args)  # type: ignore[union-attr]
        except RuntimeError:  # the loop is closed: we are shutting down
            pass

    def _samples(self, samples: Sequence[Any]) -> None:
        published = []
        for sample in samples:
            key = str(sample.key_expr)
            if key == self._barrier_key:  # every sample before it is in `published` (or already handed on)
                thing, _, barrier = sample.payload.to_bytes().decode().partition("\n")
                published.append((thing, "barrier", barrier, b""))
                continue
            parsed = self.keys.parse(key)
            if parsed is not None and parsed.kind in ("properties", "events", "td") and str(sample.kind).endswith("PUT"):
                published.append((parsed.thing, parsed.kind, parsed.name, sample.payload.to_bytes()))
        if published:
            self._soon(self._on_samples, published)

    def _joined(self, thing: str) -> None:
        self._soon(self._on_join, thing)

    def _left(self, thing: str) -> None:
        self._soon(self._on_leave, thing)

    # --- on the loop -------------------------------------------------------------------------
    def _on_join(self, thing: str) -> None:
        entry = self._things.setdefault(thing, ThingEntry(thing))
        entry.alive = True
        entry.generation += 1
        entry.td, entry.td_error = None, None
        entry.values.clear()
        entry.rendered.clear()
        entry.fetch = asyncio.ensure_future(self._fetch_td(entry, entry.generation))
        log.info("%s joined the mesh", thing)

    def _on_leave(self, thing: str) -> None:
        entry = self._things.get(thing)
        if entry is None:
            return
        entry.alive = False
        entry.values.clear()
        if entry.fetch:
            entry.fetch.cancel()
        self.observers.thing_left(thing)
        if entry.td is not None:
            self._directory_event("thing_deleted", entry)
        log.info("%s left the mesh", thing)

    def _on_samples(self, published: list[tuple[str, str, str, bytes]]) -> None:
        for sample in published:
            self._on_sample(*sample)

    def _on_sample(self, thing: str, kind: str, name: str, payload: bytes) -> None:
        entry = self._things.get(thing)
        if kind == "barrier":
            if entry is not None:
                entry.settling.discard(int(name))
            return
        if entry is None or not entry.alive:
            return
        if kind == "td":
            # a published TD is only a hint that it changed: anyone on the mesh can put one, so the
            # TD is asked of the Thing itself (its queryable), as on a join
            entry.generation += 1
            if entry.fetch:
                entry.fetch.cancel()
            entry.refetching = True
            entry.fetch = asyncio.ensure_future(self._fetch_td(entry, entry.generation))
            entry.fetch.add_done_callback(lambda done: self._refetched(entry, done))
            return
        if entry.td is None:  # not yet checkable, and no misbehaviour: a fleet's sensors publish from the start
            return
        why = self._invalid(entry, kind, name, payload)
        if why is not None:
            key = f"{kind}/{name}"
            entry.dropped[key] = entry.dropped.get(key, 0) + 1
            if entry.dropped[key] == 1:
                log.warning("%s: dropped a publication on %s that its TD does not allow (%s); further ones are "
                            "dropped silently", thing, key, why)
            return
        if kind == "properties":
            entry.samples[name] = entry.samples.get(name, 0) + 1
            if self._observable(entry, name) and not entry.settling:
                entry.values[name] = _Cached(payload, time.monotonic())
        self.observers.publish(thing, kind, Change(name, payload, time.time()))

    @staticmethod
    def _refetched(entry: ThingEntry, done: asyncio.Future) -> None:
        if entry.fetch is done:  # not a fetch that a newer announcement replaced
            entry.refetching = False

    @staticmethod
    def _invalid(entry: ThingEntry, kind: str, name: str, payload: bytes) -> str | None:
        """Why a published value must not be served (None when it may): no TD to check it with, an
        affordance the TD lacks, a payload that is not JSON or breaks the affordance's schema."""
        if entry.td is None:
            return "its TD is not known yet"
        affordance = entry.td.affordance(kind, name)  # type: ignore[arg-type]
        if affordance is None:
            return "no such affordance"
        schema = entry.schemas.of(affordance if kind == "properties" else affordance.data, kind, name,
                                  "" if kind == "properties" else "data")
        try:
            value = decode_json(payload, f"{kind}/{name}") if payload else None
            if payload or schema is not None and kind == "properties":
                validate(value, schema, name)
        except BadInput as e:
            return e.detail
        return None

    async def _fetch_td(self, entry: ThingEntry, generation: int) -> None:
        """A fresh peer's queryables may take a moment to reach us, and a mesh with thousands of Things
        starting may answer late: retry with backoff (up to every 30 s) as long as the Thing is alive,
        saying once when it takes long."""
        attempts = 0
        delays = pauses(0.05, 2.0)
        while True:
            try:
                reply = await self.call(self.client.request, self.keys.td(entry.name), None, None, entry.name)
            except Problem as p:
                attempts += 1
                if attempts == self.fetch_attempts:
                    log.warning("%s: no TD after %d attempts (%s); still trying", entry.name, attempts, p)
            else:
                if entry.generation == generation:
                    self._set_td(entry, reply.payload)
                return
            if entry.generation != generation or not entry.alive:
                return
            await asyncio.sleep(next(delays))
            if attempts == self.fetch_attempts:
                delays = pauses(2.0, 30.0)

    def _set_td(self, entry: ThingEntry, payload: bytes) -> None:
        known = entry.td is not None and entry.source is not None
        previous = entry.source
        try:
            entry.td, entry.td_error = with_types(decode_td(payload)), None
            entry.source = msgspec.json.decode(payload)
            entry.schemas = SourceSchemas(entry.source)
            if not known:  # not a robot's TD regenerated with new bounds: compiling them would slow its serving
                prepare(entry.td)
        except (msgspec.ValidationError, *JSON_ERRORS) as e:
            entry.td_error = f"{entry.name} serves an invalid TD: {e}"
            log.warning(entry.td_error)
        entry.values.clear()
        entry.rendered.clear()
        if entry.td_error is None and not (known and entry.source == previous):
            self._directory_event("thing_updated" if known else "thing_created", entry)

    def _directory_event(self, kind: str, entry: ThingEntry) -> None:
        """The directory's notification (WoT Discovery): `{id, title}` of the Thing that came, changed or went."""
        assert entry.td is not None
        data = {"id": served_id(entry.td, entry.name), "title": entry.name}
        self.observers.publish(DIRECTORY, "events", Change(kind, msgspec.json.encode(data), time.time()))

    @staticmethod
    def _observable(entry: ThingEntry, prop: str) -> bool:
        p = entry.td.properties.get(prop) if entry.td else None
        return bool(p and p.observable)

    # --- for the routes ----------------------------------------------------------------------
    def names(self) -> list[str]:
        """Things alive with a known TD, sorted."""
        return sorted(n for n, e in self._things.items() if e.alive and e.td is not None)

    def known_tds(self) -> dict[str, ThingDescription]:
        """Every TD seen, of Things alive or gone (a gone one still answers 503, not 404)."""
        return {n: e.td for n, e in sorted(self._things.items()) if e.td is not None}

    def _entry(self, thing: str) -> ThingEntry:
        if self.closing:
            raise unavailable("the adapter is shutting down", retry_after=1)
        entry = self._things.get(thing)
        if entry is None:
            raise NotFound(f"no Thing {thing!r} on the mesh")
        if not entry.alive:
            raise unavailable(f"{thing} has left the mesh")
        return entry

    def schemas(self, thing: str) -> SourceSchemas:
        """The Thing's data schemas as its TD document states them (inputs are checked against these)."""
        entry = self._things.get(thing)
        return entry.schemas if entry is not None else SourceSchemas(None)

    async def td(self, thing: str) -> ThingDescription:
        """The Thing's mesh TD; waits for a fetch in progress. 404 unknown, 503 gone or not yet known."""
        entry = self._entry(thing)
        if entry.refetching and entry.fetch is not None and not entry.fetch.done():
            await asyncio.wait({entry.fetch}, timeout=self.settings.query_timeout)  # the TD that was announced
            entry = self._entry(thing)
        if entry.td is None and entry.td_error is None:
            if entry.fetch is None or entry.fetch.done():
                entry.fetch = asyncio.ensure_future(self._fetch_td(entry, entry.generation))
            await asyncio.wait({entry.fetch}, timeout=self.settings.query_timeout)  # never raises its outcome
            entry = self._entry(thing)
        if entry.td_error:
            raise BadGateway(entry.td_error)
        if entry.td is None:
            raise unavailable(f"{thing}'s TD could not be fetched yet", retry_after=1)
        return entry.td

    def render(self, thing: str, base: str,
               make: Callable[[ThingDescription, dict[str, Any] | None], bytes]) -> bytes:
        """The HTTP TD for a base URL, made once per TD version (call after `td()`)."""
        entry = self._entry(thing)
        out = entry.rendered.get(base)
        if out is None:
            if len(entry.rendered) >= 8:  # bases come from Host headers: bound them
                entry.rendered.clear()
            out = entry.rendered[base] = make(entry.td, entry.source)  # type: ignore[arg-type]
        return out

    def cached(self, thing: str, prop: str) -> bytes | None:
        """The fresh cached value `read` would answer without a round trip, else None."""
        entry = self._things.get(thing)
        if entry is None or not entry.alive or self.closing:
            return None
        cached = entry.values.get(prop)
        if cached is None or time.monotonic() - cached.at > self.max_age:
            return None
        return cached.payload

    async def read(self, thing: str, prop: str) -> bytes:
        entry = self._entry(thing)
        cached = entry.values.get(prop)
        if cached is not None and time.monotonic() - cached.at <= self.max_age:
            return cached.payload
        before = (entry.generation, entry.epoch, entry.samples.get(prop, 0))
        reply: Reply = await self.call(self.client.request, self.keys.property(thing, prop), None, None, thing)
        if (entry.alive and (entry.generation, entry.epoch, entry.samples.get(prop, 0)) == before
                and not entry.settling and self._observable(entry, prop)):
            entry.values[prop] = _Cached(reply.payload, time.monotonic())
        return reply.payload

    async def write(self, thing: str, prop: str, payload: bytes) -> None:
        key = self.keys.property(thing, prop)
        await self._mutate(thing, self.client.request, key, payload, self.settings.query_timeout, thing)

    async def invoke(self, thing: str, action: str, payload: bytes | None) -> bytes:
        """The output once the action is over (MeshClient.invoke: short long-poll queries, however long it takes)."""
        return await self._mutate(thing, self.client.invoke_bytes, thing, action, payload)

    async def invoke_async(self, thing: str, action: str, payload: bytes | None) -> ActionStatus:
        """Start the action on the Thing; its status (the Thing checked the input, as for `invoke`)."""
        reply: Reply = await self._mutate(thing, self.client.request, self.keys.action(thing, action), payload,
                                          self.settings.query_timeout, thing, None, "async")
        return self.client.decode_status(reply.payload)

    async def query_action(self, thing: str, action: str, id: str) -> ActionStatus:
        self._entry(thing)
        return await self.call(self.client.query_action, thing, action, id)

    async def cancel_action(self, thing: str, action: str, id: str) -> ActionStatus:
        self._entry(thing)
        return await self.call(self.client.cancel_action, thing, action, id)

    async def query_all_actions(self, thing: str) -> dict[str, list[ActionStatus]]:
        self._entry(thing)
        return await self.call(self.client.query_all_actions, thing)

    async def _mutate(self, thing: str, fn: Callable[..., Any], *args: Any) -> Any:
        """`fn(*args)` in a worker thread, as a change of `thing`: its cache is emptied when it answers
        and stays empty until the samples published before the answer have all been handled."""
        entry = self._entry(thing)
        entry.epoch += 1
        try:
            return await self.call(fn, *args)
        finally:
            entry.epoch += 1
            entry.values.clear()
            self._settle(entry)

    def _settle(self, entry: ThingEntry) -> None:
        """Send a barrier through our own subscription: Zenoh puts a local sample in the channel at once,
        behind every sample already received. Lost (a full channel), it is given up after `max_age`."""
        import zenoh

        barrier = next(self._barriers)
        entry.settling.add(barrier)
        self._loop.call_later(self.max_age, entry.settling.discard, barrier)  # type: ignore[union-attr]
        try:
            self.client.session.put(self._barrier_key, f"{entry.name}\n{barrier}".encode(),
                                    allowed_destination=zenoh.Locality.SESSION_LOCAL)
        except Exception:  # noqa: BLE001 - a closing session: nothing is cached until the deadline
            log.debug("no barrier for %s", entry.name, exc_info=True)

    async def file(self, thing: str, name: str) -> Reply:
        """A linked file. Files are not in the TD's affordances: a Thing that is alive but has no
        queryable for the name answers nothing at all, which means 404 here, not 503."""
        self._entry(thing)
        try:
            return await self.call(self.client.request, self.keys.file(thing, name), None, None, thing)
        except (Unavailable, NotFound):
            self._entry(thing)
            raise NotFound(f"{thing} has no file {name!r}") from None

    def watch(self, thing: str, kind: str, names: list[str]) -> AbstractContextManager[Feed]:
        """A feed of the named properties' changes or events, registered on entry (call after `td()`)."""
        self._entry(thing)
        return self.observers.watch(thing, kind, names)


@contextmanager
def open_registry(settings: MeshSettings) -> Iterator[Registry]:
    """The adapter's view of the mesh on its own two sessions: one takes every publication, the other
    holds the liveliness subscription (thousands of tokens never slow the publications down)."""
    with open_session(settings, service=True) as session, open_session(settings, service=True) as presence:
        yield Registry(session, settings, presence=presence)


def _resolve(future: asyncio.Future[None] | None) -> None:
    if future is not None and not future.done():
        future.set_result(None)


def _undeclare(declared: Any) -> None:
    try:
        (declared.close if isinstance(declared, Directory) else declared.undeclare)()
    except Exception:  # the session may already be closing
        pass


def _outcome_read(work: asyncio.Future) -> None:
    if not work.cancelled():
        work.exception()
