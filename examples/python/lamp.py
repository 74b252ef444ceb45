"""Switch a lamp on and read it back, whatever state it is in: a `mesh.consume()` script.

    python examples/python/lamp.py [ADAPTER_URL] [THING]     # default http://127.0.0.1:8080 light-left

It observes `lightState` before anything else, so no change can slip by between reading and acting;
then it reads the state (the lamp may already be on: an observation brings changes only, and a lamp
that is on already sends none), switches the lamp on (the action answers once it is done) and waits
for the change only when there is one to come. It prints one JSON line: the state before and after,
and the colour.
"""
from __future__ import annotations

import json
import sys

import mesh
from mesh.wot.consumed import Inbox


def switch_on(base: str, name: str) -> dict:
    with mesh.consume(f"{base.rstrip('/')}/{name}") as lamp:
        changes = Inbox()
        watching = lamp.observe_property("lightState", changes)  # first: from here on no change is missed
        try:
            before = lamp.read_property("lightState")
            lamp.invoke_action("switchOn")  # synchronous: the lamp is on when this returns
            if before is not True:
                while changes.get(timeout=10) is not True:  # NothingArrived (a mesh.Problem) after 10 s
                    pass
        finally:
            watching.stop()
        after = lamp.read_multiple_properties(["lightState", "lightColor"])
    return {"thing": name, "before": before, "after": after["lightState"], "color": after["lightColor"]}


def main(argv: list[str]) -> int:
    base = argv[1] if len(argv) > 1 else "http://127.0.0.1:8080"
    name = argv[2] if len(argv) > 2 else "light-left"
    try:
        result = switch_on(base, name)
    except mesh.Problem as problem:  # no lab at that address, no such Thing, no change in time...
        print(f"lamp.py: {problem}", file=sys.stderr)
        return 1
    print(json.dumps(result))
    return 0 if result["after"] is True else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
