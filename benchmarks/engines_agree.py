"""Do the two engines agree? The same heaps (same fill from the same seed, same condition,
lift, stop criterion and angle measurement) on the built-in kernel and on LAMMPS, side by side.

Usage:  python benchmarks/engines_agree.py [--preset smoke] [--seeds 3] [--points 0,1,2] [--spring] [--caps]
Prints, per parameter point, the mean and sd over seeds of each engine's angle, their
difference, and whether it lies within the run-to-run spread (2 standard errors).

LAMMPS's rolling law is a spring-dashpot-slider (`rolling sds`); the built-in kernel's default is
the constant directional torque of SPEC 5. `--spring` adds a row per point with the built-in
kernel on `rolling_spring = 1`, the same law with the same constants, beside the same LAMMPS heaps.
`--caps` adds one with `rolling_spring = 1` and `caps_pulloff = 1`: LAMMPS's jkr caps sliding and
rolling at |F_ne + 2 F_pulloff|, where SPEC 5 caps sliding on the repulsive part and rolling on |F_ne|
(identical without cohesion).
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
    ap.add_argument("--spring", action="store_true",
                    help="also run the built-in kernel with rolling_spring = 1 (LAMMPS's rolling law)")
    ap.add_argument("--caps", action="store_true",
                    help="also run the built-in kernel with rolling_spring = 1 and caps_pulloff = 1 (LAMMPS's caps)")
    a = ap.parse_args()
    pre = get_preset(a.preset)
    laws = {"": {}, **({", spring": {"rolling_spring": 1.0}} if a.spring else {}),
            **({", spring, pull-off caps": {"rolling_spring": 1.0, "caps_pulloff": 1.0}} if a.caps else {})}
    print(f"preset {a.preset}: {pre.note}; {a.seeds} seeds per point; angle from coordinates (deg)")
    print(f"{'point':<42}{'calib':>14}{'LAMMPS':>14}{'diff':>8}{'2 SE':>7}  agree   wall calib/LAMMPS [s]")
    for name, p in [POINTS[int(i)] for i in a.points.split(",")]:
        A, B, ta, tb = {k: [] for k in laws}, [], dict.fromkeys(laws, 0.0), 0.0
        for s in range(1, a.seeds + 1):
            for k, law in laws.items():
                t = time.perf_counter()
                r = run_heap({**p, **law}, pre.condition, pre.numerics, seed=s)
                ta[k] += time.perf_counter() - t
                A[k].append(r.angle.angle if r.status == "ok" else np.nan)
            t = time.perf_counter()
            q = run_heap_lammps(p, pre.condition, pre.numerics, seed=s)
            tb += time.perf_counter() - t
            B.append(q.angle.angle if q.status == "ok" else np.nan)
        B = np.array(B)
        for k in laws:
            x = np.array(A[k])
            d = np.nanmean(x) - np.nanmean(B)
            se = 2 * np.sqrt(np.nanvar(x, ddof=1) / np.isfinite(x).sum() + np.nanvar(B, ddof=1) / np.isfinite(B).sum())
            print(f"{name + k:<42}{np.nanmean(x):>8.2f} +-{np.nanstd(x, ddof=1):4.1f}{np.nanmean(B):>8.2f} +-"
                  f"{np.nanstd(B, ddof=1):4.1f}{d:>8.2f}{se:>7.2f}  {'yes' if abs(d) <= se else 'NO '}    "
                  f"{ta[k]:.1f} / {tb:.1f}", flush=True)


if __name__ == "__main__":
    main()
