"""Scalar contact laws (SPEC section 5; EDEM Hertz-Mindlin no-slip + JKR).

Conventions: overlap ``delta > 0`` in contact; normal force ``F > 0`` repulsive.
Equivalent quantities: 1/E* = (1-v1^2)/E1 + (1-v2^2)/E2, 1/G* = 2(2-v1)(1+v1)/E1 + 2(2-v2)(1+v2)/E2,
1/R* = 1/R1 + 1/R2, 1/m* = 1/m1 + 1/m2.

JKR (paper Eqs. 2-3, exponent corrected):
    F = -4 sqrt(pi g E*) a^(3/2) + 4 E* a^3 / (3 R*),   delta = a^2/R* - 2 sqrt(pi g a / E*).
With k = pi g / E*, a = u (k R*^2)^(1/3) and delta = k^(2/3) R*^(1/3) (u^2 - 2 sqrt(u)), so one
dimensionless equation serves every pair. The stable branch (u above the minimum of
delta(u), u^3 > 1/4) is followed. The force minimum is -3 pi g R* (at u^3 = 9/4); the
attraction ends at the cutoff gap delta_c of a_c = [9 pi g R*^2/(2E*) (3/4 - 1/sqrt 2)]^(1/3).
With g = 0 the law is Hertz: F = 4/3 E* sqrt(R*) delta^(3/2) (paper Eq. 6).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

SQRT_5_6 = math.sqrt(5.0 / 6.0)
#: u_c^3 = 9/2 (3/4 - 1/sqrt 2): the cutoff contact radius in units of (k R*^2)^(1/3)
U_CUT = (4.5 * (0.75 - 1.0 / math.sqrt(2.0))) ** (1.0 / 3.0)
#: dimensionless cutoff overlap u_c^2 - 2 sqrt(u_c) (about -1.1864)
DELTA_CUT = U_CUT**2 - 2.0 * math.sqrt(U_CUT)


@nb.njit(cache=True, inline="always")
def damping_ratio(e):
    """beta = ln e / sqrt(ln^2 e + pi^2) (negative for e < 1, 0 for e = 1)."""
    if e >= 1.0:
        return 0.0
    le = math.log(e)
    return le / math.sqrt(le * le + math.pi * math.pi)


@nb.njit(cache=True)
def jkr_cutoff_overlap(Rs, Es, gamma):
    """delta_c: the most negative overlap with non-zero (attractive) force; 0 for g = 0."""
    if gamma <= 0.0:
        return 0.0
    k = math.pi * gamma / Es
    return DELTA_CUT * k ** (2.0 / 3.0) * Rs ** (1.0 / 3.0)


#: s = sqrt(u) at the turning point of delta(u) (u^3 = 1/4): every stable-branch root lies above it
S_TURN = 0.25 ** (1.0 / 6.0)


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


def rolling_spring_constants(Gs, m_typ):
    """(k_r, g_r) of the spring-dashpot-slider rolling law: the stiffness of the order of a contact's
    tangential one, 8 G* x 0.1 mm, and the damping critical at a typical grain, 2 sqrt(k_r m)
    (the LAMMPS engine's `rolling sds` mapping, docs/physics.md "Rolling spring")."""
    k = 8 * Gs * 1e-4
    return k, 2 * math.sqrt(k * m_typ)


def hertz_contact_time(Rs, Es, ms, v):
    """Duration of an elastic Hertz impact at speed v: 2.868 (m*^2/(R* E*^2 v))^(1/5)."""
    return 2.8683 * (ms * ms / (Rs * Es * Es * v)) ** 0.2
