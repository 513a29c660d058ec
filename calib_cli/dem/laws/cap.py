"""Which normal force caps sliding and rolling (the friction cap laws).

Each law: ``(F_el, F_rep, Rs, prm, row) -> (N_slide, N_roll)``: the normal forces that the sliding
cap mu_s N_slide and the rolling torque mu_r N_roll R use, from the elastic normal force F_el and
its repulsive part F_rep (:mod:`.normal`). Without cohesion all three laws are the same.
"""

from __future__ import annotations

import math

import numba as nb

from .columns import GAMMA


@nb.njit(cache=True, inline="always")
def repulsive(Fel, Frep, Rs, prm, row):
    """Sliding on the repulsive part F_rep = 4E*a^3/(3R*), rolling on |F_el| (the built-in default).
    The rolling torque takes the net force: its repulsive part stays at 12 pi g R* at zero load and
    would lock every cohesive contact."""
    return Frep, abs(Fel)


@nb.njit(cache=True, inline="always")
def net(Fel, Frep, Rs, prm, row):
    """Both on |F_el| (a literal reading of EDEM's JKR help: a contact near zero load slides freely)."""
    fc = abs(Fel)
    return fc, fc


@nb.njit(cache=True, inline="always")
def pulloff(Fel, Frep, Rs, prm, row):
    """Both on |F_el + 2 F_c|, F_c = 3 pi g R* the JKR pull-off force (Thornton 1991, Marshall 2009;
    LAMMPS's jkr): a cohesive contact keeps 2 F_c of both caps at zero net load, where |F_el| has none."""
    fc = abs(Fel + 6.0 * math.pi * prm[row, GAMMA] * Rs)
    return fc, fc
