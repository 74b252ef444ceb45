"""The one shape of a device's WoT binding: `bind_<kind>(thing, model) -> Cleanup`.

A binding registers a device model's handlers on an ExposedThing its caller made from the device's
TD (not exposed yet), and returns what undoes the subscriptions it made on the model (a model's
change callbacks, a publisher thread). The caller may wrap handlers before exposing (a guard puts
the real device behind them) and enters the Thing; `serve` does the usual: expose, and on the way
out undo the binding first, so no change is published to a Thing that is gone.

Things that own more than a device model (the world, a robot that re-publishes its generated TD, a
virtual Thing drawing values) are classes with `with`; they are not bindings.
"""
from __future__ import annotations

from contextlib import ExitStack
from typing import Callable

from mesh.fabric.server import ExposedThing

Cleanup = Callable[[], None]


def nothing_to_undo() -> None:
    """The Cleanup of a binding that subscribes to nothing."""


def serve(stack: ExitStack, thing: ExposedThing, cleanup: Cleanup) -> ExposedThing:
    """Expose `thing` on `stack`; leaving the stack undoes the binding, then destroys the Thing."""
    stack.enter_context(thing)
    stack.callback(cleanup)
    return thing
