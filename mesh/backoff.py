"""Doubling pauses between retries, capped: the one backoff every retry loop of the lab uses."""
from __future__ import annotations

from collections.abc import Iterator


def pauses(first: float, longest: float, factor: float = 2.0) -> Iterator[float]:
    """`first`, then `factor` times as long each time, never longer than `longest`; endless (a caller
    stops with its own count or condition: `zip(range(n), pauses(...))`, a deadline, an event)."""
    pause = first
    while True:
        yield pause
        pause = min(pause * factor, longest)


def pause_after(failures: int, first: float, longest: float, factor: float = 2.0) -> float:
    """The pause after `failures` failures in a row (1: `first`), as `pauses` gives them."""
    return min(first * factor ** max(failures - 1, 0), longest)
