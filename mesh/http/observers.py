"""Observers of the mesh's notifications: one bounded queue (`Feed`) per long-poll GET or SSE stream.

Property changes and events arrive once on the adapter's Zenoh subscriber and are fanned out here
to every feed watching that affordance. Everything runs on the event loop; a slow reader loses its
oldest notification rather than ever blocking the mesh side.
"""
from __future__ import annotations

import asyncio
import logging
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Iterator

from mesh.http.problems import unavailable

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Change:
    """One notification: a property's new value or an event's data (JSON bytes)."""

    name: str
    payload: bytes
    at: float  # wall-clock time it reached the adapter


_GONE, _CLOSED = object(), object()


class Feed:
    """What one observer reads: the changes of one or more affordances of a Thing, in order."""

    def __init__(self, thing: str, size: int):
        self.thing = thing
        self._queue: asyncio.Queue[Any] = asyncio.Queue(size)

    def push(self, item: Any) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            log.warning("observer of %s too slow: dropped a notification", self.thing)
        self._queue.put_nowait(item)

    async def next(self) -> Change:
        """The next notification; Unavailable when the Thing left or the adapter is closing."""
        item = await self._queue.get()
        if item is _GONE:
            raise unavailable(f"{self.thing} has left the mesh")
        if item is _CLOSED:
            raise unavailable("the adapter is shutting down", retry_after=1)
        return item


class Observers:
    """Feeds by (thing, kind, affordance name)."""

    def __init__(self, feed_size: int = 256):
        self.feed_size = feed_size
        self._feeds: dict[tuple[str, str, str], set[Feed]] = {}
        self._everything: set[Feed] = set()  # the control page's one stream per browser tab

    def count(self) -> int:
        """Observers connected now (each feed once, however many affordances it watches)."""
        return len({id(feed) for feeds in self._feeds.values() for feed in feeds}) + len(self._everything)

    def publish(self, thing: str, kind: str, change: Change) -> None:
        for feed in self._feeds.get((thing, kind, change.name), ()):
            feed.push(change)
        if self._everything:
            named = Change(f"{thing}/{kind}/{change.name}", change.payload, change.at)
            for feed in self._everything:
                feed.push(named)

    def thing_left(self, thing: str) -> None:
        for (name, _, _), feeds in self._feeds.items():
            if name == thing:
                for feed in feeds:
                    feed.push(_GONE)

    def close_all(self) -> None:
        for feeds in [*self._feeds.values(), self._everything]:
            for feed in feeds:
                feed.push(_CLOSED)

    @contextmanager
    def watch_everything(self) -> Iterator[Feed]:
        """Every notification of every Thing (and the directory's), named `<thing>/<kind>/<name>`: a
        browser gets six connections per host, so a page showing the whole lab uses one stream."""
        feed = Feed("the lab", self.feed_size * 8)
        self._everything.add(feed)
        try:
            yield feed
        finally:
            self._everything.discard(feed)

    @contextmanager
    def watch(self, thing: str, kind: str, names: list[str]) -> Iterator[Feed]:
        """A feed registered for the named affordances while the `with` block runs."""
        feed = Feed(thing, self.feed_size)
        keys = [(thing, kind, n) for n in names]
        for key in keys:
            self._feeds.setdefault(key, set()).add(feed)
        try:
            yield feed
        finally:
            for key in keys:
                feeds = self._feeds.get(key)
                if feeds is not None:
                    feeds.discard(feed)
                    if not feeds:
                        del self._feeds[key]
