"""Many heaps advanced together on a GPU (numba's CUDA target, the ``[gpu]`` extra: numba-cuda).

A batch holds every heap's grains in one set of arrays, heap by heap (``first[h]:first[h+1]``), each
heap with its own time step, parameter rows, walls, neighbour grid and state; a heap whose work is done
is switched off (``active``). A step is the CPU kernel's (:func:`.integrate.run_steps`): half kick and
drift, a Verlet-list rebuild where a grain moved half the skin, the rim's height, forces, half kick, the
overlap and speed checks. Each phase is a device function of one grain (or cell); how the phases are
launched is the batch's mode (:data:`MODES`): a kernel a phase launched from Python every step (bound by
the launches, ~70 us each on an H200), the same captured in a CUDA graph (the default, the fastest measured),
one persistent cooperative kernel a chunk, whose grid waits for itself between phases, or one launch a chunk
with a thread block a heap, each block waiting only for itself (docs/performance.md measures each). The
kernel-a-phase modes run a step's pair contacts a thread a grain or a thread a neighbour slot (:data:`CONTACTS`).

One physics source: a contact is :func:`.forces.contact_of` (the laws of :mod:`.laws`, composed by the
run's spec), the same compiled function the CPU kernel calls, compiled here for the GPU. What is this
module's own is the bookkeeping around it: per-particle neighbour slots (pairs i < j, their contact
history carried over a rebuild by looking j up in i's old slots), a cell grid per heap, and atomic
accumulation of pair forces (so, unlike the CPU kernel, the sum's order and its last bits vary from
run to run). The cylinder's geometry is the CPU kernel's too (:func:`.forces.cylinder_overlap`).

Without a GPU it runs under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``: every thread in
Python), which is how ``make test`` checks it against the CPU kernel on a few grains.
"""

from __future__ import annotations

import functools
import inspect
import math
import os
import time
from dataclasses import dataclass

import numba as nb
import numpy as np

# numba-cuda 0.30 registers a GPU overload for np.row_stack when it compiles its first kernel, and numpy 2.5
# removed that name: seen on an H200 machine with numpy 2.5.2, where no kernel compiled without this alias
if not hasattr(np, "row_stack"):
    np.row_stack = np.vstack

from numba import cuda  # noqa: E402  (a module global: the simulator swaps it for its own in each kernel)

from ..errors import CalibError
from .forces import contact_of, cylinder_overlap
from .laws.columns import A_OLD, CYL, FLOOR, HIST, PP, R13

SIMULATOR = os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"
#: per-heap status after a chunk, as :func:`.integrate.run_steps` returns it
OK, OVERLAP, SPEED = 0, 2, 3


def cuda_module():
    """numba's CUDA module, or a one-line error saying what is missing."""
    if not SIMULATOR and not cuda.is_available():
        raise CalibError("--engine gpu found no usable NVIDIA GPU (or no CUDA driver); install the [gpu] "
                         "extra on a machine with one, or set NUMBA_ENABLE_CUDASIM=1 to run the GPU code on the "
                         "CPU (slow: for tests)")
    return cuda


def _unwrap(a):
    """The numpy array under a simulator's kernel argument (a compiled law takes arrays, not proxies)."""
    while not isinstance(a, np.ndarray):
        a = a._item if hasattr(a, "_item") else a._ary
    return a


@nb.njit(inline="always")
def _same(a):
    return a


#: what a kernel hands a compiled law: the array itself on a GPU, the array under the proxy in the simulator
_raw = _unwrap if SIMULATOR else _same


@dataclass
class Grid:
    """One heap's neighbour cells: origin ``lo``, ``dims`` cells of side ``side`` (a grain outside the
    box counts in the nearest edge cell, so it is still found, only with more candidates)."""

    lo: np.ndarray
    dims: np.ndarray
    side: float

    @classmethod
    def around(cls, pos: np.ndarray, side: float, spread: float = 4.5) -> "Grid":
        """A box ``spread`` times the grains' horizontal extent (a heap spreads as the cylinder lifts: a
        `default` fill of 25 mm radius ends as a 15-20 deg cone of 85-95 mm), from the floor to 1.5 times
        the top, at least 3 cells a side."""
        r = max(float(np.abs(pos[:, :2]).max()) * spread, 2 * side)
        lo = np.array([-r, -r, min(float(pos[:, 2].min()), 0.0) - side])
        hi = np.array([r, r, float(pos[:, 2].max()) * 1.5 + side])
        dims = np.maximum(np.ceil((hi - lo) / side).astype(np.int64), 3)
        return cls(lo, dims, side)


@functools.cache
def kernels(spec: str, cap: int = 0) -> dict:
    """The step's kernels for one composition of laws (``spec``), compiled once per process (the force
    kernels at most ``cap`` registers a thread, where not 0: :func:`register_cap`)."""
    cuda_module()
    return _build(contact_of(spec), cap)


def _build(contact, cap: int = 0) -> dict:
    """The step's kernels: the ones that call the composed ``contact`` (pair and wall forces), compiled
    around it, and the ones that do not (integration, neighbour lists, per-heap bookkeeping)."""
    return {**STEP_KERNELS, **_force_kernels(contact, cap)}


def register_cap(cap: int | None = None) -> int:
    """The force kernels' registers a thread asked for (``cap``, else ``CALIB_GPU_MAXREG``, else 0: the
    compiler's choice, 140-152 for the grain kernel): a cap lets more warps share a multiprocessor and spills
    the rest to local memory (``benchmarks/gpu_compile.py --registers`` prints both, with no GPU). Not under
    the simulator, which has no registers."""
    raw = cap if cap is not None else os.environ.get("CALIB_GPU_MAXREG") or 0
    try:
        cap = int(raw)
    except ValueError:
        cap = -1
    if cap != 0 and not 32 <= cap <= 255:
        raise CalibError(f"CALIB_GPU_MAXREG must be a whole number of registers from 32 to 255 (or 0: the "
                         f"compiler's choice), not {raw!r}")
    return 0 if SIMULATOR else cap


@cuda.jit(device=True)
def _half_kick(i, half, vel, omg, force, torque, mass, inv_inertia):
    """Grain i's half step of velocity Verlet: v += (dt/2) F/m, w += (dt/2) T/I (both halves below)."""
    im = 1.0 / mass[i]
    for d in range(3):
        vel[i, d] += half * force[i, d] * im
        omg[i, d] += half * torque[i, d] * inv_inertia[i]


# ------------------------------------------------------------------ one grain's (or cell's) share of a step
# Each phase of a step is a device function of one index; the per-phase kernels below and the persistent
# kernel (:func:`_persistent_kernel`) call the same ones, so every stepping mode runs the same arithmetic.

@cuda.jit(device=True)
def _drift_one(i, active, status, heap, first, dt, pos, vel, omg, force, torque, mass, inv_inertia, ref_pos,
               limit2, rebuild, anyreb, grav, cnew, step, t0, lift_start, geo):
    """The step's first half: half kick and drift, the rebuild flag where a grain moved half the skin,
    the force reset to gravity for the step's contacts; a heap's first grain moves its cylinder. A heap
    whose last step blew up (``status``, set during that step's kick) stops here: its first grain switches
    it off for the rest of the step and after, so every grain of it finished that step, as the CPU kernel
    ends a run, and no thread reads ``active`` in the phase that writes it."""
    h = heap[i]
    if active[h] == 0:
        return
    if status[h] != OK:
        if i == first[h]:
            active[h] = 0
        return
    _half_kick(i, 0.5 * dt[h], vel, omg, force, torque, mass, inv_inertia)
    for d in range(3):
        pos[i, d] += dt[h] * vel[i, d]
    dx = pos[i, 0] - ref_pos[i, 0]
    dy = pos[i, 1] - ref_pos[i, 1]
    dz = pos[i, 2] - ref_pos[i, 2]
    if dx * dx + dy * dy + dz * dz > limit2[h]:
        rebuild[h] = 1
        anyreb[0] = 1
    for d in range(3):
        force[i, d] = mass[i] * grav[d]
        torque[i, d] = 0.0
    cnew[i] = 0.0
    if i == first[h] and geo[h, 2] != 0.0:  # the rim's height at the step's end, as the CPU kernel rounds it
        geo[h, 1] = geo[h, 2] * max(0.0, t0[h] + step * dt[h] + dt[h] - lift_start[h])


@cuda.jit(device=True)
def _cell_of(pos, i, lo, dims, side, h, d):
    c = int(math.floor((pos[i, d] - lo[h, d]) / side[h]))
    return min(max(c, 0), dims[h, d] - 1)


@cuda.jit(device=True)
def _grain_cell(pos, i, lo, dims, side, cell0, h):
    """The index of grain i's cell in the batch's cells (heap h's box)."""
    cx = _cell_of(pos, i, lo, dims, side, h, 0)
    cy = _cell_of(pos, i, lo, dims, side, h, 1)
    cz = _cell_of(pos, i, lo, dims, side, h, 2)
    return cell0[h] + (cx * dims[h, 1] + cy) * dims[h, 2] + cz


@cuda.jit(device=True)
def _bin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count, slots, cap, overflow):
    h = heap[i]
    if rebuild[h] == 0:
        return
    c = _grain_cell(pos, i, lo, dims, side, cell0, h)
    s = cuda.atomic.add(count, c, 1)
    if s < cap:
        slots[c, s] = i
    else:
        overflow[0] = 1


@cuda.jit(device=True)
def _find_one(i, heap, rebuild, pos, ref_pos, rad, reach, lo, dims, side, cell0, count, slots, cap, nnb, nbr, hist,
              new_nbr, new_hist, overflow):
    """Grain i's neighbours j > i within reach, from the 27 cells around it, each with its old history; they
    become its list, and its position the list's reference."""
    h = heap[i]
    if rebuild[h] == 0:
        return
    cx = _cell_of(pos, i, lo, dims, side, h, 0)
    cy = _cell_of(pos, i, lo, dims, side, h, 1)
    cz = _cell_of(pos, i, lo, dims, side, h, 2)
    m = 0
    width = nbr.shape[1]
    for x in range(max(cx - 1, 0), min(cx + 2, dims[h, 0])):
        for y in range(max(cy - 1, 0), min(cy + 2, dims[h, 1])):
            for z in range(max(cz - 1, 0), min(cz + 2, dims[h, 2])):
                c = cell0[h] + (x * dims[h, 1] + y) * dims[h, 2] + z
                for q in range(min(count[c], cap)):
                    j = slots[c, q]
                    if j <= i:
                        continue
                    dx = pos[i, 0] - pos[j, 0]
                    dy = pos[i, 1] - pos[j, 1]
                    dz = pos[i, 2] - pos[j, 2]
                    r = rad[i] + rad[j] + reach[h]
                    if dx * dx + dy * dy + dz * dz >= r * r:
                        continue
                    if m >= width:
                        overflow[0] = 1
                        continue
                    new_nbr[i, m] = j
                    old = -1
                    for s in range(nnb[i]):  # carry the contact's history (springs, contact radius)
                        if nbr[i, s] == j:
                            old = s
                    for col in range(hist.shape[2]):
                        new_hist[i, m, col] = hist[i, old, col] if old >= 0 else 0.0
                    m += 1
    # the new list replaces the old at once: no other thread reads grain i's slots, histories or reference
    # position during the search (a grain reads only its own)
    nnb[i] = m
    for s in range(m):
        nbr[i, s] = new_nbr[i, s]
        for col in range(hist.shape[2]):
            hist[i, s, col] = new_hist[i, s, col]
    for d in range(3):
        ref_pos[i, d] = pos[i, d]


@cuda.jit(device=True)
def _unbin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count):
    """Grain i's cell emptied again after a rebuild (every search has read it by then), so that the next
    rebuild bins into empty cells: a grain's work, where clearing every cell of a heap's box cost ~110 us a
    step for 256 heaps (23.6 million cells) on an H200 whenever one heap rebuilt (docs/performance.md)."""
    h = heap[i]
    if rebuild[h] == 0:
        return
    count[_grain_cell(pos, i, lo, dims, side, cell0, h)] = 0


@cuda.jit(device=True)
def _kick_one(i, active, heap, first, rebuild, dt, vel, omg, force, torque, mass, inv_inertia, ncont, cnew,
              overlap_limit, speed_limit, worst, status):
    """The step's second half: half kick, the contact counts, the overlap and speed checks (a heap that
    blew up stops at the next step's drift, :func:`_drift_one`); a heap's first grain clears its rebuild
    flag (the lists were rebuilt earlier in the step)."""
    h = heap[i]
    if i == first[h]:
        rebuild[h] = 0
    if active[h] == 0:
        return
    _half_kick(i, 0.5 * dt[h], vel, omg, force, torque, mass, inv_inertia)
    ncont[i] = cnew[i]
    v2 = vel[i, 0] ** 2 + vel[i, 1] ** 2 + vel[i, 2] ** 2
    if not v2 <= speed_limit * speed_limit:  # NaN fails too
        status[h] = SPEED
    if worst[h] > overlap_limit and status[h] == OK:
        status[h] = OVERLAP


# ------------------------------------------------------------------ a kernel a phase (modes launch, device, graph)
# A thread a grain. The step number within the chunk is read from the device
# (``nstep``, counted by ``kick``), so that a captured CUDA graph replays the same launches step after step.

@cuda.jit
def kick_drift(n, active, status, heap, first, dt, pos, vel, omg, force, torque, mass, inv_inertia, ref_pos, limit2,
               rebuild, anyreb, grav, cnew, nstep, t0, lift_start, geo):
    i = cuda.grid(1)
    if i < n:
        _drift_one(i, active, status, heap, first, dt, pos, vel, omg, force, torque, mass, inv_inertia, ref_pos,
                   limit2, rebuild, anyreb, grav, cnew, nstep[0], t0, lift_start, geo)


@cuda.jit
def bin_grains(n, heap, rebuild, pos, lo, dims, side, cell0, count, slots, cap, overflow):
    i = cuda.grid(1)
    if i < n:
        _bin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count, slots, cap, overflow)


@cuda.jit
def find_neighbours(n, heap, rebuild, pos, ref_pos, rad, reach, lo, dims, side, cell0, count, slots, cap,
                    nnb, nbr, hist, new_nbr, new_hist, overflow):
    i = cuda.grid(1)
    if i < n:
        _find_one(i, heap, rebuild, pos, ref_pos, rad, reach, lo, dims, side, cell0, count, slots, cap, nnb, nbr,
                  hist, new_nbr, new_hist, overflow)


@cuda.jit
def kick(n, active, heap, first, rebuild, anyreb, dt, vel, omg, force, torque, mass, inv_inertia, ncont, cnew,
         overlap_limit, speed_limit, worst, status, nstep):
    i = cuda.grid(1)
    if i >= n:
        return
    if i == 0:  # every thread of the step read both before this launch
        nstep[0] += 1
        anyreb[0] = 0
    _kick_one(i, active, heap, first, rebuild, dt, vel, omg, force, torque, mass, inv_inertia, ncont, cnew,
              overlap_limit, speed_limit, worst, status)


#: the kernels that take no contact law (one set for every composition)
STEP_KERNELS = dict(kick_drift=kick_drift, bin_grains=bin_grains, find_neighbours=find_neighbours, kick=kick)


def _force_kernels(contact, cap: int = 0) -> dict:
    """The step's contacts around the composed ``contact`` (a compiled function of :mod:`.forces`): one
    kernel, a thread a grain, its pairs and then its walls (and its cell emptied after a rebuild); the
    ``pair`` layout's two, a thread a neighbour slot for the pairs, then a thread a grain for the walls (each
    grain's sums in the same order: its pairs, then its walls); and the persistent and block kernels, which
    call the first's device function. ``cap``: their registers a thread, where not 0."""
    (pairs_of, pair_of), walls_of = _pairs_of(contact), _walls_of(contact)
    jit = functools.partial(cuda.jit, max_registers=cap) if cap else cuda.jit

    @cuda.jit(device=True)
    def forces_one(i, active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, hf, hc, prm, gap, geo, dt,
                   force, torque, ncont, cnew, worst):
        h = heap[i]
        if active[h] == 0:
            return
        p = _raw(prm[h])
        most, count = pairs_of(i, h, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, p, gap, dt, force, torque,
                               ncont, cnew)
        most, count = walls_of(i, h, pos, vel, omg, rad, mass, inv_inertia, hf, hc, p, gap, geo, dt, force, torque,
                               ncont, most, count)
        _settle(i, h, most, count, cnew, worst)

    @jit
    def forces(n, active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, hf, hc, prm, gap, geo, dt,
               force, torque, ncont, cnew, worst, rebuild, lo, dims, side, cell0, count):
        i = cuda.grid(1)
        if i < n:
            _unbin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count)
            forces_one(i, active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, hf, hc, prm, gap, geo,
                       dt, force, torque, ncont, cnew, worst)

    @jit
    def pair_forces(n, active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, prm, gap, dt, force,
                    torque, ncont, cnew, worst):
        t = cuda.grid(1)
        i = t // nbr.shape[1]
        if i < n:
            pair_of(i, t - i * nbr.shape[1], active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist,
                    prm, gap, dt, force, torque, ncont, cnew, worst)

    @jit
    def wall_forces(n, active, heap, pos, vel, omg, rad, mass, inv_inertia, hf, hc, prm, gap, geo, dt, force, torque,
                    ncont, cnew, worst, rebuild, lo, dims, side, cell0, count):
        i = cuda.grid(1)
        if i < n:
            _unbin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count)
            h = heap[i]
            if active[h] != 0:
                most, hits = walls_of(i, h, pos, vel, omg, rad, mass, inv_inertia, hf, hc, _raw(prm[h]), gap, geo, dt,
                                      force, torque, ncont, 0.0, 0.0)
                _settle(i, h, most, hits, cnew, worst)

    return {"forces": forces, "pair_forces": pair_forces, "wall_forces": wall_forces,
            "persistent": _persistent_kernel(forces_one, jit), "blocks": _block_kernel(forces_one, jit)}


def _persistent_kernel(forces_one, jit=cuda.jit):
    """``nsteps`` whole steps in one cooperative launch: every thread strides over the grains of a
    phase, and the grid waits for all before the next (``this_grid().sync()``, a cooperative launch that
    numba makes when a kernel syncs its grid). The rebuild's two phases run only on a step where some
    heap asked for one (``anyreb``, read by every thread after the sync that follows the drift). Under
    numba's simulator a grid is one block, launched here with one thread: phases in grain order, as the
    per-phase kernels run there, so the states stay bit for bit the CPU kernel's."""

    @jit
    def persistent(nsteps, n, cap, overlap_limit, speed_limit, active, heap, first, dt, pos, vel,
                   omg, force, torque, rad, mass, inv_inertia, ref_pos, limit2, rebuild, anyreb, grav, cnew, t0,
                   lift_start, geo, lo, dims, side, cell0, count, slots, overflow, reach, nnb, nbr, hist, new_nbr,
                   new_hist, hf, hc, prm, gap, ncont, worst, status, nstep):
        grid = cuda.cg.this_grid()
        start = cuda.grid(1)
        stride = cuda.gridsize(1)
        for step in range(nsteps):
            for i in range(start, n, stride):
                _drift_one(i, active, status, heap, first, dt, pos, vel, omg, force, torque, mass, inv_inertia,
                           ref_pos, limit2, rebuild, anyreb, grav, cnew, step, t0, lift_start, geo)
            grid.sync()
            if anyreb[0] != 0:
                for i in range(start, n, stride):
                    _bin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count, slots, cap, overflow)
                grid.sync()
                for i in range(start, n, stride):
                    _find_one(i, heap, rebuild, pos, ref_pos, rad, reach, lo, dims, side, cell0, count, slots, cap,
                              nnb, nbr, hist, new_nbr, new_hist, overflow)
                grid.sync()
            for i in range(start, n, stride):
                _unbin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count)
                forces_one(i, active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, hf, hc, prm, gap,
                           geo, dt, force, torque, ncont, cnew, worst)
            grid.sync()
            if start == 0:  # every thread read anyreb before the sync above
                anyreb[0] = 0
            for i in range(start, n, stride):
                _kick_one(i, active, heap, first, rebuild, dt, vel, omg, force, torque, mass, inv_inertia, ncont,
                          cnew, overlap_limit, speed_limit, worst, status)
            grid.sync()
        if start == 0:
            nstep[0] += nsteps

    return persistent


def _block_kernel(forces_one, jit=cuda.jit):
    """``nsteps`` whole steps in one launch of a thread block a heap: block h's threads stride over heap h's
    grains and wait for each other between phases with ``syncthreads`` (a barrier of one
    multiprocessor, where the persistent kernel's grid sync spans the GPU); heaps never touch each other's
    grains, so no block waits for another. A heap's rebuild runs on the steps where it asked for one. A heap
    is as fast as one multiprocessor can step it: for batches of small heaps, not one large heap. Under
    numba's simulator a block is one thread (grains in order, blocks one after another: each heap bit for bit
    the CPU kernel's)."""

    @jit
    def blocks(nsteps, cap, overlap_limit, speed_limit, active, heap, first, dt, pos, vel, omg, force, torque, rad,
               mass, inv_inertia, ref_pos, limit2, rebuild, anyreb, grav, cnew, t0, lift_start, geo, lo, dims, side,
               cell0, count, slots, overflow, reach, nnb, nbr, hist, new_nbr, new_hist, hf, hc, prm, gap,
               ncont, worst, status, nstep):
        h = cuda.blockIdx.x
        start, stride = first[h] + cuda.threadIdx.x, cuda.blockDim.x
        end = first[h + 1]
        for step in range(nsteps):
            # read by every thread after the sync that ended the last step (the drift below may switch the heap
            # off, but only once its status says so): all leave together
            if active[h] == 0 or status[h] != OK:
                break
            for i in range(start, end, stride):
                _drift_one(i, active, status, heap, first, dt, pos, vel, omg, force, torque, mass, inv_inertia,
                           ref_pos, limit2, rebuild, anyreb, grav, cnew, step, t0, lift_start, geo)
            cuda.syncthreads()
            if rebuild[h] != 0:
                for i in range(start, end, stride):
                    _bin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count, slots, cap, overflow)
                cuda.syncthreads()
                for i in range(start, end, stride):
                    _find_one(i, heap, rebuild, pos, ref_pos, rad, reach, lo, dims, side, cell0, count, slots, cap,
                              nnb, nbr, hist, new_nbr, new_hist, overflow)
                cuda.syncthreads()
            for i in range(start, end, stride):
                _unbin_one(i, heap, rebuild, pos, lo, dims, side, cell0, count)
                forces_one(i, active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, hf, hc, prm, gap,
                           geo, dt, force, torque, ncont, cnew, worst)
            cuda.syncthreads()
            for i in range(start, end, stride):
                _kick_one(i, active, heap, first, rebuild, dt, vel, omg, force, torque, mass, inv_inertia, ncont,
                          cnew, overlap_limit, speed_limit, worst, status)
            cuda.syncthreads()
        if h == 0 and cuda.threadIdx.x == 0:
            nstep[0] += nsteps

    return blocks


def _law_of(contact):
    """One slot's contact around the composed ``contact``, shared by both layouts (:func:`_pairs_of`)."""

    @cuda.jit(device=True)
    def law_on(i, s, h, Ri, pos, vel, omg, rad, mass, inv_inertia, nbr, ht, p, dt, force, torque, ncont, cnew):
        """Slot s's contact (within reach) added to both grains; returns its overlap over the smaller radius,
        and 1 where it counts as a contact (grain j's count added here, grain i's by the caller)."""
        j = nbr[i, s]
        Rj = rad[j]
        dx = pos[i, 0] - pos[j, 0]
        dy = pos[i, 1] - pos[j, 1]
        dz = pos[i, 2] - pos[j, 2]
        Rs = Ri * Rj / (Ri + Rj)
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        inv = 1.0 / d
        delta = Ri + Rj - d
        fx, fy, fz, tix, tiy, tiz, tjx, tjy, tjz, ov = contact(
            dx * inv, dy * inv, dz * inv, delta, Ri - 0.5 * delta, Rj - 0.5 * delta, Rs,
            mass[i] * mass[j] / (mass[i] + mass[j]), inv_inertia[i], inv_inertia[j], ncont[i], ncont[j],
            vel[i, 0] - vel[j, 0], vel[i, 1] - vel[j, 1], vel[i, 2] - vel[j, 2],
            omg[i, 0], omg[i, 1], omg[i, 2], omg[j, 0], omg[j, 1], omg[j, 2], ht, s, p, PP, dt[h])
        _add3(force, i, fx, fy, fz)
        _add3(force, j, -fx, -fy, -fz)
        _add3(torque, i, tix, tiy, tiz)
        _add3(torque, j, tjx, tjy, tjz)
        hit = 0.0
        if ht[s, A_OLD] > 0.0:
            hit = 1.0
            cuda.atomic.add(cnew, j, 1.0)
        return ov / min(Ri, Rj), hit

    return law_on


def _pairs_of(contact):
    """Grain i's pairs (its slots, j > i): their contacts, added to both grains atomically. Returns grain i's
    largest relative overlap and its contacts counted (:func:`_settle` adds them); and the same for one slot
    (``pair_of``: the ``pair`` layout's thread, ``pair_forces`` in :func:`_force_kernels`).

    Two passes over each window of :data:`WINDOW` slots: the first marks the pairs within reach (a bit each)
    and clears the others' history, the second runs the contact law on the marked ones in slot order. So
    the threads of a warp each compute their k-th contact together, where one pass ran the law for slot s
    whenever any thread's slot s touched, the others waiting (7.7 of 32 threads active on an H200 at 64
    heaps, docs/performance.md). The sums' order within a grain is the one pass's."""
    law_on = _law_of(contact)

    @cuda.jit(device=True)
    def pairs_of(i, h, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, p, gap, dt, force, torque, ncont,
                 cnew):
        ht = _raw(hist[i])
        most, count = 0.0, 0.0
        Ri = rad[i]
        for base in range(0, nnb[i], WINDOW):
            mask = 0
            for s in range(base, min(base + WINDOW, nnb[i])):
                if _within(i, s, h, Ri, pos, rad, nbr, gap):
                    mask |= 1 << (s - base)
                else:
                    _clear(ht, s)
            while mask != 0:
                low = mask & -mask
                mask ^= low
                s = base + cuda.popc(low - 1)
                ov, hit = law_on(i, s, h, Ri, pos, vel, omg, rad, mass, inv_inertia, nbr, ht, p, dt, force, torque,
                                 ncont, cnew)
                count += hit
                most = _fold(most, ov)
        return most, count

    @cuda.jit(device=True)
    def pair_of(i, s, active, heap, pos, vel, omg, rad, mass, inv_inertia, nnb, nbr, hist, prm, gap, dt, force,
                torque, ncont, cnew, worst):
        """Slot s of grain i alone: its contact, or its history cleared out of reach; its tallies straight
        into the grain's count and the heap's largest overlap (whole numbers and a maximum: any order)."""
        h = heap[i]
        if active[h] == 0 or s >= nnb[i]:
            return
        ht = _raw(hist[i])
        Ri = rad[i]
        if not _within(i, s, h, Ri, pos, rad, nbr, gap):
            _clear(ht, s)
            return
        ov, hit = law_on(i, s, h, Ri, pos, vel, omg, rad, mass, inv_inertia, nbr, ht, _raw(prm[h]), dt, force,
                         torque, ncont, cnew)
        _settle(i, h, _fold(0.0, ov), hit, cnew, worst)

    return pairs_of, pair_of


@cuda.jit(device=True)
def _within(i, s, h, Ri, pos, rad, nbr, gap):
    """Whether slot s's pair is within reach (a NaN distance too, as the law always ran on it)."""
    j = nbr[i, s]
    reach = Ri + rad[j] + gap[h, PP]
    return not _dist2(pos, i, j) >= reach * reach


@cuda.jit(device=True)
def _clear(ht, s):
    """A slot's history out of reach: springs and contact radius cleared; the cached R*^(1/3) stays valid."""
    for c in range(ht.shape[1]):
        if c != R13:
            ht[s, c] = 0.0


#: slots a grain's pairs are marked in at a time (bits of one int64 mask, the sign bit unused)
WINDOW = 32


@cuda.jit(device=True)
def _dist2(pos, i, j):
    dx = pos[i, 0] - pos[j, 0]
    dy = pos[i, 1] - pos[j, 1]
    dz = pos[i, 2] - pos[j, 2]
    return dx * dx + dy * dy + dz * dz


@cuda.jit(device=True)
def _fold(most, v):
    """A running maximum that passes over a NaN, as numba's atomic maximum did when each contact called it
    (a heap whose overlaps are NaN is stopped by the speed check)."""
    return v if v > most else most


@cuda.jit(device=True)
def _settle(i, h, most, count, cnew, worst):
    """Grain i's share of the step's tallies, once a grain instead of once a contact: its contact count (whole
    numbers: exact in any order) and its largest overlap into the heap's (skipped where the heap's is larger
    already: the maximum only grows within a chunk). Every contact of a heap once hit one address."""
    if count > 0.0:
        cuda.atomic.add(cnew, i, count)
    if most > worst[h]:
        cuda.atomic.max(worst, h, most)


@cuda.jit(device=True)
def _add3(a, i, x, y, z):
    """a[i] += (x, y, z), atomically: other threads add their pairs' share to the same grain."""
    cuda.atomic.add(a, (i, 0), x)
    cuda.atomic.add(a, (i, 1), y)
    cuda.atomic.add(a, (i, 2), z)


def _walls_of(contact):
    """Grain i's floor and cylinder contacts and the settling drag (the CPU kernel's wall blocks)."""

    @cuda.jit(device=True)
    def on_wall(i, nx, ny, nz, delta, gap, wall_vz, ht, row, Ri, vel, omg, mass, inv_inertia, ncont, p, dt,
                force, torque):
        """Grain i on a wall moving up at ``wall_vz``: its contact with history ``ht[i]`` and interaction
        ``row`` added to its force and torque, or, out of reach, its history cleared. Returns its relative
        overlap and 1 (a contact), or -1 and 0 out of reach."""
        if not delta > -gap:
            for c in range(ht.shape[1]):
                if c != R13:
                    ht[i, c] = 0.0
            return -1.0, 0.0
        fx, fy, fz, tix, tiy, tiz, _a, _b, _c, ov = contact(
            nx, ny, nz, delta, Ri - delta, 0.0, Ri, mass[i], inv_inertia[i], 0.0, ncont[i], 1.0,
            vel[i, 0], vel[i, 1], vel[i, 2] - wall_vz, omg[i, 0], omg[i, 1], omg[i, 2], 0.0, 0.0, 0.0,
            _raw(ht), i, p, row, dt)
        _add3(force, i, fx, fy, fz)
        _add3(torque, i, tix, tiy, tiz)
        return ov / Ri, 1.0

    @cuda.jit(device=True)
    def walls_of(i, h, pos, vel, omg, rad, mass, inv_inertia, hf, hc, p, gap, geo, dt, force, torque, ncont, most,
                 count):
        """Grain i's wall contacts, folded into its running tallies (``most``, ``count``: as
        :func:`_pairs_of`'s), which it returns."""
        Ri = rad[i]
        drag = geo[h, 5]
        if drag > 0.0:  # settling aid only (set during the fill): background viscous drag
            m = drag * mass[i]
            _add3(force, i, -m * vel[i, 0], -m * vel[i, 1], -m * vel[i, 2])
        # floor z = 0, normal +z
        if geo[h, 4] > 0.0:
            ov, hit = on_wall(i, 0.0, 0.0, 1.0, Ri - pos[i, 2], gap[h, FLOOR], 0.0, hf, FLOOR, Ri, vel, omg, mass,
                              inv_inertia, ncont, p, dt[h], force, torque)
            if hit > 0.0:
                most = _fold(most, ov)
                count += hit
        # cylinder: vertical, axis through the origin, open bottom rim at z_edge moving up at vlift
        if geo[h, 3] > 0.0:
            delta, nx, ny, nz = cylinder_overlap(pos[i, 0], pos[i, 1], pos[i, 2], Ri, geo[h, 0], geo[h, 1])
            ov, hit = on_wall(i, nx, ny, nz, delta, gap[h, CYL], geo[h, 2], hc, CYL, Ri, vel, omg, mass,
                              inv_inertia, ncont, p, dt[h], force, torque)
            if hit > 0.0:
                most = _fold(most, ov)
                count += hit
        return most, count

    return walls_of


#: the per-grain and per-heap arrays a batch keeps on the device, and the ones a chunk may leave half-done
STATE = ("pos", "vel", "omg", "force", "torque", "ref_pos", "ncont", "cnew", "hf", "hc", "nnb", "nbr", "hist",
         "geo", "active", "status")


def pack(systems: list, width: int = 16, cell_cap: int = 48) -> dict:
    """Every heap's arrays, heap after heap, as the kernels take them (host numpy arrays, named as the
    kernels' parameters). Starts from each system's own state, neighbour list and contact history."""
    ss = list(systems)
    cat = lambda f: np.ascontiguousarray(np.concatenate([f(s) for s in ss]))  # noqa: E731
    host = {
        "pos": cat(lambda s: s.particles.pos), "vel": cat(lambda s: s.particles.vel),
        "omg": cat(lambda s: s.particles.omg), "force": cat(lambda s: s.force), "torque": cat(lambda s: s.torque),
        "rad": cat(lambda s: s.particles.rad), "mass": cat(lambda s: s.mass),
        "inv_inertia": cat(lambda s: s.inv_inertia), "ref_pos": cat(lambda s: s.ref_pos),
        "ncont": cat(lambda s: s.ncont), "cnew": cat(lambda s: s.cnew), "hf": cat(lambda s: s.hf),
        "hc": cat(lambda s: s.hc), "heap": np.repeat(np.arange(len(ss)), [s.n for s in ss]).astype(np.int64),
        "dt": np.array([s.dt for s in ss]), "prm": np.ascontiguousarray(np.stack([s.prm for s in ss])),
        "gap": np.stack([s.gap for s in ss]), "geo": np.stack([s.geo for s in ss]),
        "lift_start": np.array([s.walls.lift_start for s in ss]), "reach": np.array([s.reach for s in ss]),
        "limit2": np.array([(0.5 * s.skin) ** 2 for s in ss]), "grav": np.asarray(ss[0].grav, dtype=np.float64),
        "active": np.ones(len(ss), np.int64), "status": np.zeros(len(ss), np.int64),
        "rebuild": np.zeros(len(ss), np.int64), "worst": np.zeros(len(ss)), "overflow": np.zeros(1, np.int64),
        "anyreb": np.zeros(1, np.int64), "nstep": np.zeros(1, np.int64),
        "t0": np.array([s.t for s in ss]),
    }
    first = np.concatenate([[0], np.cumsum([s.n for s in ss])]).astype(np.int64)
    return {**host, "first": first, **_slots(ss, first, width), **_grids(ss, cell_cap)}


def _slots(systems: list, first: np.ndarray, width: int) -> dict:
    """Each grain's neighbours j > i and their contact history, from the systems' own pair lists (wider
    than ``width`` where a grain has more)."""
    n = int(first[-1])
    pi = np.concatenate([s.pi[:int(s.npairs[0])] + off for s, off in zip(systems, first)]).astype(np.int64)
    pj = np.concatenate([s.pj[:int(s.npairs[0])] + off for s, off in zip(systems, first)]).astype(np.int64)
    ht = np.concatenate([s.ht[:int(s.npairs[0])] for s in systems])
    nnb = np.bincount(pi, minlength=n).astype(np.int64)
    width = max(width, int(nnb.max(initial=0)))
    slot = np.arange(len(pi)) - np.concatenate([[0], np.cumsum(nnb)])[pi]  # pairs come sorted by i
    nbr = np.zeros((n, width), np.int64)
    hist = np.zeros((n, width, HIST), systems[0].ht.dtype)  # a batch's systems share one precision
    nbr[pi, slot], hist[pi, slot] = pj, ht
    return {"nnb": nnb, "nbr": nbr, "hist": hist, "new_nbr": np.zeros_like(nbr), "new_hist": np.zeros_like(hist)}


def _grids(systems: list, cell_cap: int) -> dict:
    grids = [Grid.around(s.particles.pos, 2.0 * float(s.particles.rad.max()) + s.reach) for s in systems]
    sizes = [int(np.prod(g.dims)) for g in grids]
    cell0 = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    return {"lo": np.stack([g.lo for g in grids]), "dims": np.stack([g.dims for g in grids]),
            "side": np.array([g.side for g in grids]), "cell0": cell0,
            "count": np.zeros(cell0[-1], np.int64), "slots": np.zeros((cell0[-1], cell_cap), np.int64)}


def _to_pairs(s, nnb: np.ndarray, nbr: np.ndarray, hist: np.ndarray) -> None:
    """A system's pair list (sorted by i, then j, as the CPU kernel keeps it) from one heap's slots."""
    i = np.repeat(np.arange(len(nnb)), nnb)
    slot = np.arange(len(i)) - np.repeat(np.cumsum(nnb) - nnb, nnb)
    j, h = nbr[i, slot], hist[i, slot]
    order = np.lexsort((j, i))
    if len(order) > len(s.pi):
        s._alloc(2 * len(order))
    s.pi[:len(order)], s.pj[:len(order)], s.ht[:len(order)] = i[order], j[order], h[order]
    s.npairs[0] = len(order)


@functools.cache
def _params(kernel) -> tuple[str, ...]:
    """A kernel's parameter names: a launch passes each the array or value of that name."""
    fn = getattr(kernel, "py_func", None) or getattr(kernel, "fn", None)
    return tuple(inspect.signature(fn).parameters)


def _scalars(host: dict, systems: list, cell_cap: int, nsteps: int = 1) -> dict:
    return {"n": len(host["heap"]), "cap": cell_cap,
            "nsteps": nsteps, "overlap_limit": float(systems[0].overlap_limit),
            "speed_limit": float(systems[0].speed_limit)}


def compile_ptx(spec: str, systems: list, cc: tuple[int, int] = (9, 0)) -> dict[str, str]:
    """Each kernel of composition ``spec`` compiled to PTX for compute capability ``cc`` (9.0: H100,
    H200), typed by the arrays :func:`pack` makes of ``systems``: needs numba's CUDA compiler (the
    [gpu] extra and CUDA's NVVM), not a GPU. The check that the laws compile for the GPU as written."""
    from numba import typeof

    import numba.cuda.dispatcher as dispatcher
    from types import SimpleNamespace

    host = pack(systems)
    values = {**host, **_scalars(host, systems, 48)}
    out = {}
    # numba-cuda asks the current GPU's compute capability when it compiles a function a kernel calls
    # (the composed contact); with no GPU there is none: it is given the target's
    asked = dispatcher.get_current_device
    dispatcher.get_current_device = lambda: SimpleNamespace(compute_capability=cc)
    try:
        for name, kernel in _build(contact_of(spec)).items():
            types = tuple(typeof(values[p]) for p in _params(kernel))
            out[name] = cuda.compile_ptx(kernel.py_func, types, cc=cc)[0]
    finally:
        dispatcher.get_current_device = asked
    return out


#: how a batch runs its steps (docs/performance.md measures each on a GPU):
#: ``launch``: a kernel a phase, launched from Python every step, the host reading whether any heap asked for
#: a neighbour rebuild (the engine as first measured); ``device``: the same kernels with no read-back, all
#: five launched every step and each heap's threads skipping a rebuild it did not ask for; ``graph``:
#: ``device``'s launches for :data:`GRAPH_STEPS` steps captured once in a CUDA graph and replayed;
#: ``persistent``: one cooperative launch a chunk (:func:`_persistent_kernel`); ``blocks``: one launch a chunk, a
#: thread block a heap (:func:`_block_kernel`). Chosen by ``CALIB_GPU_STEP``.
MODES = ("launch", "device", "graph", "persistent", "blocks")
#: the default: the fastest on an H200 from 16 to 256 `default` heaps and for one `paper` heap, and within 2 % of
#: `persistent` for one `default` heap (docs/performance.md, 2026-11-28: 36.7 us a step against 36.0)
DEFAULT_MODE = "graph"
GRAPH_STEPS = 50
#: the blocks mode's threads a heap under the simulator: one keeps its arithmetic in the CPU kernel's order
SIM_BLOCK_THREADS = 1
#: the threads a block of the launch modes' kernels under the simulator: one, the blocks one after another. The
#: order of a kernel's threads sets a grain's bits (atomic sums into other threads' grains; the order of grains
#: in a cell, which orders the neighbour lists), and the simulator runs a block's threads as Python threads that
#: the interpreter switches between every 5 ms: on a loaded machine their sums came in another order (a
#: lattice's velocities 3.5e-18 off the CPU kernel's under pytest-xdist). A thread is a Python thread either
#: way, so blocks of one cost no more than blocks of 32, and the test suite's runner (tests/simulator_blocks.py)
#: takes such blocks in turn on the launching thread, with no thread started at all
SIM_THREADS = 1


#: how a step's contacts are shared among threads in the kernel-a-phase modes (``launch``, ``device``, ``graph``):
#: ``grain``: a thread a grain, its pairs one after another, then its walls (:func:`_pairs_of`); ``pair``: a thread
#: a neighbour slot (grains x slots threads, most of them idle where no pair is within reach), then a thread a
#: grain for the walls; ``auto``: ``pair`` for a batch of fewer than :data:`PAIR_BELOW_GRAINS` grains, where a
#: grain's thread stepping its ~10 contacts in a row is what bounds a step, else ``grain``. Chosen by
#: ``CALIB_GPU_CONTACTS``; the persistent and block kernels are ``grain``.
CONTACTS = ("auto", "grain", "pair")
DEFAULT_CONTACTS = "auto"
#: measured on an H200 (docs/performance.md, ``benchmarks/gpu_device_layout.sh``): a thread a slot took 25.3, 29.8
#: and 36.8 us a step for 1, 2 and 4 ``default`` heaps (3,971-15,884 grains) against 35.8, 39.4 and 42.8 a thread
#: a grain; 49.8 against 49.1 at 31,768 grains, and it loses from there (54.4 against 49.3 for a 44,669-grain
#: ``paper`` heap, 80.8 against 70.1 at 63,536), all on fresh fills, whose grains hardly touch: not yet timed on
#: heaps in contact (docs/performance.md, "What the figures below timed")
PAIR_BELOW_GRAINS = 24_000


def contact_layout(layout: str | None = None, grains: int | None = None) -> str:
    """The contact layout asked for (``layout``, else ``CALIB_GPU_CONTACTS``, else :data:`DEFAULT_CONTACTS`),
    checked; ``auto`` resolved for a batch of ``grains`` where given."""
    layout = layout or os.environ.get("CALIB_GPU_CONTACTS") or DEFAULT_CONTACTS
    if layout not in CONTACTS:
        raise CalibError(f"unknown GPU contact layout {layout!r} (CALIB_GPU_CONTACTS): one of {', '.join(CONTACTS)}")
    if layout == "auto" and grains is not None:
        return "pair" if grains < PAIR_BELOW_GRAINS else "grain"
    return layout


def step_mode(mode: str | None = None) -> str:
    """The stepping mode asked for (``mode``, else ``CALIB_GPU_STEP``, else :data:`DEFAULT_MODE`), checked."""
    mode = mode or os.environ.get("CALIB_GPU_STEP") or DEFAULT_MODE
    if mode not in MODES:
        raise CalibError(f"unknown GPU stepping mode {mode!r} (CALIB_GPU_STEP): one of {', '.join(MODES)}")
    return mode


class Batch:
    """Heaps advanced together: ``systems`` (:class:`.system.System`, one composition of laws) packed
    into one set of device arrays. :meth:`advance` runs steps on all the active ones, :meth:`pull`
    brings positions and velocities back into the systems, :meth:`push_walls` sends their wall
    settings (lift, drag, cylinder on or off) to the device. ``mode``: how the steps are launched
    (:data:`MODES`); every mode runs the same device functions.

    Starts from each system's own state, neighbour list and contact history, so that a batch and the
    CPU kernel step from the same point. The device arrays keep their addresses between chunks (a captured
    graph holds them) except where :meth:`_grow` makes room, which drops the graphs. ``contacts``: a thread a
    grain or a neighbour slot for the pairs (:data:`CONTACTS`), in the kernel-a-phase modes; ``max_registers``:
    the contact kernels' registers a thread (:func:`register_cap`)."""

    def __init__(self, systems: list, width: int = 16, cell_cap: int = 48, block: int = 128,
                 mode: str | None = None, contacts: str | None = None, max_registers: int | None = None):
        specs = {s.model.spec for s in systems}
        if len(specs) != 1:
            raise CalibError(f"a GPU batch runs one composition of contact laws; these heaps have {len(specs)}")
        if len({s.precision for s in systems}) != 1:
            raise CalibError("a GPU batch runs one precision; these heaps mix them")
        self.systems, self.spec, self.mode = list(systems), specs.pop(), step_mode(mode)
        self.contacts = contact_layout(contacts, sum(s.n for s in systems))
        self.block = block
        self.cuda = cuda_module()
        self.k = kernels(self.spec, register_cap(max_registers))
        self.width, self.cell_cap = width, cell_cap
        self.host = pack(self.systems, width, cell_cap)
        self.first = self.host["first"]
        self.width = self.host["nbr"].shape[1]
        self.d = {k: self.cuda.to_device(v) for k, v in self.host.items()}
        self._graphs, self._coop, self._blk, self._stream, self._kept = {}, None, None, None, None

    def _set(self, name: str, value: np.ndarray) -> None:
        """Host values into device array ``name``, in place (its address stays)."""
        self.d[name].copy_to_device(np.ascontiguousarray(value, dtype=self.d[name].dtype))

    def _args(self, kernel, extra: dict | None = None) -> list:
        """``kernel``'s arguments by parameter name: the batch's scalars, ``extra``, the device arrays."""
        scalars = {**_scalars(self.host, self.systems, self.cell_cap), **(extra or {})}
        return [scalars[p] if p in scalars else self.d[p] for p in _params(kernel)]

    def _launch(self, name: str, threads: int, stream=None) -> None:
        """Kernel ``name`` on ``threads`` threads (into ``stream``: a graph being built)."""
        kernel = self.k[name]
        b = SIM_THREADS if SIMULATOR else self.block
        grid = (threads + b - 1) // b
        (kernel[grid, b] if stream is None else kernel[grid, b, stream])(*self._args(kernel))

    # -------------------------------------------------------------- stepping
    def advance(self, nsteps: int) -> np.ndarray:
        """``nsteps`` steps of every active heap; returns each heap's status (:data:`OK`, :data:`OVERLAP`,
        :data:`SPEED`). A chunk whose neighbour slots or cells overflowed is run again with more room."""
        while True:
            self._keep()
            self._chunk(nsteps)
            if not self.d["overflow"].copy_to_host()[0]:
                break
            for k, v in self._kept.items():
                self.d[k].copy_to_device(v)
            self._grow()
        status = self.d["status"].copy_to_host()
        worst = self.d["worst"].copy_to_host()
        for h, s in enumerate(self.systems):
            if self.host["active"][h]:  # as System.advance counts it
                s.t += nsteps * s.dt
                s.n_steps += nsteps
                s.max_overlap = max(s.max_overlap, float(worst[h]))
        # a heap that blew up on the chunk's last step has not reached the drift that switches it off
        self.host["active"] = np.where(status == OK, self.d["active"].copy_to_host(), 0)
        self._set("active", self.host["active"])
        return status

    def _chunk(self, nsteps: int) -> None:
        nh = len(self.systems)
        for name, v in (("worst", np.zeros(nh)), ("overflow", np.zeros(1)), ("nstep", np.zeros(1)),
                        ("anyreb", np.zeros(1)), ("t0", [s.t for s in self.systems])):
            self._set(name, v)
        getattr(self, f"_steps_{self.mode}")(nsteps)
        self.cuda.synchronize()

    def _steps_launch(self, nsteps: int) -> None:
        n = len(self.host["heap"])
        for _ in range(nsteps):
            self._launch("kick_drift", n)
            # skip a rebuild no heap asked for (same result): here a step is bound by its launches (~70 us each
            # on an H200, docs/performance.md), and reading one flag costs less than two launches
            if self.d["anyreb"].copy_to_host()[0]:
                self._rebuild(n)
            self._forces(n)
            self._launch("kick", n)

    def _forces(self, n: int, stream=None) -> None:
        if self.contacts == "pair":
            self._launch("pair_forces", n * self.width, stream)
            self._launch("wall_forces", n, stream)
        else:
            self._launch("forces", n, stream)

    def _rebuild(self, n: int, stream=None) -> None:
        self._launch("bin_grains", n, stream)
        self._launch("find_neighbours", n, stream)

    def _steps_device(self, nsteps: int, stream=None) -> None:
        n = len(self.host["heap"])
        for _ in range(nsteps):
            self._launch("kick_drift", n, stream)
            self._rebuild(n, stream)
            self._forces(n, stream)
            self._launch("kick", n, stream)

    def _steps_graph(self, nsteps: int) -> None:
        """Whole graphs of :data:`GRAPH_STEPS` steps replayed, the rest launched one by one. Under the
        simulator (no graphs there) the same launches as ``device``."""
        if SIMULATOR:
            return self._steps_device(nsteps)
        if GRAPH_STEPS not in self._graphs:
            warm = min(nsteps, GRAPH_STEPS)
            self._steps_device(warm)  # compiles and loads the kernels: not while a graph is being captured
            nsteps -= warm
        reps, rest = divmod(nsteps, GRAPH_STEPS)
        if reps:
            graph = self._graph(GRAPH_STEPS)
            self.cuda.synchronize()  # the chunk's values were copied on numba's stream, not the graph's
            for _ in range(reps):
                graph.launch(self._stream)
            self._stream.sync()
        self._steps_device(rest)

    def _graph(self, steps: int):
        """The launches of ``steps`` steps captured in a CUDA graph (numba-cuda launches into a cuda.core
        GraphBuilder passed as the stream), built once per room size."""
        if steps not in self._graphs:
            try:
                from cuda.core import Device
            except ImportError:  # cuda.core before 0.4
                from cuda.core.experimental import Device
            dev = Device()
            dev.set_current()
            if self._stream is None:
                self._stream = dev.create_stream()
            builder = dev.create_graph_builder()
            builder.begin_building()
            self._steps_device(steps, builder)
            self._graphs[steps] = builder.end_building().complete()
        return self._graphs[steps]

    def _steps_persistent(self, nsteps: int) -> None:
        kernel, grid, block = self._cooperative()
        kernel[grid, block](*self._args(kernel, {"nsteps": nsteps}))

    def _steps_blocks(self, nsteps: int) -> None:
        kernel, threads = self._blocks()
        kernel[len(self.systems), threads](*self._args(kernel, {"nsteps": nsteps}))

    def _blocks(self):
        """The block-a-heap kernel, specialized to the batch's arrays, and its threads a heap: ``block``, at most
        what its registers leave room for (its kernel takes ~130 registers a thread: 512 threads do not fit
        a multiprocessor's 65,536 for every composition); :data:`SIM_BLOCK_THREADS` under the simulator."""
        if self._blk is None:
            kernel = self.k["blocks"]
            if SIMULATOR:
                self._blk = (kernel, SIM_BLOCK_THREADS)
            else:
                kernel = kernel.specialize(*self._args(kernel, {"nsteps": 1}))
                self._blk = (kernel, max(1, min(self.block, kernel.get_max_threads_per_block())))
        return self._blk

    @property
    def heap_threads(self) -> int:
        """The threads a heap in the ``blocks`` mode (``block``, or fewer where the kernel's registers allow
        no more)."""
        return self._blocks()[1]

    def _cooperative(self):
        """The persistent kernel, specialized to the batch's arrays, with the most blocks that can all be
        resident at once (a cooperative launch needs them all running); one thread under the simulator."""
        if self._coop is None:
            kernel = self.k["persistent"]
            if SIMULATOR:
                self._coop = (kernel, 1, 1)
            else:
                kernel = kernel.specialize(*self._args(kernel, {"nsteps": 1}))
                most = next(iter(kernel.overloads.values())).max_cooperative_grid_blocks(self.block)
                need = (len(self.host["heap"]) + self.block - 1) // self.block
                self._coop = (kernel, max(1, min(most, need)), self.block)
        return self._coop

    def _keep(self) -> None:
        """The state a chunk may leave half-done, copied on the device (a host copy would move GBs), into
        arrays allocated once per room size."""
        if self._kept is None:
            self._kept = {k: self.cuda.device_array_like(self.d[k]) for k in STATE}
        for k, v in self._kept.items():
            v.copy_to_device(self.d[k])

    def _grow(self) -> None:
        """Twice the neighbour slots and cell room, the lists rebuilt from the current positions."""
        self.width, self.cell_cap = 2 * self.width, 2 * self.cell_cap
        state = {k: self.d[k].copy_to_host() for k in STATE}
        n = len(self.host["heap"])
        old_nbr, old_hist, old_nnb = state.pop("nbr"), state.pop("hist"), state.pop("nnb")
        f = old_hist.dtype
        slots = {"nnb": old_nnb, "nbr": np.zeros((n, self.width), np.int64), "hist": np.zeros((n, self.width, HIST), f),
                 "new_nbr": np.zeros((n, self.width), np.int64), "new_hist": np.zeros((n, self.width, HIST), f)}
        w = old_nbr.shape[1]
        slots["nbr"][:, :w], slots["hist"][:, :w] = old_nbr, old_hist
        grids = _grids(self.systems, self.cell_cap)
        for name, v in {**slots, "count": grids["count"], "slots": grids["slots"]}.items():
            self.host[name] = v
            self.d[name] = self.cuda.to_device(v)
        # they hold the old arrays (and the cell count)
        self._graphs, self._coop, self._blk, self._kept = {}, None, None, None

    # -------------------------------------------------------------- exchange with the systems
    def pull(self, lists: bool = False) -> None:
        """Positions, velocities, spins, forces and wall settings back into each system; with ``lists``
        also its neighbour list, contact histories and contact counts (all a checkpoint needs)."""
        names = ["pos", "vel", "omg", "force", "torque", "geo"]
        if lists:
            names += ["ref_pos", "hf", "hc", "ncont", "cnew", "nnb", "nbr", "hist"]
        got = {k: self.d[k].copy_to_host() for k in names}
        for h, (s, a, b) in enumerate(zip(self.systems, self.first[:-1], self.first[1:])):
            p = s.particles
            p.pos[:], p.vel[:], p.omg[:] = got["pos"][a:b], got["vel"][a:b], got["omg"][a:b]
            s.force[:], s.torque[:] = got["force"][a:b], got["torque"][a:b]
            s.geo[:] = got["geo"][h]
            if lists:
                for k in ("ref_pos", "hf", "hc", "ncont", "cnew"):
                    getattr(s, k)[:] = got[k][a:b]
                _to_pairs(s, got["nnb"][a:b], got["nbr"][a:b] - a, got["hist"][a:b])

    def push_walls(self) -> None:
        """The systems' wall settings (``geo``: lift speed, cylinder on, drag) and lift start to the device."""
        self.host["geo"] = np.stack([s.geo for s in self.systems])
        self.host["lift_start"] = np.array([s.walls.lift_start for s in self.systems])
        self._set("geo", self.host["geo"])
        self._set("lift_start", self.host["lift_start"])

    def stop(self, h: int) -> None:
        """Heap ``h`` takes no more steps (its test is done)."""
        self.host["active"][h] = 0
        self._set("active", self.host["active"])


def run_heaps(tests: list, progress=None, checkpoints: list | None = None, every: float | None = None,
              mode: str | None = None) -> list:
    """Run heap tests (:class:`.heap.HeapTest`) together on the GPU, one batch per composition of laws
    and chunk length; returns their :class:`.heap.HeapResult`, in order. Each test follows the CPU
    engine's protocol: every active heap advances one chunk, then each test decides its next phase (its
    walls change on the device before the next chunk); a finished or blown-up heap leaves the batch.
    ``checkpoints`` (a file per test, or None): each unfinished test's state is saved there every
    ``every`` seconds (:func:`.heap.save_checkpoint`), to go on from with :func:`.heap.resume`. ``mode``:
    how the batches step (:func:`step_mode`)."""
    from .heap import CHECKPOINT_EVERY

    results: list = [None] * len(tests)
    files = list(checkpoints) if checkpoints is not None else [None] * len(tests)
    groups: dict = {}
    for i, t in enumerate(tests):
        groups.setdefault((t.system.model.spec, t.numerics.chunk, t.system.precision), []).append(i)
    for (_, chunk, _), members in groups.items():
        done = _run_batch([tests[i] for i in members], chunk, [files[i] for i in members],
                          CHECKPOINT_EVERY if every is None else every, mode)
        for i, r in zip(members, done):
            results[i] = r
        if progress:
            progress(len([r for r in results if r is not None]), len(tests))
    return results


def _run_batch(tests: list, chunk: int, files: list, every: float, mode: str | None) -> list:
    batch = Batch([t.system for t in tests], mode=mode)
    out: list = [None] * len(tests)
    for h, t in enumerate(tests):
        if t.done:  # nothing to step (a zero time limit)
            out[h] = t.result()
            batch.stop(h)
    last = time.monotonic()
    while any(r is None for r in out):
        status = batch.advance(chunk)
        save = any(files) and time.monotonic() - last > every
        batch.pull(lists=save)
        for h, t in enumerate(tests):
            if out[h] is None:
                out[h] = _decide(batch, h, t, status[h])
        batch.push_walls()
        if save:
            _save(tests, out, files)
            last = time.monotonic()
    return out


def _decide(batch: Batch, h: int, t, status: int):
    """One heap's next step after a chunk: its result if it blew up or is done (it leaves the batch), else None."""
    if status != OK:
        what = "overlap above the limit" if status == OVERLAP else "a speed above the limit (or NaN)"
        return t.result(f"unstable run: {what} in the GPU chunk ending at t = {t.system.t:.4g} s; "
                        "lower the time step or raise the shear modulus")
    t.advanced()
    if not t.done:
        return None
    batch.stop(h)
    return t.result()


def _save(tests: list, out: list, files: list) -> None:
    from .heap import save_checkpoint

    for t, r, f in zip(tests, out, files):
        if r is None and f is not None:
            save_checkpoint(f, t.state())
