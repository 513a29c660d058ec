"""Rolling resistance laws (Ai, Chen, Rotter & Ooi 2011 classify them; EDEM's names in brackets).

Each law: ``(tix, tiy, tiz, tjx, tjy, tjz, ht, k, nx, ny, nz, Ri, Rj, Rs, Ii_inv, Ij_inv, ci, cj,
wix, wiy, wiz, wjx, wjy, wjz, N_roll, prm, row, dt) -> (tix, tiy, tiz, tjx, tjy, tjz)``: the torques on
i and j with the rolling torque added. Ri, Rj are the lever arms to the contact point, Rs = R*,
I_inv the inverse moments of inertia (0 on a wall), ci, cj each body's rolling contacts at the
last evaluation, w the spins, N_roll the normal force of the cap law (:mod:`.cap`). Nothing when
the row's mu_r is 0.
"""

from __future__ import annotations

import math

import numba as nb

from .columns import G_ROLL, K_ROLL, MU_R, PP, ROLL_SPRING


@nb.njit(cache=True, inline="always")
def rvd(tix, tiy, tiz, tjx, tjy, tjz, ht, k, nx, ny, nz, Ri, Rj, Rs, Ii_inv, Ij_inv, ci, cj,
        wix, wiy, wiz, wjx, wjy, wjz, Nr, prm, row, dt):
    """Constant directional torque on the pair's relative spin (Ai et al. type A; EDEM's 'RVD'
    rolling friction): tau = -mu_r |F_n| R w_rel/|w_rel| on i, its opposite (with R_j) on j.

    Limited so that it never reverses the relative rotation within the step. A particle with c
    rolling contacts receives c such torques at once, so each is limited to 1/c of the stop:
    without this the summed torques overshoot every step and the packing chatters (rotational
    energy is pumped in and a heap never comes to rest)."""
    mur = prm[row, MU_R]
    if mur > 0.0:
        wrx = wix - wjx
        wry = wiy - wjy
        wrz = wiz - wjz
        wr = math.sqrt(wrx * wrx + wry * wry + wrz * wrz)
        if wr > 0.0:
            m = mur * Nr
            rate = m * (Ri * Ii_inv * max(ci, 1.0) + Rj * Ij_inv * max(cj, 1.0)) * dt
            if rate > wr:
                m *= wr / rate
            inv = 1.0 / wr
            ux, uy, uz = wrx * inv, wry * inv, wrz * inv
            tix -= m * Ri * ux
            tiy -= m * Ri * uy
            tiz -= m * Ri * uz
            tjx += m * Rj * ux
            tjy += m * Rj * uy
            tjz += m * Rj * uz
    return tix, tiy, tiz, tjx, tjy, tjz


@nb.njit(cache=True, inline="always")
def _own_spin_brake(m, R, I_inv, c, wx, wy, wz, dt):
    """-m R w/|w| on one body, limited (as :func:`rvd`) so that it never reverses the
    body's spin within the step; nothing on a wall (I_inv = 0)."""
    w = math.sqrt(wx * wx + wy * wy + wz * wz)
    if w == 0.0 or I_inv == 0.0:
        return 0.0, 0.0, 0.0
    rate = m * R * I_inv * max(c, 1.0) * dt
    if rate > w:
        m *= w / rate
    return -m * R * wx / w, -m * R * wy / w, -m * R * wz / w


@nb.njit(cache=True, inline="always")
def standard(tix, tiy, tiz, tjx, tjy, tjz, ht, k, nx, ny, nz, Ri, Rj, Rs, Ii_inv, Ij_inv, ci, cj,
             wix, wiy, wiz, wjx, wjy, wjz, Nr, prm, row, dt):
    """Constant directional torque on each body's own spin (EDEM's 'Standard' rolling friction):
    tau_i = -mu_r |F_n| R_i w_i/|w_i|, a wall has none. It brakes a cluster turning as one, where
    the relative law does not, and it does not conserve angular momentum in a free collision."""
    mur = prm[row, MU_R]
    if mur > 0.0:
        m0 = mur * Nr
        bx, by, bz = _own_spin_brake(m0, Ri, Ii_inv, ci, wix, wiy, wiz, dt)
        tix += bx
        tiy += by
        tiz += bz
        bx, by, bz = _own_spin_brake(m0, Rj, Ij_inv, cj, wjx, wjy, wjz, dt)
        tjx += bx
        tjy += by
        tjz += bz
    return tix, tiy, tiz, tjx, tjy, tjz


@nb.njit(cache=True, inline="always")
def sds(tix, tiy, tiz, tjx, tjy, tjz, ht, k, nx, ny, nz, Ri, Rj, Rs, Ii_inv, Ij_inv, ci, cj,
        wix, wiy, wiz, wjx, wjy, wjz, Nr, prm, row, dt):
    """Spring-dashpot-slider (Ai et al. 2011 type C, 'elastic-plastic spring-dashpot'; LAMMPS's
    `rolling sds`, the same steps): the rolling displacement u, rotated into the tangent plane
    (magnitude kept), grows by v_r dt with v_r = R* (w_i - w_j) x n; F_r = -k_r u - g_r v_r, capped at
    mu_r N_roll x 2 for a pair (1 on a wall: the arm R* against EDEM's R_i, as the LAMMPS engine maps
    it), u then rescaled to carry the cap. Torque R* n x F_r on i, its opposite on j. Unlike the
    constant torque it holds a static torque below the cap: a heap does not creep. k_r, g_r:
    :func:`rolling_spring_constants`."""
    mur = prm[row, MU_R]
    kr = prm[row, K_ROLL]
    if mur > 0.0 and kr > 0.0:
        gr = prm[row, G_ROLL]
        wrx = wix - wjx
        wry = wiy - wjy
        wrz = wiz - wjz
        vlx = Rs * (wry * nz - wrz * ny)
        vly = Rs * (wrz * nx - wrx * nz)
        vlz = Rs * (wrx * ny - wry * nx)
        ux, uy, uz = ht[k, ROLL_SPRING], ht[k, ROLL_SPRING + 1], ht[k, ROLL_SPRING + 2]
        u2 = ux * ux + uy * uy + uz * uz
        if u2 > 0.0:
            un = ux * nx + uy * ny + uz * nz
            ux -= un * nx
            uy -= un * ny
            uz -= un * nz
            p2 = ux * ux + uy * uy + uz * uz
            s = math.sqrt(u2 / p2) if p2 > 0.0 else 0.0
            ux *= s
            uy *= s
            uz *= s
        ux += vlx * dt
        uy += vly * dt
        uz += vlz * dt
        frx = -kr * ux - gr * vlx
        fry = -kr * uy - gr * vly
        frz = -kr * uz - gr * vlz
        crit = mur * Nr * (2.0 if row == PP else 1.0)
        fr = math.sqrt(frx * frx + fry * fry + frz * frz)
        if fr > crit:
            s = crit / fr
            frx *= s
            fry *= s
            frz *= s
            inv = -1.0 / kr
            ux = (frx + gr * vlx) * inv
            uy = (fry + gr * vly) * inv
            uz = (frz + gr * vlz) * inv
        ht[k, ROLL_SPRING] = ux
        ht[k, ROLL_SPRING + 1] = uy
        ht[k, ROLL_SPRING + 2] = uz
        rtx = Rs * (ny * frz - nz * fry)
        rty = Rs * (nz * frx - nx * frz)
        rtz = Rs * (nx * fry - ny * frx)
        tix += rtx
        tiy += rty
        tiz += rtz
        tjx -= rtx
        tjy -= rty
        tjz -= rtz
    return tix, tiy, tiz, tjx, tjy, tjz


def rolling_spring_constants(Gs, m_typ):
    """(k_r, g_r) of :func:`sds`: the stiffness of the order of a contact's tangential one,
    8 G* x 0.1 mm, and the damping critical at a typical grain, 2 sqrt(k_r m) (the LAMMPS engine's
    `rolling sds` mapping, docs/physics.md "Rolling spring")."""
    k = 8 * Gs * 1e-4
    return k, 2 * math.sqrt(k * m_typ)
