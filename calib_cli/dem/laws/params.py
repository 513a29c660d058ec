"""A contact law's own parameter: a value of the interaction (EDEM's interaction table) that only
that law reads, declared once with its default, bounds and meaning. The interaction, the heap test's
parameter list, the walls' rule and the validation all take it from the declaration
(:mod:`calib_cli.dem.materials`, :mod:`calib_cli.dem.heap`)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Param:
    name: str
    default: float
    low: float
    high: float
    unit: str
    doc: str
    #: a fixed setting of the law (chosen, like a law switch, and shared by the walls), not a value the
    #: calibration moves
    setting: bool = False
    #: the walls never take the grains' value (no wall holds a liquid bridge): 0 at the floor and the cylinder
    wall_zero: bool = False
    low_open: bool = False
    high_open: bool = False

    def check(self, value: float) -> str | None:
        """Why ``value`` is not allowed (None when it is)."""
        if not math.isfinite(value):
            return f"{self.name} must be finite"
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        if above and below:
            return None
        interval = f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"
        return f"{self.name} ({self.doc}) must lie in {interval}{' ' + self.unit if self.unit else ''}"
