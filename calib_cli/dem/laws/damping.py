"""Contact damping laws.

Each law: ``(a, ms, prm, row) -> (c_n, c_t)``, the normal and tangential viscous coefficients of a
contact of radius a between bodies of equivalent mass m* (the forces are c_n v_n and c_t v_t).
"""

from __future__ import annotations

import math

import numba as nb

from .columns import BETA, E_S, T_RATIO

SQRT_5_6 = math.sqrt(5.0 / 6.0)


@nb.njit(cache=True)
def damping_ratio(e):
    """beta = ln e / sqrt(ln^2 e + pi^2) (negative for e < 1, 0 for e = 1)."""
    if e >= 1.0:
        return 0.0
    le = math.log(e)
    return le / math.sqrt(le * le + math.pi * math.pi)


@nb.njit(cache=True, inline="always")
def edem(a, ms, prm, row):
    """EDEM's Hertz-Mindlin damping (Tsuji et al. 1992 with the contact stiffnesses of Mindlin):
    c_n = -2 sqrt(5/6) beta sqrt(S_n m*), S_n = 2 E* a; c_t the same with S_t = 8 G* a, i.e.
    c_n sqrt(4 G*/E*). beta from the restitution coefficient (:func:`damping_ratio`)."""
    Sn = 2.0 * prm[row, E_S] * a
    cn = 2.0 * SQRT_5_6 * prm[row, BETA] * math.sqrt(Sn * ms)
    return cn, cn * prm[row, T_RATIO]
