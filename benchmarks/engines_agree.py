"""Do the two engines agree? The same heaps (same fill from the same seed, same condition,
lift, stop criterion and angle measurement) on the built-in kernel and on LAMMPS, side by side.

Usage:  python benchmarks/engines_agree.py [--preset smoke] [--seeds 3] [--points 0,1,2]
Prints, per parameter point, the mean and sd over seeds of each engine's angle, their
difference, and whether it lies within the run-to-run spread (2 standard errors).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from calib_cli.dem.heap import get_preset, run_heap
from calib_cli.engines.lammps import run_heap_lammps

POINTS = [
    ("non-cohesive, mu_r 0.1", {"static_friction": 0.5, "rolling_friction": 0.1, "restitution": 0.3}),
    ("non-cohesive, mu_r 0.3", {"static_friction": 0.5, "rolling_friction": 0.3, "restitution": 0.3}),
    ("cohesive 0.5 J/m2", {"static_friction": 0.5, "rolling_friction": 0.2, "restitution": 0.3,
                           "surface_energy": 0.5}),
]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="smoke")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--points", default=",".join(str(i) for i in range(len(POINTS))),
                    help="which points, by index (0-based, comma separated): larger presets take minutes per heap")
    a = ap.parse_args()
    pre = get_preset(a.preset)
    print(f"preset {a.preset}: {pre.note}; {a.seeds} seeds per point; angle from coordinates (deg)")
    print(f"{'point':<24}{'calib':>14}{'LAMMPS':>14}{'diff':>8}{'2 SE':>7}  agree   wall calib/LAMMPS [s]")
    for name, p in [POINTS[int(i)] for i in a.points.split(",")]:
        A, B, ta, tb = [], [], 0.0, 0.0
        for s in range(1, a.seeds + 1):
            t = time.perf_counter()
            r = run_heap(p, pre.condition, pre.numerics, seed=s)
            ta += time.perf_counter() - t
            t = time.perf_counter()
            q = run_heap_lammps(p, pre.condition, pre.numerics, seed=s)
            tb += time.perf_counter() - t
            A.append(r.angle.angle if r.status == "ok" else np.nan)
            B.append(q.angle.angle if q.status == "ok" else np.nan)
        A, B = np.array(A), np.array(B)
        d = np.nanmean(A) - np.nanmean(B)
        se = 2 * np.sqrt(np.nanvar(A, ddof=1) / np.isfinite(A).sum() + np.nanvar(B, ddof=1) / np.isfinite(B).sum())
        print(f"{name:<24}{np.nanmean(A):>8.2f} +-{np.nanstd(A, ddof=1):4.1f}{np.nanmean(B):>8.2f} +-"
              f"{np.nanstd(B, ddof=1):4.1f}{d:>8.2f}{se:>7.2f}  {'yes' if abs(d) <= se else 'NO '}    "
              f"{ta:.1f} / {tb:.1f}", flush=True)


if __name__ == "__main__":
    main()
