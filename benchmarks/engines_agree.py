"""Do the two engines agree? The same heaps (same fill from the same seed, same condition,
lift, stop criterion and angle measurement) on the built-in kernel and on LAMMPS, side by side.

Usage:  python benchmarks/engines_agree.py [--preset smoke] [--seeds 3] [--first-seed 1] [--points 0,1,2]
                                          [--spring] [--caps] [--csv FILE]
Prints, per parameter point, the mean and sd over seeds of each engine's angle, their
difference, and whether it lies within the run-to-run spread (2 standard errors). `--csv` appends
one row per heap (point, law, engine, seed, angle, wall time), so that seeds run in separate
processes (`--first-seed`) can be pooled afterwards.

LAMMPS's rolling law is a spring-dashpot-slider (`rolling sds`); the built-in kernel's default is
the constant directional torque of SPEC 5. `--spring` adds a row per point with the built-in
kernel on `rolling_spring = 1`, the same law with the same constants, beside the same LAMMPS heaps.
`--caps` adds one with `rolling_spring = 1` and `caps_pulloff = 1`: LAMMPS's jkr caps sliding and
rolling at |F_ne + 2 F_pulloff|, where SPEC 5 caps sliding on the repulsive part and rolling on |F_ne|
(identical without cohesion).
"""

from __future__ import annotations

import argparse
import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from calib_cli.dem.heap import get_preset, run_heap
from calib_cli.engines.lammps import run_heap_lammps

POINTS = [
    ("non-cohesive, mu_r 0.1", {"static_friction": 0.5, "rolling_friction": 0.1, "restitution": 0.3}),
    ("non-cohesive, mu_r 0.3", {"static_friction": 0.5, "rolling_friction": 0.3, "restitution": 0.3}),
    ("cohesive 0.5 J/m2", {"static_friction": 0.5, "rolling_friction": 0.2, "restitution": 0.3,
                           "surface_energy": 0.5}),
]


def _record(path, row):
    if not path:
        return
    import csv
    import os

    new = not os.path.exists(path)
    with open(path, "a", newline="") as f:
        w = csv.writer(f)
        if new:
            w.writerow(row)
        w.writerow(row.values())


def _table(name, A, B, ta, tb):
    """One line per built-in law: its mean and sd over seeds against LAMMPS's, and 2 SE of the difference."""
    B = np.array(B)
    for k, x in A.items():
        x = np.array(x)
        d = np.nanmean(x) - np.nanmean(B)
        se = 2 * np.sqrt(np.nanvar(x, ddof=1) / np.isfinite(x).sum() + np.nanvar(B, ddof=1) / np.isfinite(B).sum())
        print(f"{name + k:<42}{np.nanmean(x):>8.2f} +-{np.nanstd(x, ddof=1):4.1f}{np.nanmean(B):>8.2f} +-"
              f"{np.nanstd(B, ddof=1):4.1f}{d:>8.2f}{se:>7.2f}  {'yes' if abs(d) <= se else 'NO '}    "
              f"{ta[k]:.1f} / {tb:.1f}   ({len(x)} / {len(B)} heaps)", flush=True)


HEADER = f"{'point':<42}{'calib':>14}{'LAMMPS':>14}{'diff':>8}{'2 SE':>7}  agree   wall calib/LAMMPS [s]"


def pool(path):
    """The table from heaps recorded with --csv (several processes, several seed ranges)."""
    import pandas as pd

    df = pd.read_csv(path).drop_duplicates(["preset", "point", "law", "engine", "seed"], keep="last")
    for preset, d in df.groupby("preset", sort=False):
        seeds = sorted(int(s) for s in d["seed"].unique())
        print(f"preset {preset}: seeds {seeds}, pooled from {path}; angle from coordinates (deg)")
        print(HEADER)
        for name, e in d.groupby("point", sort=False):
            lam = e[e["engine"] == "lammps"]
            cal = e[e["engine"] == "calib"]
            A = {k: list(g["angle"]) for k, g in cal.groupby("law", sort=False)}
            ta = {k: g["wall_s"].sum() for k, g in cal.groupby("law", sort=False)}
            _table(name + ", ", A, list(lam["angle"]), ta, lam["wall_s"].sum())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="smoke")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=1, help="seeds first-seed .. first-seed + seeds - 1")
    ap.add_argument("--csv", help="append one row per heap to this CSV file")
    ap.add_argument("--pool", metavar="CSV", help="print the table from the heaps in this CSV file, run nothing")
    ap.add_argument("--points", default=",".join(str(i) for i in range(len(POINTS))),
                    help="which points, by index (0-based, comma separated): larger presets take minutes per heap")
    ap.add_argument("--spring", action="store_true",
                    help="also run the built-in kernel with rolling_spring = 1 (LAMMPS's rolling law)")
    ap.add_argument("--caps", action="store_true",
                    help="also run the built-in kernel with rolling_spring = 1 and caps_pulloff = 1 (LAMMPS's caps)")
    a = ap.parse_args()
    if a.pool:
        return pool(a.pool)
    pre = get_preset(a.preset)
    laws = {"": {}, **({", spring": {"rolling_spring": 1.0}} if a.spring else {}),
            **({", spring, pull-off caps": {"rolling_spring": 1.0, "caps_pulloff": 1.0}} if a.caps else {})}
    print(f"preset {a.preset}: {pre.note}; {a.seeds} seeds per point from seed {a.first_seed}; angle from "
          "coordinates (deg)")
    print(HEADER)
    for name, p in [POINTS[int(i)] for i in a.points.split(",")]:
        A, B, ta, tb = {k: [] for k in laws}, [], dict.fromkeys(laws, 0.0), 0.0
        for s in range(a.first_seed, a.first_seed + a.seeds):
            for k, law in laws.items():
                t = time.perf_counter()
                r = run_heap({**p, **law}, pre.condition, pre.numerics, seed=s)
                ta[k] += time.perf_counter() - t
                A[k].append(r.angle.angle if r.status == "ok" else np.nan)
                _record(a.csv, {"preset": a.preset, "point": name, "law": k.lstrip(", ") or "constant torque",
                                "engine": "calib", "seed": s, "angle": A[k][-1],
                                "wall_s": round(time.perf_counter() - t, 1)})
            t = time.perf_counter()
            q = run_heap_lammps(p, pre.condition, pre.numerics, seed=s)
            tb += time.perf_counter() - t
            B.append(q.angle.angle if q.status == "ok" else np.nan)
            _record(a.csv, {"preset": a.preset, "point": name, "law": "", "engine": "lammps", "seed": s,
                            "angle": B[-1], "wall_s": round(time.perf_counter() - t, 1)})
        _table(name, A, B, ta, tb)


if __name__ == "__main__":
    main()
