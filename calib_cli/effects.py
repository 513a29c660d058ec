"""A physical effect the discrepancy loop can add to a model: one parameter, its bounds, the value at
which it is off, and how its misfit shows across conditions (diagnose's words).

Kept apart from :mod:`calib_cli.model` so that a contact law can declare the effect it brings
(:mod:`calib_cli.dem.laws`) without the DEM engine importing the model's machinery.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Effect:
    name: str
    parameter: str
    low: float
    high: float
    neutral: float  # the value at which the effect is off
    step: float  # the step away from neutral that diagnose simulates
    description: str
    signature: str  # how its misfit shows across conditions (diagnose's words)
    #: an absent effect's parameter is written into every simulation at its neutral value; an effect
    #: added after heaps were cached leaves it out instead (the heap's own default is the same "off"),
    #: so that the cache keys of the heaps made before it stay what they were
    pinned_when_absent: bool = True
    unit: str = "-"  # the parameter's unit ("-": dimensionless)

    @property
    def two_sided(self) -> bool:
        """No neutral value (NaN: a wall's value defaults to the grains' own), so the effect can act
        either way from where the model stands."""
        return math.isnan(self.neutral)

    @property
    def tied(self) -> str | None:
        """The grains' parameter a two-sided (wall) effect's value defaults to while it is absent; None for
        an effect with a neutral value."""
        return self.parameter.replace("wall_", "") if self.two_sided else None

    def probe(self, theta: dict[str, float]) -> tuple[float, float]:
        """The two values of the parameter whose simulations give diagnose's sensitivity
        g = (angle(b) - angle(a)) / (b - a).

        With a neutral value: a forward step from it, (neutral, neutral + step); the model's own
        simulations stand at a. Without one (two-sided): a central difference over the same span
        around the value the model implies (the grains' own: wall_static_friction starts at
        theta's static_friction), clipped to the bounds. A forward step from a calibrated 0.30 to
        0.50 lands where friction no longer matters and misses a slipperier wall."""
        start = self.start(theta)
        if not self.two_sided:
            return start, start + self.step
        return max(start - self.step / 2, self.low), min(start + self.step / 2, self.high)

    def start(self, theta: dict[str, float]) -> float:
        """The value the model implies while the effect is absent: neutral, or the grains' own."""
        if not self.two_sided:
            return self.neutral
        return float(theta.get(self.tied, 0.5))
