"""Waiting on events in tests: `eventually` polls a condition until it holds, never a fixed sleep.

A busy machine only makes a wait longer; it never makes a test pass or fail by timing. The timeout
is a last resort that names what was awaited.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def eventually(condition: Callable[[], T], timeout: float = 60.0, interval: float = 0.02, what: str = "",
               longest: float = 0.5) -> T:
    """Call `condition` until it returns something truthy (returned) or raises nothing falsy in time.

    An AssertionError from `condition` counts as "not yet", so `lambda: check(x)` with asserts inside
    works; the last one is re-raised at the timeout, which is what a failing test should show.
    """
    deadline = time.monotonic() + timeout
    delay = interval
    last: BaseException | None = None
    while True:
        try:
            value = condition()
            if value:
                return value
            last = None
        except AssertionError as e:
            last = e
        if time.monotonic() > deadline:
            if last is not None:
                raise last
            raise AssertionError(f"not true after {timeout:.0f} s: {what or getattr(condition, '__name__', condition)}")
        time.sleep(delay)
        delay = min(delay * 1.5, max(longest, interval))


def always(condition: Callable[[], object], duration: float, interval: float = 0.05, what: str = "") -> None:
    """Assert that `condition` holds on every check for `duration` seconds: a negative observation
    ("it stays where it stopped", "nothing is served"), the window being the claim itself. Use it
    only where no event can say "it will not happen"; it never stands in for waiting on something."""
    deadline = time.monotonic() + duration
    while True:
        assert condition(), f"stopped holding: {what or getattr(condition, '__name__', condition)}"
        if time.monotonic() >= deadline:
            return
        time.sleep(interval)


def subscribed(session, key: str, timeout: float = 60.0) -> None:
    """Return once a subscriber matching `key` is declared where `session` can see it: a Zenoh matching
    listener on a publisher of `key` (declare it on the publishing side's session: that is the view
    that decides whether a publication reaches the subscriber). For "the subscription is declared"."""
    publisher = session.declare_publisher(key)
    matched = threading.Event()
    listener = publisher.declare_matching_listener(lambda status: status.matching and matched.set())
    try:
        if not (publisher.matching_status or matched.wait(timeout)):
            raise AssertionError(f"no subscriber matching {key} declared within {timeout:.0f} s")
    finally:
        listener.undeclare()
        publisher.undeclare()


def seconds_until(check: Callable[[], object], limit: float) -> float | None:
    """Seconds until `check()` holds, asked again at once (a benchmark's figure, whose checks take their own
    time: a screenshot); None when it does not hold within `limit`."""
    started = time.perf_counter()
    while not check():
        if time.perf_counter() - started > limit:
            return None
    return time.perf_counter() - started
