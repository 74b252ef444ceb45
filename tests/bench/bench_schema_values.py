"""What a virtual Thing's values cost: every schema of the TD corpus (tests/data/td-corpus, the real
lab's TDs, tests/data/tds), its preparation (the time to its first value: the pool built at start,
validators compiled) and each live value after, the worst named; beside them, in the same run, the
validator alone on one valid value of the same schema (the floor: every value given out is checked).

    python tests/bench/bench_schema_values.py [--values 50] [--worst 8]
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import msgspec

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from devices.things.virtual import schemas_of  # noqa: E402
from mesh.wot import schema_values  # noqa: E402
from mesh.wot.schema_values import NoValue, SchemaValues  # noqa: E402
from mesh.wot.validate import validate  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"


def corpus() -> list[tuple[str, object]]:
    """(where, schema) for every property, action output and event data of the corpus."""
    files = [p for folder in ("td-corpus", "reference-tds/real-lab", "tds") for p in sorted((DATA / folder).rglob("*"))
             if p.suffix in (".json", ".jsonld") and "refused" not in p.parts]
    out = []
    for path in files:
        td = json.loads(path.read_text())
        for schema, where in schemas_of(td):
            out.append((f"{path.relative_to(DATA)}#/{'/'.join(where)}", schema))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--values", type=int, default=50, help="live values timed per schema")
    ap.add_argument("--worst", type=int, default=8, help="schemas named, slowest first")
    args = ap.parse_args()
    started = time.perf_counter()  # the process's first schema loads jsonschema and rstr: said apart
    SchemaValues(0).prepare({"type": "integer", "minimum": 0, "maximum": 9})
    cold = time.perf_counter() - started
    rows = []
    refused = []
    for where, schema in corpus():
        schema_values._plans.clear()
        values = SchemaValues(1)
        started = time.perf_counter()
        try:
            values.prepare(schema, where)
        except NoValue as e:
            refused.append(str(e))
            continue
        first = time.perf_counter() - started
        started = time.perf_counter()
        drawn = [values.value(schema) for _ in range(args.values)]
        each = (time.perf_counter() - started) / args.values
        started = time.perf_counter()
        for v in drawn:
            validate(v, schema, path="value")
        check = (time.perf_counter() - started) / args.values
        plan = schema_values._plans.get(msgspec.json.encode(schema))
        rows.append((first, each, check, where, getattr(plan, "live", None), len(getattr(plan, "pool", []))))
    firsts = sorted(r[0] for r in rows)
    eaches = sorted(r[1] for r in rows)
    checks = sorted(r[2] for r in rows)

    def ms(x: float) -> str:
        return f"{x * 1000:.2f} ms"

    print(f"{len(rows)} schemas served, {len(refused)} refused; the process's first schema (imports): {ms(cold)}")
    print(f"first value (prepare): median {ms(statistics.median(firsts))}, p95 {ms(firsts[int(0.95 * len(firsts))])}, "
          f"max {ms(firsts[-1])}, all {sum(firsts):.2f} s")
    print(f"each value after:      median {ms(statistics.median(eaches))}, p95 {ms(eaches[int(0.95 * len(eaches))])}, "
          f"max {ms(eaches[-1])}")
    print(f"baseline, the validator alone on a valid value: median {ms(statistics.median(checks))}, max {ms(checks[-1])}")
    print(f"slowest first values (of {args.values} values each; live: drawn per call, else from the pool):")
    for first, each, check, where, live, pool in sorted(rows, reverse=True)[:args.worst]:
        print(f"  {ms(first):>10s} first, {ms(each):>9s} each (validator {ms(check)}), "
              f"{'live' if live else 'pool'} {pool}: {where}")
    slow_each = max(rows, key=lambda r: r[1])
    print(f"slowest per value: {ms(slow_each[1])} {slow_each[3]}")
    for line in refused:
        print(f"  refused: {line}")


if __name__ == "__main__":
    main()
