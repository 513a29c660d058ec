"""Numba kernels: neighbour list, contact forces, velocity-Verlet integration.

Everything that runs per step is compiled (``cache=True``, so a second process
does not recompile). A chunk of steps runs without returning to Python.

Interaction parameter rows (``prm[row]``): 0 particle-particle, 1 floor, 2 cylinder;
columns ``E*, G*, mu_s, mu_r, beta, gamma``, the two law switches, the derived constants
``k^(1/3), 4 sqrt(pi g E* k^(1/3))`` (JKR, :func:`.contact.jkr_constants`) and ``sqrt(4 G*/E*)``,
the rolling spring's stiffness and damping (0: the constant-torque law) and the pull-off cap
switch (``caps_pulloff``). Wall geometry ``geo``: ``[cylinder radius, rim height z_edge, lift speed,
cylinder on (1/0), floor on (1/0), drag (1/s)]``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .contact import SQRT_5_6, jkr_cutoff_overlap, normal_law_core

PP, FLOOR, CYL = 0, 1, 2
E_S, G_S, MU_S, MU_R, BETA, GAMMA, ROLL_OWN, CAP_NET, K13, ATT, T_RATIO, K_ROLL, G_ROLL, CAP_PULL = range(14)

OK, NEED_CAPACITY = 0, 1
#: columns of a contact's history row: tangential spring (3), contact radius, cached R*^(1/3),
#: rolling spring (3; the spring-dashpot-slider law only)
HIST = 8


@nb.njit(cache=True, inline="always")
def _own_spin_brake(m, R, I_inv, c, wx, wy, wz, dt):
    """EDEM 'Standard' rolling torque on one body, -m R w/|w|, limited (as the relative law) so
    that it never reverses the body's spin within the step; nothing on a wall (I_inv = 0)."""
    w = math.sqrt(wx * wx + wy * wy + wz * wz)
    if w == 0.0 or I_inv == 0.0:
        return 0.0, 0.0, 0.0
    rate = m * R * I_inv * max(c, 1.0) * dt
    if rate > w:
        m *= w / rate
    return -m * R * wx / w, -m * R * wy / w, -m * R * wz / w


@nb.njit(cache=True, inline="always")
def _contact(nx, ny, nz, delta, Ri, Rj, Rs, ms, Ii_inv, Ij_inv, ci, cj,
             vx, vy, vz, wix, wiy, wiz, wjx, wjy, wjz, ht, k, prm, row, dt):
    """Force on i and torques on i and j of one contact (n points from j to i).

    Ri, Rj are the lever arms from each centre to the contact point (radius minus half
    the overlap for a pair, minus the overlap for a wall), so that the torques of a pair
    sum to zero about any point and angular momentum is conserved. ci, cj are the rolling
    contacts each particle had at the last evaluation (see the rolling limit below).
    Returns (fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, overlap). (vx, vy, vz) is v_i - v_j.
    ``ht[k, :3]`` is the tangential spring, ``ht[k, 3]`` the contact radius a of the last
    step, ``ht[k, 5:8]`` the rolling spring (``rolling_spring`` law only); all updated in place.
    ``ht[k, 4]`` caches R*^(1/3) (0: not yet computed).
    """
    Es = prm[row, E_S]
    a_old = ht[k, 3]
    gamma = prm[row, GAMMA]
    r13 = ht[k, 4]
    if r13 == 0.0 and gamma > 0.0:
        # R*^(1/3) is fixed for a pair (or a particle on a wall): a cube root per contact and
        # step was a fifth of the step's time
        r13 = np.cbrt(Rs)
        ht[k, 4] = r13
    Fel, Frep, a = normal_law_core(delta, Rs, r13, Es, gamma, prm[row, K13], prm[row, ATT], a_old)
    ht[k, 3] = a
    if a == 0.0:
        ht[k, 0] = 0.0
        ht[k, 1] = 0.0
        ht[k, 2] = 0.0
        ht[k, 5] = 0.0
        ht[k, 6] = 0.0
        ht[k, 7] = 0.0
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    beta = prm[row, BETA]
    # relative velocity of the contact points: v_i - v_j - (R_i w_i + R_j w_j) x n
    cx = Ri * wix + Rj * wjx
    cy = Ri * wiy + Rj * wjy
    cz = Ri * wiz + Rj * wjz
    rx = vx - (cy * nz - cz * ny)
    ry = vy - (cz * nx - cx * nz)
    rz = vz - (cx * ny - cy * nx)
    vn = rx * nx + ry * ny + rz * nz
    tx = rx - vn * nx
    ty = ry - vn * ny
    tz = rz - vn * nz
    # normal: elastic (Hertz/JKR) + damping -2 sqrt(5/6) beta sqrt(S_n m*) v_n, S_n = 2 E* a
    Sn = 2.0 * Es * a
    cn = 2.0 * SQRT_5_6 * beta * math.sqrt(Sn * ms)
    Fn = Fel + cn * vn
    # tangential spring, rotated into the current tangent plane (magnitude kept) and
    # rescaled by a_old / a: Mindlin-Deresiewicz's incremental law dF_t = -S_t(a) d(delta_t).
    # The total form F_t = -S_t(a) delta_t creates energy whenever a changes at fixed
    # delta_t; with JKR, where a stays large and twitchy at zero load, that alone kept a
    # settled packing humming at ~17 mm/s rms (it comes to rest with the incremental law).
    hx, hy, hz = ht[k, 0], ht[k, 1], ht[k, 2]
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
    cd = cn * prm[row, T_RATIO]  # 2 sqrt(5/6) beta sqrt(S_t m*), S_t / S_n = 4 G* / E*
    ftx = -St * hx + cd * tx
    fty = -St * hy + cd * ty
    ftz = -St * hz + cd * tz
    # the normal force of both caps (sliding, rolling): |F_el| (SPEC 5's rolling torque); with
    # caps_pulloff Thornton's (1991) |F_el + 2 F_c|, F_c = 3 pi g R* the pull-off force, as
    # LAMMPS's jkr: a cohesive contact keeps 2 F_c of both at zero net load, where |F_el| has none
    fc = abs(Fel)
    if prm[row, CAP_PULL] > 0.0:
        fc = abs(Fel + 6.0 * math.pi * gamma * Rs)
    cap = prm[row, MU_S] * (fc if prm[row, CAP_NET] + prm[row, CAP_PULL] > 0.0 else Frep)
    ft = math.sqrt(ftx * ftx + fty * fty + ftz * ftz)
    if ft > cap:
        # Coulomb: slide at the cap; the spring is rescaled to carry exactly the cap
        if ft > 0.0:
            s = cap / ft
            ftx *= s
            fty *= s
            ftz *= s
        inv = -1.0 / St
        hx = ftx * inv
        hy = fty * inv
        hz = ftz * inv
    ht[k, 0] = hx
    ht[k, 1] = hy
    ht[k, 2] = hz
    fx = Fn * nx + ftx
    fy = Fn * ny + fty
    fz = Fn * nz + ftz
    # torque of F_t at the contact point: (-R n) x F_t on both bodies
    tix = -Ri * (ny * ftz - nz * fty)
    tiy = -Ri * (nz * ftx - nx * ftz)
    tiz = -Ri * (nx * fty - ny * ftx)
    tjx = -Rj * (ny * ftz - nz * fty)
    tjy = -Rj * (nz * ftx - nx * ftz)
    tjz = -Rj * (nx * fty - ny * ftx)
    # rolling friction, constant directional torque: -mu_r |F_n| R w_rel/|w_rel| with F_n the
    # contact's elastic normal force (SPEC 5; for JKR the net force, not its repulsive part,
    # which stays at 12 pi g R* at zero load and would lock every cohesive contact),
    # limited so that it never reverses the relative rotation within the step. A particle
    # with c rolling contacts receives c such torques at once, so each is limited to 1/c of
    # the stop: without this the summed torques overshoot every step and the packing chatters
    # (rotational energy is pumped in and a heap never comes to rest).
    mur = prm[row, MU_R]
    kr = prm[row, K_ROLL]
    if mur > 0.0 and kr > 0.0:
        # spring-dashpot-slider (Ai et al. 2011 type C; LAMMPS `rolling sds`, the same steps): the
        # rolling displacement u, rotated into the tangent plane (magnitude kept), grows by
        # v_r dt with v_r = R* (w_i - w_j) x n; F_r = -k_r u - g_r v_r, capped at mu_r |F_n| x 2 for
        # a pair (1 on a wall: the arm R* against EDEM's R_i, as the LAMMPS engine maps it), u
        # then rescaled to carry the cap. Torque R* n x F_r on i, its opposite on j. Unlike the
        # constant torque it holds a static torque below the cap: a heap does not creep.
        gr = prm[row, G_ROLL]
        wrx = wix - wjx
        wry = wiy - wjy
        wrz = wiz - wjz
        vlx = Rs * (wry * nz - wrz * ny)
        vly = Rs * (wrz * nx - wrx * nz)
        vlz = Rs * (wrx * ny - wry * nx)
        ux, uy, uz = ht[k, 5], ht[k, 6], ht[k, 7]
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
        crit = mur * fc * (2.0 if row == PP else 1.0)
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
        ht[k, 5] = ux
        ht[k, 6] = uy
        ht[k, 7] = uz
        rtx = Rs * (ny * frz - nz * fry)
        rty = Rs * (nz * frx - nx * frz)
        rtz = Rs * (nx * fry - ny * frx)
        tix += rtx
        tiy += rty
        tiz += rtz
        tjx -= rtx
        tjy -= rty
        tjz -= rtz
    elif mur > 0.0 and prm[row, ROLL_OWN] > 0.0:
        # EDEM's 'Standard' model: each body is braked against its own spin, tau_i =
        # -mu_r |F_n| R_i w_i/|w_i| (a wall has none), with the same no-reversal limit per body.
        # It brakes a cluster turning as one, where the relative law does not, and it does not
        # conserve angular momentum in a free collision.
        m0 = mur * fc
        bx, by, bz = _own_spin_brake(m0, Ri, Ii_inv, ci, wix, wiy, wiz, dt)
        tix += bx
        tiy += by
        tiz += bz
        bx, by, bz = _own_spin_brake(m0, Rj, Ij_inv, cj, wjx, wjy, wjz, dt)
        tjx += bx
        tjy += by
        tjz += bz
    elif mur > 0.0:
        wrx = wix - wjx
        wry = wiy - wjy
        wrz = wiz - wjz
        wr = math.sqrt(wrx * wrx + wry * wry + wrz * wrz)
        if wr > 0.0:
            m = mur * fc
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
    return fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, delta


@nb.njit(cache=True)
def build_pairs(pos, rad, reach, pi, pj):
    """Half neighbour list (i < j, sorted by (i, j)) of pairs closer than R_i + R_j + reach.

    Cell list of cell size 2 R_max + reach over the particles' bounding box (capped at
    64^3 cells: an escaped particle only coarsens the grid). Returns the pair count, or
    -1 when the arrays are too small.
    """
    n = pos.shape[0]
    cap = pi.shape[0]
    lo = np.empty(3)
    hi = np.empty(3)
    for d in range(3):
        lo[d] = pos[:, d].min()
        hi[d] = pos[:, d].max()
    rmax = rad.max()
    cell = 2.0 * rmax + reach
    nc = np.empty(3, np.int64)
    for d in range(3):
        c = cell
        m = int((hi[d] - lo[d]) / c) + 1
        while m > 64:
            c *= 2.0
            m = int((hi[d] - lo[d]) / c) + 1
        nc[d] = m
    cs = np.empty(3)
    for d in range(3):
        cs[d] = max((hi[d] - lo[d]) / nc[d], cell) * (1.0 + 1e-12)
    ncell = nc[0] * nc[1] * nc[2]
    head = -np.ones(ncell, np.int64)
    nxt = -np.ones(n, np.int64)
    cid = np.empty((n, 3), np.int64)
    for i in range(n):
        for d in range(3):
            c = int((pos[i, d] - lo[d]) / cs[d])
            cid[i, d] = min(max(c, 0), nc[d] - 1)
        lin = (cid[i, 0] * nc[1] + cid[i, 1]) * nc[2] + cid[i, 2]
        nxt[i] = head[lin]
        head[lin] = i
    count = 0
    buf = np.empty(n, np.int64)
    for i in range(n):
        nb_ = 0
        for ox in range(-1, 2):
            x = cid[i, 0] + ox
            if x < 0 or x >= nc[0]:
                continue
            for oy in range(-1, 2):
                y = cid[i, 1] + oy
                if y < 0 or y >= nc[1]:
                    continue
                for oz in range(-1, 2):
                    z = cid[i, 2] + oz
                    if z < 0 or z >= nc[2]:
                        continue
                    j = head[(x * nc[1] + y) * nc[2] + z]
                    while j >= 0:
                        if j > i:
                            dx = pos[i, 0] - pos[j, 0]
                            dy = pos[i, 1] - pos[j, 1]
                            dz = pos[i, 2] - pos[j, 2]
                            r = rad[i] + rad[j] + reach
                            if dx * dx + dy * dy + dz * dz < r * r:
                                buf[nb_] = j
                                nb_ += 1
                        j = nxt[j]
        # sorted j within i -> globally sorted keys, for the linear history merge
        buf[:nb_].sort()
        if count + nb_ > cap:
            return -1
        for q in range(nb_):
            pi[count] = i
            pj[count] = buf[q]
            count += 1
    return count


@nb.njit(cache=True)
def transfer_history(oi, oj, oh, no, ni, nj, nh, nn):
    """Carry tangential springs of pairs present in both sorted lists (linear merge)."""
    a = 0
    for k in range(nn):
        while a < no and (oi[a] < ni[k] or (oi[a] == ni[k] and oj[a] < nj[k])):
            a += 1
        if a < no and oi[a] == ni[k] and oj[a] == nj[k]:
            for c in range(HIST):
                nh[k, c] = oh[a, c]
        else:
            for c in range(HIST):
                nh[k, c] = 0.0


@nb.njit(cache=True, parallel=True)
def compute_forces(pos, vel, omg, rad, mass, inv_inertia, pi, pj, npairs, ht, hf, hc,
                   prm, geo, gravity, dt, force, torque, ncont, cnew, pf):
    """Gravity + every particle-particle and particle-wall contact. Returns max overlap / radius.

    ``pf`` is a per-pair scratch buffer (capacity x 11).
    ``ncont`` holds each particle's contact count from the last evaluation (read);
    this evaluation's counts go to ``cnew`` and are copied into ``ncont`` at the end.
    """
    n = pos.shape[0]
    for i in range(n):
        cnew[i] = 0.0
        m = mass[i]
        force[i, 0] = m * gravity[0]
        force[i, 1] = m * gravity[1]
        force[i, 2] = m * gravity[2]
        torque[i, 0] = 0.0
        torque[i, 1] = 0.0
        torque[i, 2] = 0.0
    worst = 0.0
    # the widest attraction range of any pair (JKR cutoff gap grows with R*)
    dc_max = -jkr_cutoff_overlap(rad.max() / 2.0, prm[PP, E_S], prm[PP, GAMMA])
    # pair forces in parallel into a per-pair buffer, then scattered serially in pair order:
    # the result is bitwise the same whatever the number of threads
    for k in nb.prange(npairs):
        i = pi[k]
        j = pj[k]
        dx = pos[i, 0] - pos[j, 0]
        dy = pos[i, 1] - pos[j, 1]
        dz = pos[i, 2] - pos[j, 2]
        d2 = dx * dx + dy * dy + dz * dz
        Ri = rad[i]
        Rj = rad[j]
        reach = Ri + Rj + dc_max
        pf[k, 10] = 0.0
        if d2 >= reach * reach:
            for c in range(HIST):  # springs and contact radius; the cached R*^(1/3) stays valid
                if c != 4:
                    ht[k, c] = 0.0
            continue
        Rs = Ri * Rj / (Ri + Rj)
        d = math.sqrt(d2)
        inv = 1.0 / d
        nx, ny, nz = dx * inv, dy * inv, dz * inv
        ms = mass[i] * mass[j] / (mass[i] + mass[j])
        delta = Ri + Rj - d
        fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, ov = _contact(
            nx, ny, nz, delta, Ri - 0.5 * delta, Rj - 0.5 * delta, Rs, ms, inv_inertia[i], inv_inertia[j],
            ncont[i], ncont[j], vel[i, 0] - vel[j, 0], vel[i, 1] - vel[j, 1], vel[i, 2] - vel[j, 2],
            omg[i, 0], omg[i, 1], omg[i, 2], omg[j, 0], omg[j, 1], omg[j, 2], ht, k, prm, PP, dt)
        pf[k, 0] = fx
        pf[k, 1] = fy
        pf[k, 2] = fz
        pf[k, 3] = tix
        pf[k, 4] = tiy
        pf[k, 5] = tiz
        pf[k, 6] = tjx
        pf[k, 7] = tjy
        pf[k, 8] = tjz
        pf[k, 9] = ov / min(Ri, Rj)
        pf[k, 10] = 1.0
    for k in range(npairs):
        if pf[k, 10] == 0.0:
            continue
        i = pi[k]
        j = pj[k]
        force[i, 0] += pf[k, 0]
        force[i, 1] += pf[k, 1]
        force[i, 2] += pf[k, 2]
        force[j, 0] -= pf[k, 0]
        force[j, 1] -= pf[k, 1]
        force[j, 2] -= pf[k, 2]
        torque[i, 0] += pf[k, 3]
        torque[i, 1] += pf[k, 4]
        torque[i, 2] += pf[k, 5]
        torque[j, 0] += pf[k, 6]
        torque[j, 1] += pf[k, 7]
        torque[j, 2] += pf[k, 8]
        if ht[k, 3] > 0.0:
            cnew[i] += 1.0
            cnew[j] += 1.0
        if pf[k, 9] > worst:
            worst = pf[k, 9]
    Rc, zedge, vlift, cyl_on, floor_on, drag = geo[0], geo[1], geo[2], geo[3], geo[4], geo[5]
    dcf = jkr_cutoff_overlap(rad.max(), prm[FLOOR, E_S], prm[FLOOR, GAMMA])
    dcc = jkr_cutoff_overlap(rad.max(), prm[CYL, E_S], prm[CYL, GAMMA])
    for i in range(n):
        if drag > 0.0:
            # settling aid only (set during the fill): background viscous drag
            for d in range(3):
                force[i, d] -= drag * mass[i] * vel[i, d]
        Ri = rad[i]
        wix, wiy, wiz = omg[i, 0], omg[i, 1], omg[i, 2]
        # floor z = 0, normal +z. (The floor and cylinder blocks repeat their accumulation on
        # purpose: folding it into an inlined helper cost 40 % of the throughput, 6.0 -> 3.6 M p-steps/s.)
        if floor_on > 0.0:
            delta = Ri - pos[i, 2]
            if delta > dcf:
                fx, fy, fz, tix, tiy, tiz, _a, _b, _c, ov = _contact(
                    0.0, 0.0, 1.0, delta, Ri - delta, 0.0, Ri, mass[i], inv_inertia[i], 0.0, ncont[i], 1.0,
                    vel[i, 0], vel[i, 1], vel[i, 2], wix, wiy, wiz, 0.0, 0.0, 0.0, hf, i, prm, FLOOR, dt)
                force[i, 0] += fx
                force[i, 1] += fy
                force[i, 2] += fz
                torque[i, 0] += tix
                torque[i, 1] += tiy
                torque[i, 2] += tiz
                cnew[i] += 1.0
                if ov / Ri > worst:
                    worst = ov / Ri
            else:
                for c in range(HIST):
                    if c != 4:
                        hf[i, c] = 0.0
        # cylinder: vertical, axis through the origin, open bottom rim at z_edge moving up at vlift
        if cyl_on > 0.0:
            x, y, z = pos[i, 0], pos[i, 1], pos[i, 2]
            r = math.sqrt(x * x + y * y)
            delta = -1.0
            nx = ny = nz = 0.0
            if r > 1e-12:
                if z >= zedge:
                    if r <= Rc:
                        delta = Ri - (Rc - r)
                        nx, ny = -x / r, -y / r
                    else:
                        delta = Ri - (r - Rc)
                        nx, ny = x / r, y / r
                else:
                    qx, qy = Rc * x / r, Rc * y / r
                    ex, ey, ez = x - qx, y - qy, z - zedge
                    dd = math.sqrt(ex * ex + ey * ey + ez * ez)
                    if dd > 1e-15:
                        delta = Ri - dd
                        nx, ny, nz = ex / dd, ey / dd, ez / dd
            if delta > dcc:
                fx, fy, fz, tix, tiy, tiz, _a, _b, _c, ov = _contact(
                    nx, ny, nz, delta, Ri - delta, 0.0, Ri, mass[i], inv_inertia[i], 0.0, ncont[i], 1.0,
                    vel[i, 0], vel[i, 1], vel[i, 2] - vlift, wix, wiy, wiz, 0.0, 0.0, 0.0, hc, i, prm, CYL, dt)
                force[i, 0] += fx
                force[i, 1] += fy
                force[i, 2] += fz
                torque[i, 0] += tix
                torque[i, 1] += tiy
                torque[i, 2] += tiz
                cnew[i] += 1.0
                if ov / Ri > worst:
                    worst = ov / Ri
            else:
                for c in range(HIST):
                    if c != 4:
                        hc[i, c] = 0.0
    ncont[:] = cnew
    return worst


@nb.njit(cache=True)
def run_steps(nsteps, t0, dt, pos, vel, omg, force, torque, rad, mass, inv_inertia,
              pi, pj, npairs_arr, ht, ref_pos, skin, reach, hf, hc, prm, geo, lift_start, gravity,
              overlap_limit, speed_limit, spare_i, spare_j, spare_h, ncont, cnew, pf):
    """Advance ``nsteps`` velocity-Verlet steps.

    Returns (status, steps_done, max_overlap_ratio, rebuilds). status 0 OK,
    1 neighbour arrays too small (caller grows them and calls again), 2 overlap above
    the limit, 3 a speed above the limit or not finite (unstable).
    The list holds pairs within R_i + R_j + ``reach`` (skin plus the JKR cutoff gap).
    ``geo[1]`` (the rim height) is advanced with the lift: z_edge = geo[2] * max(0, t - lift_start).
    """
    n = pos.shape[0]
    half = 0.5 * dt
    # Verlet criterion: rebuild once any particle has moved half the skin
    limit2 = (0.5 * skin) ** 2
    worst_all = 0.0
    rebuilds = 0
    npairs = npairs_arr[0]
    for s in range(nsteps):
        t = t0 + s * dt
        for i in range(n):
            im = 1.0 / mass[i]
            for d in range(3):
                vel[i, d] += half * force[i, d] * im
                omg[i, d] += half * torque[i, d] * inv_inertia[i]
                pos[i, d] += dt * vel[i, d]
        maxd2 = 0.0
        for i in range(n):
            dx = pos[i, 0] - ref_pos[i, 0]
            dy = pos[i, 1] - ref_pos[i, 1]
            dz = pos[i, 2] - ref_pos[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > maxd2:
                maxd2 = d2
        if maxd2 > limit2:
            cnt = build_pairs(pos, rad, reach, spare_i, spare_j)
            if cnt < 0:
                # undo this step's drift so the caller can grow the arrays and resume exactly
                for i in range(n):
                    im = 1.0 / mass[i]
                    for d in range(3):
                        pos[i, d] -= dt * vel[i, d]
                        vel[i, d] -= half * force[i, d] * im
                        omg[i, d] -= half * torque[i, d] * inv_inertia[i]
                npairs_arr[0] = npairs
                return NEED_CAPACITY, s, worst_all, rebuilds
            transfer_history(pi, pj, ht, npairs, spare_i, spare_j, spare_h, cnt)
            pi[:cnt] = spare_i[:cnt]
            pj[:cnt] = spare_j[:cnt]
            ht[:cnt] = spare_h[:cnt]
            npairs = cnt
            ref_pos[:, :] = pos
            rebuilds += 1
        if geo[2] != 0.0:
            geo[1] = geo[2] * max(0.0, t + dt - lift_start)
        worst = compute_forces(pos, vel, omg, rad, mass, inv_inertia, pi, pj, npairs, ht, hf, hc,
                               prm, geo, gravity, dt, force, torque, ncont, cnew, pf)
        vmax2 = 0.0
        for i in range(n):
            im = 1.0 / mass[i]
            for d in range(3):
                vel[i, d] += half * force[i, d] * im
                omg[i, d] += half * torque[i, d] * inv_inertia[i]
            v2 = vel[i, 0] ** 2 + vel[i, 1] ** 2 + vel[i, 2] ** 2
            if v2 > vmax2 or v2 != v2:  # NaN sticks, and fails the check below
                vmax2 = v2
        if worst > worst_all:
            worst_all = worst
        npairs_arr[0] = npairs
        if worst > overlap_limit:
            return 2, s + 1, worst_all, rebuilds
        if not vmax2 <= speed_limit * speed_limit:
            return 3, s + 1, worst_all, rebuilds
    npairs_arr[0] = npairs
    return OK, nsteps, worst_all, rebuilds
