"""Time integration: velocity-Verlet steps with neighbour-list upkeep, in chunks that run without
returning to Python (numba)."""

from __future__ import annotations

import functools

import numba as nb

from .forces import compute_forces
from .neighbours import build_pairs, transfer_history

OK, NEED_CAPACITY = 0, 1


@nb.njit(cache=True)
def run_steps(spec, nsteps, t0, dt, pos, vel, omg, force, torque, rad, mass, inv_inertia,
              pi, pj, npairs_arr, ht, ref_pos, skin, reach, hf, hc, prm, gap, geo, lift_start, gravity,
              overlap_limit, speed_limit, spare_i, spare_j, spare_h, ncont, cnew, pf):
    """Advance ``nsteps`` velocity-Verlet steps with the contact laws of ``spec``
    (:attr:`.laws.ContactModel.spec`, compiled as a constant: one machine code per composition).

    Returns (status, steps_done, max_overlap_ratio, rebuilds). status 0 OK,
    1 neighbour arrays too small (caller grows them and calls again), 2 overlap above
    the limit, 3 a speed above the limit or not finite (unstable).
    The list holds pairs within R_i + R_j + ``reach`` (skin plus the widest gap a law acts across).
    ``geo[1]`` (the rim height) is advanced with the lift: z_edge = geo[2] * max(0, t - lift_start).
    """
    nb.literally(spec)
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
            # loops, not slice assignments: numba's code for those took half of this loop's compile
            # (a process's first composition 16-19 s -> 9-10 s, docs/performance.md); rebuilds are rare
            for k in range(cnt):
                pi[k] = spare_i[k]
                pj[k] = spare_j[k]
                for c in range(ht.shape[1]):
                    ht[k, c] = spare_h[k, c]
            npairs = cnt
            for i in range(n):
                for d in range(3):
                    ref_pos[i, d] = pos[i, d]
            rebuilds += 1
        if geo[2] != 0.0:
            geo[1] = geo[2] * max(0.0, t + dt - lift_start)
        worst = compute_forces(spec, pos, vel, omg, rad, mass, inv_inertia, pi, pj, npairs, ht, hf, hc,
                               prm, gap, geo, gravity, dt, force, torque, ncont, cnew, pf)
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


@functools.cache
def stepper(spec: str):
    """:func:`run_steps` with ``spec`` bound, called as ``stepper(spec)(nsteps, t0, ...)``.

    Called from Python, a string argument that numba must read as a constant costs a typing attempt
    per call (~35 ms); bound here as a constant of a closure, once per composition, a call costs
    microseconds, and numba's disk cache keeps the machine code across processes (its key holds the
    closure's constant)."""

    @nb.njit(cache=True)
    def run_steps_bound(nsteps, t0, dt, pos, vel, omg, force, torque, rad, mass, inv_inertia, pi, pj, npairs_arr,
                        ht, ref_pos, skin, reach, hf, hc, prm, gap, geo, lift_start, gravity, overlap_limit,
                        speed_limit, spare_i, spare_j, spare_h, ncont, cnew, pf):
        return run_steps(spec, nsteps, t0, dt, pos, vel, omg, force, torque, rad, mass, inv_inertia, pi, pj,
                         npairs_arr, ht, ref_pos, skin, reach, hf, hc, prm, gap, geo, lift_start, gravity,
                         overlap_limit, speed_limit, spare_i, spare_j, spare_h, ncont, cnew, pf)

    return run_steps_bound
