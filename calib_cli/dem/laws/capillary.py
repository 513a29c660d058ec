"""Capillary liquid bridge (pendular water between wet grains): Willett et al. (2000) with the
rupture distance of Lian, Thornton & Adams (1993).

A bridge of volume V between spheres at separation S (the gap, S = -delta >= 0) pulls them
together with (Willett, Adams, Johnson & Seville 2000, Langmuir 16, 9396, their Eqs. 12-13, the
closed form fitted to their measured and computed bridges; the Derjaguin radius R = 2 R* serves
unequal spheres):

    F(S) = 2 pi R gamma cos(theta) / (1 + 2.1 S+ + 10 S+^2),   S+ = (S / 2) sqrt(R / V),

gamma the liquid's surface tension, theta its contact angle; F(0) = 2 pi R gamma cos(theta), the
force at and within contact. The bridge ruptures at (Lian et al. 1993, Eq. 13, theta in radians)

    S_c = (1 + theta / 2) V^(1/3).

Hysteresis: a bridge forms when the surfaces touch, stays until the gap exceeds S_c, and after
rupture nothing pulls until they touch again (its energy is lost at rupture, as a real bridge's).
The volume of a bridge is ``liquid_volume`` times a grain's volume, 4/3 pi R^3 (for equal grains
R is their radius), so S_c and S+ scale with the grains: S_c = c_r R and S+ = c_g S / R, with
c_r = (1 + theta/2) (4 pi phi / 3)^(1/3) and c_g = 1 / (2 sqrt(4 pi phi / 3)), per interaction.

Law: ``(delta, Rs, a, ht, k, prm, row) -> F`` (negative: attractive), added to the normal force;
``ht[k, BRIDGE]`` holds whether the bridge exists. It needs no stiffness of its own (dF/dS is
orders below a contact's), so it leaves the time step alone.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ...effects import Effect
from .columns import allocate
from .params import Param

#: the interaction's values the bridge reads: the liquid's surface tension (0: no bridge), its contact
#: angle and a bridge's volume (the last two fixed settings, not calibrated); walls hold no bridge
PARAMS = (
    Param("surface_tension", 0.0, 0.0, 1.0, "N/m", "the liquid's surface tension (water: 0.072; 0: no bridge)",
          wall_zero=True),
    Param("contact_angle", 0.0, 0.0, 90.0, "deg", "the liquid's contact angle on the grains", setting=True,
          high_open=True),
    Param("liquid_volume", 0.01, 0.0, 0.5, "", "a bridge's volume over a grain's", setting=True, low_open=True),
)
#: the parameter row's 2 pi gamma cos(theta), c_r and c_g; the history row's "bridge formed" (1/0)
(BRIDGE_F, BRIDGE_RUPTURE, BRIDGE_GAP), (BRIDGE,) = allocate(parameters=3, history=1)

#: what diagnose adds to a model to test for liquid bridges
EFFECT = Effect(
    "capillary", "surface_tension", 0.0, 0.15, 0.0, 0.07,
    "capillary liquid bridges between wet grains (Willett et al. 2000): the liquid's surface tension, "
    "with the bridge volume and contact angle as set",
    "steeper heaps, most for small grains (a bridge pulls with 2 pi R gamma, a grain weighs ~R^3); on 4-6 mm "
    "grains water bridges raised every heap by about the same amount whatever its size, where JKR cohesion "
    "grew with the fill; unlike JKR the pull does not fall with the contact stiffness and reaches across a gap",
    pinned_when_absent=False, unit="N/m")


def selected(pp, *walls) -> bool:
    """A run composes the bridge when the grains carry a liquid."""
    return pp.surface_tension > 0.0


def constants(surface_tension: float, contact_angle: float, liquid_volume: float) -> tuple[float, float, float]:
    """Per-interaction (2 pi gamma cos(theta), c_r, c_g) of :func:`capillary` (module docstring), in the
    order of its parameter-row columns."""
    if surface_tension <= 0.0:
        return 0.0, 0.0, 0.0
    theta = math.radians(contact_angle)
    v = 4.0 * math.pi * liquid_volume / 3.0
    return (2.0 * math.pi * surface_tension * math.cos(theta), (1.0 + theta / 2.0) * v ** (1.0 / 3.0),
            1.0 / (2.0 * math.sqrt(v)))


@nb.njit(cache=True, inline="always")
def bridge_force(S, R, f0, cg):
    """Willett's F(S) for a bridge that exists (Derjaguin radius R, f0 = 2 pi gamma cos(theta)),
    attractive (negative); S <= 0 (contact) gives F(0)."""
    s = cg * max(S, 0.0) / R
    return -f0 * R / (1.0 + 2.1 * s + 10.0 * s * s)


@nb.njit(cache=True, inline="always")
def capillary(delta, Rs, a, ht, k, prm, row):
    """The bridge's force on a contact of overlap delta (module docstring); 0 on a row without liquid."""
    f0 = prm[row, BRIDGE_F]
    if f0 == 0.0:
        return 0.0
    R = 2.0 * Rs
    if delta >= 0.0:
        ht[k, BRIDGE] = 1.0
    elif ht[k, BRIDGE] == 0.0 or -delta > prm[row, BRIDGE_RUPTURE] * R:
        ht[k, BRIDGE] = 0.0
        return 0.0
    return bridge_force(-delta, R, f0, prm[row, BRIDGE_GAP])


@nb.njit(cache=True, inline="always")
def none(delta, Rs, a, ht, k, prm, row):
    """No force besides the elastic contact's."""
    return 0.0


def capillary_reach(row: np.ndarray, Rs_max: float) -> float:
    """The rupture distance of the largest pair (Derjaguin radius 2 R*)."""
    return float(row[BRIDGE_RUPTURE] * 2.0 * Rs_max)
