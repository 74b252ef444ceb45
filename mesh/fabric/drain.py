"""Subscriptions read by a thread of their own, in batches, so that Zenoh's receive threads never wait.

A Python callback run on Zenoh's receive thread (`session.direct`) needs the GIL; in a process whose
other threads are busy in Python, it waits up to a switch interval (5 ms) per sample, the session
stops reading its link, and the router, whose queue to it stays full, closes the link after 5 s
(the adapter of a 5,000-device fleet: 2,000 readings a second; it lost its session every minute and
listed its Things again from zero). Here Zenoh only puts each sample in a channel (no GIL), and one
thread per subscription takes whatever is there and hands it on as one batch.
"""
from __future__ import annotations

import logging
import threading
from typing import Any, Callable, Sequence

log = logging.getLogger(__name__)

Batch = Callable[[Sequence[Any]], None]
LARGEST_BATCH = 1000


class Drained:
    """`declare(handler)` (a Zenoh subscriber declaration), read by a thread that calls `on_batch` with
    every sample waiting, oldest first. `lossy`: a ring that drops the oldest samples when `capacity`
    are waiting (publications, which Zenoh itself drops under congestion); otherwise a FIFO that makes
    Zenoh wait when full (liveliness: a join or leave must not be lost)."""

    def __init__(self, declare: Callable[[Any], Any], on_batch: Batch, capacity: int, lossy: bool,
                 name: str = "zenoh-drain"):
        import zenoh

        handler: Any = zenoh.handlers.RingChannel(capacity) if lossy else zenoh.handlers.FifoChannel(capacity)
        self._subscriber = declare(handler)
        self._on_batch = on_batch
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sub = self._subscriber.handler  # the channel: undeclaring the subscriber ends a recv() waiting on it
        while True:
            try:
                batch = [sub.recv()]  # releases the GIL while it waits
                while len(batch) < LARGEST_BATCH and (more := sub.try_recv()) is not None:
                    batch.append(more)
            except Exception:  # noqa: BLE001 - the channel ends when the subscriber is undeclared
                return
            try:
                self._on_batch(batch)
            except Exception:  # a listener's bug must not end the subscription
                log.exception("a subscriber's listener failed")

    def undeclare(self) -> None:
        self._subscriber.undeclare()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
