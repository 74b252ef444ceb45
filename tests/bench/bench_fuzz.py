"""A longer fuzz run of the iot-lab over HTTP than CI's: every affordance, valid and almost-valid inputs
from its own schema (hypothesis-jsonschema), and what came back: requests, statuses, the slowest answer.
It prints; the pass/fail rules are the test's (tests/test_fuzz_affordances.py).

    python tests/bench/bench_fuzz.py [--examples 50]
"""
from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path

import httpx
from hypothesis import given, settings
from hypothesis_jsonschema import from_schema

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs and the fuzz test's helpers

from labs import start_lab  # noqa: E402
from test_fuzz_affordances import _finite, almost, rest, send, targets  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--examples", type=int, default=50, help="valid and almost-valid inputs per affordance")
    args = ap.parse_args()
    profile = settings(max_examples=args.examples, deadline=None, database=None, derandomize=False)
    statuses: collections.Counter = collections.Counter()
    slowest = (0.0, "")
    with tempfile.TemporaryDirectory() as tmp:
        lab = start_lab(Path(tmp), None, http=True, extra_args=("--speed", "max", "--samples", "3000",
                                                               "--tdgen-cache", str(Path(tmp) / "cache")))
        try:
            with httpx.Client(base_url=lab.http, timeout=300) as http:
                tds = {td["title"]: td for td in http.get("/things").json()}
                t0 = time.monotonic()
                for thing, td in sorted(tds.items()):
                    for kind, name, schema, drawn in targets(thing, td):
                        def record(value, label: str) -> None:
                            nonlocal slowest
                            started = time.monotonic()
                            r = send(http, thing, kind, name, value)
                            took = time.monotonic() - started
                            statuses[(label, r.status_code)] += 1
                            if took > slowest[0]:
                                slowest = (took, f"{r.request.method} /{thing}/{kind}/{name} -> {r.status_code}")
                            rest(http, thing, td)

                        given(value=from_schema(drawn).filter(_finite))(profile(lambda value: record(value, "valid")))()
                        given(value=almost(schema))(profile(lambda value: record(value, "almost")))()
                seconds = time.monotonic() - t0
        finally:
            lab.stop()
    total = sum(statuses.values())
    print(f"{total} requests in {seconds:.0f} s over {len(tds)} Things")
    for (label, status), n in sorted(statuses.items()):
        print(f"  {label:7s} {status}: {n}")
    print(f"5xx: {sum(n for (_, s), n in statuses.items() if s >= 500)}")
    print(f"slowest answer: {slowest[0] * 1000:.0f} ms ({slowest[1]})")


if __name__ == "__main__":
    main()
