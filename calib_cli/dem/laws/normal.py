"""Normal elastic laws: Hertz, and JKR cohesion (EDEM's Hertz-Mindlin with JKR; paper Eqs. 2-3, 6).

Conventions: overlap ``delta > 0`` in contact; normal force ``F > 0`` repulsive; R* the pair's
equivalent radius (1/R* = 1/R1 + 1/R2, a wall's R* the grain's radius), E* the equivalent modulus.

Hertz (paper Eq. 6): F = 4/3 E* sqrt(R*) delta^(3/2), contact radius a = sqrt(R* delta).

JKR (paper Eqs. 2-3, exponent corrected):
    F = -4 sqrt(pi g E*) a^(3/2) + 4 E* a^3 / (3 R*),   delta = a^2/R* - 2 sqrt(pi g a / E*).
With k = pi g / E*, a = u (k R*^2)^(1/3) and delta = k^(2/3) R*^(1/3) (u^2 - 2 sqrt(u)), so one
dimensionless equation serves every pair. The stable branch (u above the minimum of
delta(u), u^3 > 1/4) is followed. The force minimum is -3 pi g R* (at u^3 = 9/4); the
attraction ends at the cutoff gap delta_c of a_c = [9 pi g R*^2/(2E*) (3/4 - 1/sqrt 2)]^(1/3).
With g = 0 the law is Hertz.

Each law: ``(delta, Rs, a_old, ht, k, prm, row) -> (F_el, F_rep, a)``: elastic force, its repulsive
part 4E*a^3/(3R*), contact radius (0: not in contact). ``a_old`` is the contact's radius at the last
step (0: apart); ``ht[k, R13]`` caches R*^(1/3).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .columns import ATT, E_S, GAMMA, K13, R13
from .targets import cbrt

#: u_c^3 = 9/2 (3/4 - 1/sqrt 2): the cutoff contact radius in units of (k R*^2)^(1/3)
U_CUT = (4.5 * (0.75 - 1.0 / math.sqrt(2.0))) ** (1.0 / 3.0)
#: dimensionless cutoff overlap u_c^2 - 2 sqrt(u_c) (about -1.1864)
DELTA_CUT = U_CUT**2 - 2.0 * math.sqrt(U_CUT)
#: s = sqrt(u) at the turning point of delta(u) (u^3 = 1/4): every stable-branch root lies above it
S_TURN = 0.25 ** (1.0 / 6.0)


@nb.njit(cache=True)
def jkr_cutoff_overlap(Rs, Es, gamma):
    """delta_c: the most negative overlap with non-zero (attractive) force; 0 for g = 0."""
    if gamma <= 0.0:
        return 0.0
    k = math.pi * gamma / Es
    return DELTA_CUT * k ** (2.0 / 3.0) * Rs ** (1.0 / 3.0)


@nb.njit(cache=True)
def jkr_constants(Es, gamma):
    """Per-interaction constants of :func:`normal_law_core`: (k^(1/3), 4 sqrt(pi g E* k^(1/3))), k = pi g / E*.

    Compiled, so that the cube root is libm's, as everywhere in the kernel: numpy's own
    np.cbrt runs SVML code on CPUs with AVX-512 and other code elsewhere, which differ in the
    last place (docs/performance.md, "Reproducibility"), and a heap amplifies that until it
    settles differently."""
    if gamma <= 0.0:
        return 0.0, 0.0
    k13 = np.cbrt(math.pi * gamma / Es)
    return k13, 4.0 * math.sqrt(math.pi * gamma * Es * k13)


@nb.njit(cache=True, inline="always")
def _jkr_s(dt, guess):
    """Stable-branch root s = sqrt(u) of h(s) = s^4 - 2 s - dt (u^2 - 2 sqrt(u) = dt).

    In s the equation is a polynomial, so an iteration costs one division and no square
    root. Halley's step (cubic convergence: from a warm start, the contact's previous s,
    two iterations) falls back to Newton's, which from the right of the root on this convex
    h converges monotonically, whenever Halley's would leave the stable branch. A guess
    near the turning point (h' ~ 0) is replaced by a start right of the root.
    """
    s = guess
    if s < 0.8367:  # u < 0.7
        s = math.sqrt(math.sqrt(max(dt, 0.0)) + 1.6)
    for _ in range(60):
        s2 = s * s
        s3 = s2 * s
        h = s3 * s - 2.0 * s - dt
        h1 = 4.0 * s3 - 2.0
        den = 2.0 * h1 * h1 - 12.0 * h * s2
        ds = 2.0 * h * h1 / den if den > 0.0 else h / h1
        if not s - ds > S_TURN:
            ds = h / h1
        s -= ds
        if abs(ds) < 1e-8 * s:
            break
    return s


@nb.njit(cache=True, inline="always")
def normal_law_core(delta, Rs, r13, Es, gamma, k13, att, a_prev):
    """:func:`normal_law_a` with its constants precomputed: r13 = R*^(1/3), and (k13, att)
    from :func:`jkr_constants` (the kernel keeps them in its interaction rows)."""
    if gamma <= 0.0:
        if delta <= 0.0:
            return 0.0, 0.0, 0.0
        a = math.sqrt(Rs * delta)
        f = 4.0 / 3.0 * Es * a * a * a / Rs
        return f, f, a
    if a_prev == 0.0 and delta < 0.0:
        return 0.0, 0.0, 0.0
    kr = k13 * r13
    dt = delta / (kr * k13)
    if dt < DELTA_CUT:
        return 0.0, 0.0, 0.0
    unit = kr * r13  # a = u unit = s^2 unit
    s = _jkr_s(dt, math.sqrt(a_prev / unit) if a_prev > 0.0 else 0.0)
    a = s * s * unit
    frep = 4.0 * Es * a * a * a / (3.0 * Rs)
    # 4 sqrt(pi g E* a) a, with sqrt(a) = s sqrt(k13) r13
    f = frep - att * r13 * s * a
    return f, frep, a


@nb.njit(cache=True)
def normal_law_a(delta, Rs, Es, gamma, a_prev):
    """(F, F_rep, a): elastic normal force, its repulsive part 4E*a^3/(3R*), contact radius.

    ``a_prev`` is the contact's radius at the last step: > 0 warm-starts the JKR solve,
    0 means the surfaces were apart, < 0 means "in contact, no warm start".
    JKR is hysteretic: surfaces that were apart feel nothing until they touch
    (delta >= 0); a contact once made stays attractive down to the cutoff gap delta_c.
    A non-hysteretic law (attraction on approach too) makes the force jump by
    5/3 pi g R* at delta_c in both directions, and the discrete jumps pumped energy into
    a settled cohesive packing (it never came to rest). All zero outside contact.
    """
    k13, att = jkr_constants(Es, gamma)
    return normal_law_core(delta, Rs, np.cbrt(Rs), Es, gamma, k13, att, a_prev)


@nb.njit(cache=True)
def normal_law(delta, Rs, Es, gamma, engaged=True):
    """(F, F_rep, a) of a contact that is already made (``engaged``) or approaching."""
    return normal_law_a(delta, Rs, Es, gamma, -1.0 if engaged else 0.0)


@nb.njit(cache=True)
def jkr_overlap_of_radius(a, Rs, Es, gamma):
    """Paper Eq. 3: delta(a) = a^2/R* - 2 sqrt(pi g a / E*)."""
    return a * a / Rs - 2.0 * math.sqrt(math.pi * gamma * a / Es)


@nb.njit(cache=True)
def jkr_force_of_radius(a, Rs, Es, gamma):
    """Paper Eq. 2 (exponent 3/2 on the adhesive term)."""
    return -4.0 * math.sqrt(math.pi * gamma * Es) * a ** 1.5 + 4.0 * Es * a ** 3 / (3.0 * Rs)


@nb.njit(cache=True, inline="always")
def hertz(delta, Rs, a_old, ht, k, prm, row):
    """Hertz (paper Eq. 6): F = 4/3 E* sqrt(R*) delta^(3/2) in contact, nothing apart."""
    return normal_law_core(delta, Rs, 0.0, prm[row, E_S], 0.0, 0.0, 0.0, a_old)


@nb.njit(cache=True, inline="always")
def jkr(delta, Rs, a_old, ht, k, prm, row):
    """JKR (paper Eqs. 2-3), hysteretic (:func:`normal_law_a`); Hertz where the row's g is 0 (a wall)."""
    gamma = prm[row, GAMMA]
    r13 = ht[k, R13]
    if r13 == 0.0 and gamma > 0.0:
        # R*^(1/3) is fixed for a pair (or a particle on a wall): a cube root per contact and
        # step was a fifth of the step's time
        r13 = cbrt(Rs)
        ht[k, R13] = r13
    return normal_law_core(delta, Rs, r13, prm[row, E_S], gamma, prm[row, K13], prm[row, ATT], a_old)


def jkr_reach(row: np.ndarray, Rs_max: float) -> float:
    """The JKR cutoff gap -delta_c of the largest pair (R* = Rs_max; a grain on a wall has R* = its radius)."""
    return -jkr_cutoff_overlap(Rs_max, row[E_S], row[GAMMA])
