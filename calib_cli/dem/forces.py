"""Forces: one contact composed from the run's laws, and every contact of a step (numba).

A contact's force is assembled from one law per family (:mod:`.laws`), named by the run's
:class:`~.laws.ContactModel` spec, a compile-time constant: the force loop is compiled once per
composition and carries no law switches. ``prm[row]`` holds the interaction's values
(:mod:`.laws.columns`): row 0 particle-particle, 1 floor, 2 cylinder. ``gap[row]`` is the widest
gap at which a row's laws act (the JKR cutoff, a liquid bridge's rupture distance). Wall geometry
``geo``: ``[cylinder radius, rim height z_edge, lift speed, cylinder on (1/0), floor on (1/0),
drag (1/s)]``.
"""

from __future__ import annotations

import functools
import math

import numba as nb

from .laws import cap_law, cohesion_law, damping_law, normal_law, rolling_law, tangential_law
from .laws.columns import A_OLD, CYL, FLOOR, HIST, MU_S, PP, R13, ROLL_SPRING, SPRING


@nb.njit(cache=True, inline="always")
def _clear_springs(ht, k):
    for c in range(3):
        ht[k, SPRING + c] = 0.0
        ht[k, ROLL_SPRING + c] = 0.0


@nb.njit(cache=True, inline="always")
def contact(spec, nx, ny, nz, delta, Ri, Rj, Rs, ms, Ii_inv, Ij_inv, ci, cj,
            vx, vy, vz, wix, wiy, wiz, wjx, wjy, wjz, ht, k, prm, row, dt):
    """Force on i and torques on i and j of one contact (n points from j to i), from the laws of ``spec``.

    Ri, Rj are the lever arms from each centre to the contact point (radius minus half
    the overlap for a pair, minus the overlap for a wall), so that the torques of a pair
    sum to zero about any point and angular momentum is conserved. ci, cj are the rolling
    contacts each particle had at the last evaluation. (vx, vy, vz) is v_i - v_j.
    Returns (fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, overlap); ``ht[k]`` (the contact's history,
    :mod:`.laws.columns`) is updated in place.
    """
    a_old = ht[k, A_OLD]
    Fel, Frep, a = normal_law(spec, delta, Rs, a_old, ht, k, prm, row)
    ht[k, A_OLD] = a
    Fb = cohesion_law(spec, delta, Rs, a, ht, k, prm, row)
    if a == 0.0:
        _clear_springs(ht, k)
        if Fb == 0.0:
            return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        # apart but held by a force that acts across the gap (a liquid bridge)
        return Fb * nx, Fb * ny, Fb * nz, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
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
    cn, ct = damping_law(spec, a, ms, prm, row)
    Fn = Fel + cn * vn
    if Fb != 0.0:
        Fn += Fb
    n_slide, n_roll = cap_law(spec, Fel, Frep, Rs, prm, row)
    ftx, fty, ftz = tangential_law(spec, ht, k, nx, ny, nz, tx, ty, tz, a_old, a, ct, prm[row, MU_S] * n_slide,
                                   prm, row, dt)
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
    tix, tiy, tiz, tjx, tjy, tjz = rolling_law(spec, tix, tiy, tiz, tjx, tjy, tjz, ht, k, nx, ny, nz, Ri, Rj, Rs,
                                               Ii_inv, Ij_inv, ci, cj, wix, wiy, wiz, wjx, wjy, wjz, n_roll, prm,
                                               row, dt)
    return fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, delta


@nb.njit(cache=True)
def wall_contact(spec, nx, ny, nz, delta, Ri, Rj, Rs, ms, Ii_inv, Ij_inv, ci, cj,
                 vx, vy, vz, wix, wiy, wiz, wjx, wjy, wjz, ht, k, prm, row, dt):
    """:func:`contact` for a grain against the floor or the cylinder: compiled apart (once a wall) and called,
    not inlined.

    Why: numba types an inlined law chain again at every site it is inlined into (most of a composition's
    compile); the pair loop, which holds most contacts, keeps its inlined copy. Measured on a JKR
    composition (docs/performance.md): the force kernel compiles in 30 s instead of 36 s and steps 1.04-1.06x
    as fast (``benchmarks/kernel_ab.py``). ``row`` stays a literal (one compile per wall): as a plain
    integer the compile took 9 s less but the steps lost that gain (0.99x)."""
    nb.literally(spec)
    return contact(spec, nx, ny, nz, delta, Ri, Rj, Rs, ms, Ii_inv, Ij_inv, ci, cj,
                   vx, vy, vz, wix, wiy, wiz, wjx, wjy, wjz, ht, k, prm, row, dt)


@nb.njit(cache=True, inline="always")
def cylinder_overlap(x, y, z, Ri, Rc, zedge):
    """(overlap, unit normal towards the grain) of a grain of radius Ri at (x, y, z) on the cylinder of
    radius Rc, axis through the origin, open below its rim at height zedge: its inner or outer wall
    above the rim, the rim's edge (a circle) below it. Overlap -1 where neither can be touched."""
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
    return delta, nx, ny, nz


@nb.njit(cache=True, parallel=True)
def compute_forces(spec, pos, vel, omg, rad, mass, inv_inertia, pi, pj, npairs, ht, hf, hc,
                   prm, gap, geo, gravity, dt, force, torque, ncont, cnew, pf):
    """Gravity + every particle-particle and particle-wall contact. Returns max overlap / radius.

    ``pf`` is a per-pair scratch buffer (capacity x 11).
    ``ncont`` holds each particle's contact count from the last evaluation (read);
    this evaluation's counts go to ``cnew`` and are copied into ``ncont`` at the end.
    """
    nb.literally(spec)
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
    # the widest range of any pair's attraction (gap[PP]: the largest pair's)
    dc_max = gap[PP]
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
                if c != R13:
                    ht[k, c] = 0.0
            continue
        Rs = Ri * Rj / (Ri + Rj)
        d = math.sqrt(d2)
        inv = 1.0 / d
        nx, ny, nz = dx * inv, dy * inv, dz * inv
        ms = mass[i] * mass[j] / (mass[i] + mass[j])
        delta = Ri + Rj - d
        fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, ov = contact(
            spec, nx, ny, nz, delta, Ri - 0.5 * delta, Rj - 0.5 * delta, Rs, ms, inv_inertia[i], inv_inertia[j],
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
        if ht[k, A_OLD] > 0.0:
            cnew[i] += 1.0
            cnew[j] += 1.0
        if pf[k, 9] > worst:
            worst = pf[k, 9]
    Rc, zedge, vlift, cyl_on, floor_on, drag = geo[0], geo[1], geo[2], geo[3], geo[4], geo[5]
    dcf = -gap[FLOOR]
    dcc = -gap[CYL]
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
                fx, fy, fz, tix, tiy, tiz, _a, _b, _c, ov = wall_contact(
                    spec, 0.0, 0.0, 1.0, delta, Ri - delta, 0.0, Ri, mass[i], inv_inertia[i], 0.0, ncont[i], 1.0,
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
                    if c != R13:
                        hf[i, c] = 0.0
        # cylinder: vertical, axis through the origin, open bottom rim at z_edge moving up at vlift
        if cyl_on > 0.0:
            delta, nx, ny, nz = cylinder_overlap(pos[i, 0], pos[i, 1], pos[i, 2], Ri, Rc, zedge)
            if delta > dcc:
                fx, fy, fz, tix, tiy, tiz, _a, _b, _c, ov = wall_contact(
                    spec, nx, ny, nz, delta, Ri - delta, 0.0, Ri, mass[i], inv_inertia[i], 0.0, ncont[i], 1.0,
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
                    if c != R13:
                        hc[i, c] = 0.0
    ncont[:] = cnew
    return worst


@functools.cache
def forces_of(spec: str):
    """:func:`compute_forces` with ``spec`` bound (as :func:`.integrate.stepper`, for the same reason)."""

    @nb.njit(cache=True)
    def compute_forces_bound(pos, vel, omg, rad, mass, inv_inertia, pi, pj, npairs, ht, hf, hc, prm, gap, geo,
                             gravity, dt, force, torque, ncont, cnew, pf):
        return compute_forces(spec, pos, vel, omg, rad, mass, inv_inertia, pi, pj, npairs, ht, hf, hc, prm, gap,
                              geo, gravity, dt, force, torque, ncont, cnew, pf)

    return compute_forces_bound


@functools.cache
def contact_of(spec: str):
    """:func:`contact` with ``spec`` bound, callable from Python (tests, notebooks): one contact step with
    the laws that ``spec`` names, e.g. ``contact_of(ContactModel(normal="jkr", cap="pulloff").spec)``."""

    @nb.njit(cache=True)
    def contact_bound(nx, ny, nz, delta, Ri, Rj, Rs, ms, Ii_inv, Ij_inv, ci, cj, vx, vy, vz, wix, wiy, wiz,
                      wjx, wjy, wjz, ht, k, prm, row, dt):
        return contact(spec, nx, ny, nz, delta, Ri, Rj, Rs, ms, Ii_inv, Ij_inv, ci, cj,
                       vx, vy, vz, wix, wiy, wiz, wjx, wjy, wjz, ht, k, prm, row, dt)

    return contact_bound


def evaluate_contact(spec, *args):
    """One contact step with the laws ``spec`` names (:func:`contact_of`)."""
    return contact_of(spec)(*args)
