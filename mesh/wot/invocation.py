"""Asynchronous actions, protocol-neutral: an invocation's status (the WoT Profile's ActionStatus),
the store that keeps a Thing's invocations for a while, and the cancellation a running handler heeds.

Handlers take no cancellation argument: the invocation being served sits in a context variable
(`current_cancellation()`), and what waits on simulated time (`devices.sim.pybullet_world.World.play`) stops
when it is cancelled. So every device whose actions move something can be cancelled without
knowing about invocations, and an action that moves nothing simply completes.
"""
from __future__ import annotations

import contextvars
import logging
import threading
import time
import uuid
from collections import OrderedDict
from concurrent.futures import Executor
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Callable, Literal

import msgspec

from mesh.wot.problem import Conflict, NotFound, Problem

log = logging.getLogger(__name__)

Status = Literal["pending", "running", "completed", "failed", "cancelled"]
FINISHED: frozenset[str] = frozenset({"completed", "failed", "cancelled"})
ID = r"[0-9a-f]{32}"  # what an invocation id looks like (uuid4 hex): checked before it reaches a key or URL


class ActionStatus(msgspec.Struct, omit_defaults=True):
    """One invocation as a client sees it (WoT Profile 1.0 §Asynchronous Action Response, plus `id`,
    `action` and the `cancelled` status the profile's successors add); times are RFC 3339 UTC."""

    id: str
    action: str
    status: Status
    timeRequested: str
    output: Any = None
    error: dict[str, Any] | None = None  # the problem+json of a failed or cancelled invocation
    href: str | None = None              # where to query it (set by the binding that serves it)
    timeStarted: str | None = None
    timeEnded: str | None = None


class ActionCancelled(Conflict):
    """The invocation was cancelled while it ran: the device stopped where it was."""

    slug, title = "action-cancelled", "Action cancelled"


class Cancellation:
    """The cancel signal of one invocation. Callbacks registered with `on_cancel` run once, on the
    thread that cancels (so they must not block); one registered after the cancel runs at once."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._callbacks: list[Callable[[], None]] = []
        self.requested = False

    def cancel(self) -> None:
        with self._lock:
            if self.requested:
                return
            self.requested = True
            callbacks, self._callbacks = self._callbacks, []
        for fn in callbacks:
            try:
                fn()
            except Exception:
                log.exception("a cancel callback failed")

    def on_cancel(self, fn: Callable[[], None]) -> Callable[[], None]:
        """Call `fn` when cancelled; returns a function that unregisters it."""
        with self._lock:
            if not self.requested:
                self._callbacks.append(fn)
                return lambda: self._forget(fn)
        fn()
        return lambda: None

    def _forget(self, fn: Callable[[], None]) -> None:
        with self._lock:
            if fn in self._callbacks:
                self._callbacks.remove(fn)


_current: contextvars.ContextVar[Cancellation | None] = contextvars.ContextVar("twinmesh_cancellation", default=None)


def current_cancellation() -> Cancellation | None:
    """The cancellation of the asynchronous invocation this thread is running, if it runs one."""
    return _current.get()


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


@dataclass
class _Entry:
    status: ActionStatus
    hidden: bool = False  # a synchronous call carried as an asynchronous one: not listed, gone once delivered
    token: Cancellation = field(default_factory=Cancellation)
    ended: threading.Event = field(default_factory=threading.Event)
    ended_at: float = 0.0  # monotonic


class Invocations:
    """A Thing's asynchronous invocations. Unfinished ones are always kept; finished ones for
    `keep_for` seconds and at most `keep` of them (the oldest go first), so a client polling late
    still finds its answer and a busy Thing does not grow without bound."""

    def __init__(self, executor: Executor, keep: int = 256, keep_for: float = 600.0):
        self._executor = executor
        self.keep, self.keep_for = keep, keep_for
        self._lock = threading.Lock()
        self._entries: OrderedDict[str, _Entry] = OrderedDict()

    def start(self, action: str, run: Callable[[], Any], hidden: bool = False) -> ActionStatus:
        """Queue `run()` (its input already checked); the status says `pending` until a worker takes it.
        A `hidden` invocation (a caller waiting for it synchronously) is not listed by `all()` and is
        forgotten once `wait` has delivered its end."""
        entry = _Entry(ActionStatus(id=uuid.uuid4().hex, action=action, status="pending", timeRequested=now()),
                       hidden)
        with self._lock:
            self._prune()
            self._entries[entry.status.id] = entry
        self._executor.submit(self._run, entry, run)
        return self._copy(entry)

    def get(self, id: str) -> ActionStatus:
        with self._lock:
            self._prune()
            return self._copy(self._find(id))

    def wait(self, id: str, seconds: float) -> ActionStatus:
        """Its status once it ended, or after `seconds` (a long poll: the end is told at once)."""
        with self._lock:
            entry = self._find(id)
        entry.ended.wait(seconds)
        with self._lock:
            if entry.hidden and entry.status.status in FINISHED:
                self._entries.pop(id, None)
            return self._copy(entry)

    def all(self, action: str | None = None) -> list[ActionStatus]:
        """Every kept invocation (of one action), oldest first."""
        with self._lock:
            self._prune()
            return [self._copy(e) for e in self._entries.values()
                    if action in (None, e.status.action) and not e.hidden]

    def cancel(self, id: str, wait: float = 5.0) -> ActionStatus:
        """Ask the invocation to stop and wait up to `wait` s for it to end; 409 with its final status if
        it ended otherwise than by this cancel (before it, or finishing while it was being asked)."""
        with self._lock:
            entry = self._find(id)
            ended = entry.status.status in FINISHED
        if not ended:
            entry.token.cancel()
            entry.ended.wait(wait)
        with self._lock:
            status = self._copy(entry)
        if ended or status.status in ("completed", "failed"):
            raise Conflict(f"invocation {id} of {status.action!r} has already ended ({status.status})",
                           reason="already-ended", extra={"status": status.status, "final": msgspec.to_builtins(status)})
        return status

    def cancel_all(self) -> None:
        """Stop everything under way (the Thing is going away)."""
        with self._lock:
            entries = list(self._entries.values())
        for entry in entries:
            entry.token.cancel()

    # --- worker threads ----------------------------------------------------------------------------
    def _run(self, entry: _Entry, run: Callable[[], Any]) -> None:
        st = entry.status
        if entry.token.requested:  # cancelled while it waited for a worker: it never starts
            self._end(entry, "cancelled", error=ActionCancelled(f"{st.action} was cancelled before it started"))
            return
        with self._lock:
            st.status, st.timeStarted = "running", now()
        reset = _current.set(entry.token)
        try:
            output = run()
        except Problem as p:
            self._end(entry, "cancelled" if entry.token.requested else "failed", error=p)
        except Exception as e:  # a device bug still ends the invocation, with the reason
            log.exception("%s: asynchronous invocation failed", st.action)
            self._end(entry, "failed", error=Problem(f"{type(e).__name__}: {e}"))
        else:
            self._end(entry, "completed", output=output)
        finally:
            _current.reset(reset)

    def _end(self, entry: _Entry, status: Status, output: Any = None, error: Problem | None = None) -> None:
        with self._lock:
            st = entry.status
            st.status, st.output, st.timeEnded = status, output, now()
            st.error = msgspec.to_builtins(error.details()) if error is not None else None
            entry.ended_at = time.monotonic()
        entry.ended.set()

    # --- under the lock ------------------------------------------------------------------------------
    def _find(self, id: str) -> _Entry:
        entry = self._entries.get(id)
        if entry is None:
            raise NotFound(f"no invocation {id!r} (unknown, or it ended more than {self.keep_for:g} s ago)")
        return entry

    def _prune(self) -> None:
        finished = [k for k, e in self._entries.items() if e.status.status in FINISHED]
        too_old = time.monotonic() - self.keep_for
        for n, key in enumerate(finished):
            if len(finished) - n > self.keep or self._entries[key].ended_at < too_old:
                del self._entries[key]

    @staticmethod
    def _copy(entry: _Entry) -> ActionStatus:
        return msgspec.structs.replace(entry.status)
