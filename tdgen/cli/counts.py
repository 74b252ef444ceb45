"""A sample count as people write it: 80000, 80_000, 8e4 or 1e6 (`--samples 1e6`)."""
from __future__ import annotations

import math

import click


class SampleCount(click.ParamType):
    """A whole number of at least `minimum`, given as digits, with `_` separators, or in e-notation."""

    name = "count"

    def __init__(self, minimum: int = 1):
        self.minimum = minimum

    def convert(self, value, param, ctx) -> int:
        if isinstance(value, int):
            count = value
        else:
            text = str(value).strip().replace("_", "")
            try:
                count = int(text)
            except ValueError:
                try:
                    number = float(text)
                except ValueError:
                    self.fail(f"{value!r} is not a number of samples (digits, 80_000 or 8e4)", param, ctx)
                if not math.isfinite(number) or number != int(number):
                    self.fail(f"{value!r} is not a whole number of samples", param, ctx)
                count = int(number)
        if count < self.minimum:
            self.fail(f"{value!r} is below the least number of samples, {self.minimum}", param, ctx)
        return count
