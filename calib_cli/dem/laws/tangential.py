"""Tangential (sliding) laws.

Each law: ``(ht, k, nx, ny, nz, tx, ty, tz, a_old, a, c_t, cap, prm, row, dt) -> (f_tx, f_ty, f_tz)``:
the tangential force on body i of a contact with normal n (from j to i), tangential relative
velocity t of the contact points, contact radius a (a_old at the last step), damping coefficient
c_t and Coulomb cap (the friction coefficient times the normal force of the cap law). The spring
lives in ``ht[k, SPRING:SPRING+3]`` and is updated in place.
"""

from __future__ import annotations

import math

import numba as nb

from .columns import G_S, SPRING


@nb.njit(cache=True, inline="always")
def mindlin(ht, k, nx, ny, nz, tx, ty, tz, a_old, a, ct, cap, prm, row, dt):
    """Mindlin-Deresiewicz no-slip (EDEM's Hertz-Mindlin): F_t = -S_t delta_t + c_t v_t, S_t = 8 G* a,
    capped at the Coulomb limit (slide at the cap, the spring rescaled to carry exactly the cap).

    The spring is rotated into the current tangent plane (magnitude kept) and rescaled by a_old / a:
    the incremental law dF_t = -S_t(a) d(delta_t). The total form F_t = -S_t(a) delta_t creates energy
    whenever a changes at fixed delta_t; with JKR, where a stays large and twitchy at zero load, that
    alone kept a settled packing humming at ~17 mm/s rms (it comes to rest with the incremental law).
    """
    hx, hy, hz = ht[k, SPRING], ht[k, SPRING + 1], ht[k, SPRING + 2]
    h2 = hx * hx + hy * hy + hz * hz
    if h2 > 0.0:
        hn = hx * nx + hy * ny + hz * nz
        hx -= hn * nx
        hy -= hn * ny
        hz -= hn * nz
        p2 = hx * hx + hy * hy + hz * hz
        if p2 > 0.0:
            s = math.sqrt(h2 / p2) * (a_old / a if a_old > 0.0 else 1.0)
            hx *= s
            hy *= s
            hz *= s
    hx += tx * dt
    hy += ty * dt
    hz += tz * dt
    St = 8.0 * prm[row, G_S] * a
    ftx = -St * hx + ct * tx
    fty = -St * hy + ct * ty
    ftz = -St * hz + ct * tz
    ft = math.sqrt(ftx * ftx + fty * fty + ftz * ftz)
    if ft > cap:
        if ft > 0.0:
            s = cap / ft
            ftx *= s
            fty *= s
            ftz *= s
        inv = -1.0 / St
        hx = ftx * inv
        hy = fty * inv
        hz = ftz * inv
    ht[k, SPRING] = hx
    ht[k, SPRING + 1] = hy
    ht[k, SPRING + 2] = hz
    return ftx, fty, ftz
