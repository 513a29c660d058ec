"""Factors and the parameter space: natural units <-> coded units.

Coded units follow the usual DOE convention (Myers & Montgomery, RSM, ch. 2):
``x = (2 v - (high + low)) / (high - low)`` so that ``low -> -1``, ``high -> +1``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from .errors import CalibError

#: The response every stage models.
RESPONSE = "repose_angle"


@dataclass(frozen=True)
class Factor:
    """One calibrated parameter with its unit and design range (natural units)."""

    name: str
    low: float
    high: float
    unit: str = "-"
    label: str = ""
    symbol: str = ""

    def __post_init__(self) -> None:
        for v, what in ((self.low, "low"), (self.high, "high")):
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise CalibError(f"factor {self.name!r}: {what} must be a finite number, got {v!r}")
        if not self.high > self.low:
            raise CalibError(
                f"factor {self.name!r}: high ({self.high}) must be greater than low ({self.low})"
            )

    @property
    def center(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def half_range(self) -> float:
        return 0.5 * (self.high - self.low)

    def to_coded(self, v):
        return (np.asarray(v, dtype=float) - self.center) / self.half_range

    def to_natural(self, x):
        return self.center + np.asarray(x, dtype=float) * self.half_range

    def with_range(self, low: float, high: float) -> "Factor":
        return Factor(self.name, float(low), float(high), self.unit, self.label, self.symbol)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ParameterSpace:
    """An ordered set of factors (the design space of one stage)."""

    factors: tuple[Factor, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        names = [f.name for f in self.factors]
        if len(set(names)) != len(names):
            raise CalibError(f"duplicate factor names in {names}")
        if not names:
            raise CalibError("a parameter space needs at least one factor")

    @classmethod
    def of(cls, factors: Iterable[Factor]) -> "ParameterSpace":
        return cls(tuple(factors))

    @classmethod
    def from_dicts(cls, rows: Iterable[Mapping]) -> "ParameterSpace":
        return cls(tuple(Factor(**dict(r)) for r in rows))

    @property
    def names(self) -> list[str]:
        return [f.name for f in self.factors]

    @property
    def lows(self) -> np.ndarray:
        return np.array([f.low for f in self.factors])

    @property
    def highs(self) -> np.ndarray:
        return np.array([f.high for f in self.factors])

    def __len__(self) -> int:
        return len(self.factors)

    def __getitem__(self, name: str) -> Factor:
        for f in self.factors:
            if f.name == name:
                return f
        raise CalibError(f"unknown factor {name!r}; known: {', '.join(self.names)}")

    def subset(self, names: Sequence[str]) -> "ParameterSpace":
        return ParameterSpace(tuple(self[n] for n in names))

    def to_coded(self, natural) -> np.ndarray:
        """Natural (n, k) array -> coded (n, k)."""
        v = np.atleast_2d(np.asarray(natural, dtype=float))
        return (v - 0.5 * (self.lows + self.highs)) / (0.5 * (self.highs - self.lows))

    def to_natural(self, coded) -> np.ndarray:
        """Coded (n, k) array -> natural (n, k)."""
        x = np.atleast_2d(np.asarray(coded, dtype=float))
        return 0.5 * (self.lows + self.highs) + x * 0.5 * (self.highs - self.lows)

    def to_dicts(self) -> list[dict]:
        return [f.to_dict() for f in self.factors]

    @classmethod
    def from_data(cls, data, names: Sequence[str], template: "ParameterSpace | None" = None):
        """Coding from each factor's min and max in a responses table.

        Used when no design is in the run directory (``analyze --responses``);
        units and labels are taken from ``template`` where it knows the factor.
        """
        facs = []
        for n in names:
            col = np.asarray(data[n], dtype=float)
            lo, hi = float(np.min(col)), float(np.max(col))
            if not hi > lo:
                raise CalibError(f"factor {n!r} has a single level ({lo:g}) in the responses; it cannot be analysed")
            base = None
            if template is not None and n in template.names:
                base = template[n]
            facs.append(Factor(n, lo, hi, base.unit if base else "-", base.label if base else "", base.symbol if base else ""))
        return cls(tuple(facs))
