"""Every value a user gives, declared once: the contact parameters a heap test takes, the heap-test
(condition) variables of a rig, the repose angle and the grains' shear modulus. Each with its unit,
the range the model accepts (outside it no heap can be made), the range a real material or rig
plausibly has and why, its default and what reads it. Entry points (conditions and angles files,
settings, ``--set``, ``-s``, ``--condition``, ``--target``) check a value with :func:`check`: outside
the plausible range a one-line error names the likely mistake ("0.004 mm grains: are these metres?");
``CALIB_ALLOW_EXTREME=1`` lets a deliberate extreme through (the accepted range still holds).

A contact law's own parameters (a capillary bridge's volume, a contact angle) are declared with their
law (:mod:`calib_cli.dem.laws`); this module imports nothing heavy, so that the CLI can read it at once.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass

from .errors import CalibError

#: the heap presets' names (calib_cli.dem.heap.PRESETS holds them; here for checks that import nothing heavy)
PRESET_NAMES = ("smoke", "default", "paper")
#: what a heap's state arrays store (calib_cli.dem.system.PRECISIONS holds them; here for the same reason)
PRECISION_NAMES = ("double", "mixed")
#: the engines a run's settings may name (calib_cli.heaps.inputs.RUN_ENGINES; here for the same reason; LAMMPS
#: is a command's --engine alone)
ENGINE_NAMES = ("builtin", "gpu")
#: set to 1 to accept a value outside the plausible range (inside the accepted one)
ALLOW_EXTREME = "CALIB_ALLOW_EXTREME"


@dataclass(frozen=True)
class Quantity:
    """One value's facts. ``low``/``high``: what the model accepts (``low_open``: strictly above low);
    ``plausible``: what a real material or rig has (``why``: the reason); ``mistakes``: (factor, what)
    pairs, a value that ``factor`` times over lands in the plausible range was probably given in ``what``."""

    name: str
    unit: str
    default: float
    low: float
    high: float
    plausible: tuple[float, float]
    why: str
    doc: str
    used_by: str
    low_open: bool = False
    mistakes: tuple[tuple[float, str], ...] = ()

    def accepts(self, v: float) -> bool:
        return math.isfinite(v) and (v > self.low if self.low_open else v >= self.low) and v <= self.high

    def likely(self, v: float) -> str:
        """What ``v`` was probably meant as, or ''."""
        lo, hi = self.plausible
        for factor, what in self.mistakes:
            if lo <= v * factor <= hi:
                return f": {what} ({_g(v * factor)} {self.unit})?"
        return ""


def _g(v: float) -> str:
    return f"{v:.4g}"


_LENGTH = ((1000.0, "are these metres"), (10.0, "are these centimetres"))
_ANGLE = ((180.0 / math.pi, "is this in radians"),)

#: the contact parameters of the grains (paper Table 2) and of the walls (``wall_*``: floor and cylinder,
#: ``cylinder_*``: the cylinder alone, ``floor_*``: the rig's floor, a condition variable)
PARAMETERS: dict[str, Quantity] = {q.name: q for q in (
    Quantity("static_friction", "", 0.5, 0.0, 10.0, (0.05, 1.5),
       "sliding friction coefficients of grains, rock and concrete lie in 0.1-1.2", "sliding (Coulomb) friction "
       "coefficient", "the tangential laws"),
    Quantity("rolling_friction", "", 0.1, 0.0, 10.0, (0.0, 0.6),
       "rolling resistance coefficients of real grains lie in 0-0.5 (the paper's Table 6: 0.1-0.33)",
       "rolling resistance coefficient", "the rolling laws"),
    Quantity("restitution", "", 0.2, 0.0, 1.0, (0.05, 1.0),
       "a restitution below 0.05 is a grain that never bounces, not a measurement", "coefficient of restitution",
       "the damping law", low_open=True),
    Quantity("surface_energy", "J/m2", 0.0, 0.0, 1000.0, (0.0, 10.0),
       "wet granular JKR energies lie in 0-3 J/m2 (the paper's Table 6: 0.5-2)", "JKR surface energy (cohesion)",
       "the cohesion laws", mistakes=((1e-3, "is this in mJ/m2"),)),
)}
for _w in ("wall", "cylinder", "floor"):
    for _k in ("static_friction", "rolling_friction", "restitution", "surface_energy"):
        _p = PARAMETERS[_k]  # the grains' facts, against a wall
        PARAMETERS[f"{_w}_{_k}"] = dataclasses.replace(
            _p, name=f"{_w}_{_k}", doc=f"{_p.doc} against the {_w if _w != 'wall' else 'floor and cylinder'}")

#: the heap test's rig (a conditions table's columns; paper 2.2: 150 mm x 300 mm, 300 mm/min)
CONDITION_VARIABLES: dict[str, Quantity] = {q.name: q for q in (
    Quantity("particle_d_min_mm", "mm", 3.0, 0.0, math.inf, (0.2, 50.0),
       "heap tests of grains from sand (0.2 mm) to coarse aggregate (50 mm)", "smallest grain diameter",
       "the fill", low_open=True, mistakes=_LENGTH),
    Quantity("particle_d_max_mm", "mm", 5.0, 0.0, math.inf, (0.2, 50.0),
       "heap tests of grains from sand (0.2 mm) to coarse aggregate (50 mm)", "largest grain diameter",
       "the fill", low_open=True, mistakes=_LENGTH),
    Quantity("cylinder_diameter_mm", "mm", 50.0, 0.0, math.inf, (5.0, 1000.0),
       "heap rigs use cylinders of 10-300 mm", "the lifted cylinder's inner diameter", "the fill and the walls",
       low_open=True, mistakes=_LENGTH),
    Quantity("fill_height_mm", "mm", 120.0, 0.0, math.inf, (5.0, 2000.0),
       "heap rigs fill 10-600 mm high", "height of the fill in the cylinder", "the fill", low_open=True,
       mistakes=_LENGTH),
    Quantity("lift_speed_mm_s", "mm/s", 50.0, 0.0, math.inf, (0.5, 5000.0),
       "rigs lift at 1-100 mm/s (the paper's 5 mm/s); up to 5000 in quick numerical checks",
       "speed at which the cylinder is lifted", "the lift", low_open=True,
       mistakes=((1000.0, "is this in m/s"),)),
)}
for _k in ("static_friction", "rolling_friction", "restitution", "surface_energy"):
    CONDITION_VARIABLES[f"floor_{_k}"] = PARAMETERS[f"floor_{_k}"]

#: other values a user gives
OTHER: dict[str, Quantity] = {q.name: q for q in (
    Quantity("repose_angle", "deg", 32.07, 0.0, 90.0, (5.0, 85.0),
       "a heap of real grains stands at 15-60 deg; below 5 it is a puddle, above 85 a column",
       "angle of repose", "the targets, invert --target", low_open=True, mistakes=_ANGLE),
    Quantity("shear_modulus", "Pa", 5e6, 0.0, math.inf, (1e5, 1e11),
       "DEM runs use 1 MPa-70 GPa (reduced moduli of 5-150 MPa are usual)", "the grains' shear modulus",
       "the normal laws and the time step", low_open=True,
       mistakes=((1e6, "is this in MPa"), (1e9, "is this in GPa"))),
)}

QUANTITIES: dict[str, Quantity] = {**PARAMETERS, **CONDITION_VARIABLES, **OTHER}


def extremes_allowed() -> bool:
    return os.environ.get(ALLOW_EXTREME, "") not in ("", "0")


def check_rig(d_min: float, d_max: float, cylinder: float | None = None, fill: float | None = None,
              where: str = "") -> None:
    """A rig's sizes against each other (each alone is :func:`check`'s): 0 < d_min <= d_max, a cylinder at
    least 4 and a fill at least 2 of the largest grains (None: not given, not checked)."""
    at = f" ({where})" if where else ""
    if not 0 < d_min <= d_max:
        raise CalibError(f"particle sizes must satisfy 0 < d_min <= d_max, got {d_min}, {d_max} mm{at}")
    if cylinder is not None and not cylinder >= 4 * d_max:
        raise CalibError(f"cylinder diameter {cylinder} mm must be at least 4 particle diameters{at}")
    if fill is not None and not fill >= 2 * d_max:
        raise CalibError(f"fill height {fill} mm must be at least 2 particle diameters{at}")


def is_bool(value) -> bool:
    """True and False, Python's or numpy's (known by its type's name: this module imports no numpy, so that
    the CLI's start stays light): a number's place where `--set restitution=true` would read 1.0."""
    kind = type(value)
    return isinstance(value, bool) or (kind.__module__ == "numpy" and kind.__name__ in ("bool", "bool_"))


def check(name: str, value, where: str = "") -> float:
    """``value`` of quantity ``name`` as a float, or a one-line :class:`CalibError`: not a number,
    outside what the model accepts, or (unless ``CALIB_ALLOW_EXTREME=1``) outside what a real material
    or rig plausibly has, with the likely mistake. ``where``: where the value came from, for the message."""
    q = QUANTITIES[name]
    at = f" ({where})" if where else ""
    if is_bool(value):
        raise CalibError(f"{name} must be a number{at}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer of hundreds of digits
        raise CalibError(f"{name} must be a number{at}, got {repr(value)[:40]}") from None
    unit = f" {q.unit}" if q.unit else ""
    if not math.isfinite(v):
        raise CalibError(f"{name} must be a finite number{at}, got {value!r}")
    if not q.accepts(v):
        interval = f"{'(' if q.low_open else '['}{_g(q.low)}, {_g(q.high)}]"
        raise CalibError(f"{name} = {_g(v)}{unit}{at} is outside {interval}{unit}: {q.doc}")
    lo, hi = q.plausible
    if not lo <= v <= hi and not extremes_allowed():
        hint = q.likely(v) or f"; {q.why}"
        raise CalibError(f"{name} = {_g(v)}{unit}{at} is outside the plausible {_g(lo)}-{_g(hi)}{unit}{hint} "
                         f"(set {ALLOW_EXTREME}=1 to use it anyway)")
    return v
