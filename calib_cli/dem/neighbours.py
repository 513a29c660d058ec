"""Neighbour search: a Verlet list of pairs from a cell list, and the carrying of contact history
from one list to the next (numba)."""

from __future__ import annotations

import numba as nb
import numpy as np

from .laws.columns import HIST


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
