"""Repose angle from particle coordinates (SPEC section 5).

Azimuthal sectors around the heap axis; in each, radial bins of one mean diameter;
the top surface of a bin is the highest particle top (z + R); the flank is fitted
between the toe and the apex with :func:`calib_cli.profile.fit_flank`. The angle is
the mean over sectors, with their sd.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..profile import DEFAULT_BAND, fit_flank


@dataclass(frozen=True)
class CoordAngle:
    angle: float  # mean over valid sectors, deg
    sd: float
    n_sectors: int  # valid sectors
    height: float  # apex height, m
    base_radius: float  # radius where the profile reaches the floor layer, m
    sector_angles: np.ndarray
    profile_r: np.ndarray  # mean profile over sectors (bin centres), m
    profile_h: np.ndarray


def no_angle() -> CoordAngle:
    """The angle of a run that has none (it blew up): every value NaN, no profile."""
    empty = np.zeros(0)
    return CoordAngle(np.nan, np.nan, 0, np.nan, np.nan, empty, empty, empty)


@nb.njit(cache=True)
def azimuthal_sector(x, y, sectors):
    """Sector index floor((atan2(y, x) + pi) / 2pi * sectors) mod sectors, with libm's atan2:
    numpy's np.arctan2 runs SVML code on AVX-512 CPUs, which differs from other CPUs' in the
    last place, and a grain on a sector boundary would change sector with the machine."""
    out = np.empty(x.shape[0], np.int64)
    for i in range(x.shape[0]):
        out[i] = int((math.atan2(y[i], x[i]) + math.pi) / (2.0 * math.pi) * sectors) % sectors
    return out


def top_profile(pos, rad, center=(0.0, 0.0), sectors: int = 8, bin_width: float | None = None,
                r_max: float | None = None):
    """Surface points per azimuthal sector and radial bin: the highest particle top (z + R)
    and that particle's own radius r (not the bin centre, which biases a steep flank of few
    grains low). Returns (r[sector, bin], h[sector, bin]), NaN where a bin is empty."""
    x = pos[:, 0] - center[0]
    y = pos[:, 1] - center[1]
    r = np.hypot(x, y)
    top = pos[:, 2] + rad
    bw = bin_width or 2.0 * float(np.mean(rad))
    rm = r_max or float(r.max()) + bw
    nb = max(int(np.ceil(rm / bw)), 1)
    sec = azimuthal_sector(x, y, sectors)
    b = np.minimum((r / bw).astype(int), nb - 1)
    order = np.lexsort((top, b, sec))
    cell = sec[order] * nb + b[order]
    last = np.flatnonzero(np.r_[cell[1:] != cell[:-1], True])  # the highest particle of each cell
    rr = np.full((sectors, nb), np.nan)
    hh = np.full((sectors, nb), np.nan)
    idx = order[last]
    rr[sec[idx], b[idx]] = r[idx]
    hh[sec[idx], b[idx]] = top[idx]
    return rr, hh


def repose_angle_coords(pos, rad, center=(0.0, 0.0), sectors: int = 8, band=DEFAULT_BAND) -> CoordAngle:
    r_pts, h = top_profile(pos, rad, center, sectors)
    bw = 2.0 * float(np.mean(rad))
    r_c = (np.arange(h.shape[1]) + 0.5) * bw
    floor_layer = 2.0 * float(np.max(rad))
    angles = []
    for s in range(h.shape[0]):
        hs = h[s]
        ok = np.isfinite(hs)
        if ok.sum() < 4:
            continue
        height = float(np.nanmax(hs))
        apex = int(np.nanargmax(hs))
        # outward from the apex only: the flank is the descending part
        rr, hh = r_pts[s, apex:], hs[apex:]
        fit = fit_flank(rr, hh, height, band)
        if fit.ok and fit.slope < 0:
            angles.append(fit.angle)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # empty bins far from the heap
        prof = np.nanmean(h, axis=0)
    height = float(np.nanmax(h)) if np.isfinite(h).any() else 0.0
    above = np.flatnonzero(np.nan_to_num(prof, nan=0.0) > floor_layer)
    base_r = float(r_c[above[-1]]) if above.size else 0.0
    a = np.asarray(angles)
    return CoordAngle(float(a.mean()) if a.size else float("nan"), float(a.std(ddof=1)) if a.size > 1 else float("nan"),
                      int(a.size), height, base_r, a, r_c, prof)
