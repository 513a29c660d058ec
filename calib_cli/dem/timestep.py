"""Critical time steps and contact durations (what makes a step stable)."""

from __future__ import annotations

import math


def rayleigh_time_step(r_min, density, shear_modulus, poisson):
    """Rayleigh time: pi R sqrt(rho/G) / (0.1631 v + 0.8766)."""
    return math.pi * r_min * math.sqrt(density / shear_modulus) / (0.1631 * poisson + 0.8766)


def jkr_time_step(r_min, density, Es, Gs, gamma, wall=False):
    """Critical step 2/omega of the stiffest zero-load JKR contact (inf without cohesion).

    A JKR contact keeps a finite radius a0 at zero load (u^(3/2) = 3), so its tangential
    stiffness 8 G* a0 does not vanish as Hertz's does; with the rotational inertia the
    relative tangential motion has omega^2 = 7 k_t / m for equal spheres (3.5 k_t / m on a
    wall). The Rayleigh step does not see this, and reducing G makes it relatively worse
    (omega * t_R ~ G^(-1/6)). Measured: a settled cohesive packing hummed at 30 % of
    min(t_R, this) and came to rest at 20 %.
    """
    if gamma <= 0.0:
        return math.inf
    Rs = r_min if wall else r_min / 2.0
    a0 = 3.0 ** (2.0 / 3.0) * (math.pi * gamma / Es) ** (1.0 / 3.0) * Rs ** (2.0 / 3.0)
    m = density * 4.0 / 3.0 * math.pi * r_min**3
    omega = math.sqrt((3.5 if wall else 7.0) * 8.0 * Gs * a0 / m)
    return 2.0 / omega


def hertz_contact_time(Rs, Es, ms, v):
    """Duration of an elastic Hertz impact at speed v: 2.868 (m*^2/(R* E*^2 v))^(1/5)."""
    return 2.8683 * (ms * ms / (Rs * Es * Es * v)) ** 0.2
