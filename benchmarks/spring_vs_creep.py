"""Is the rolling spring's change to a heap the creep it removes?

The constant torque (SPEC 5) cannot hold a static torque, so its heaps creep after the lift; the
spring-dashpot-slider (`rolling_spring = 1`) holds them (docs/physics.md, "Rolling spring"). If
the difference between the two laws' angles were that creep, a heap's difference (spring minus
constant torque, same point and seed) would follow how far the constant-torque heap crept between
the end of the lift and the measurement, estimated as its drift at measurement times that time.

Reads the heaps a `benchmarks/rolling_law.py --compare spring --design bbd [--modulus 5e8]` run
left in RUN (its results index) and prints, per shear modulus, the pairs found, the mean
difference, the median creep estimate and their correlation over the heaps, then per design point.
Runs nothing.

Usage:  python benchmarks/spring_vs_creep.py /tmp/calib-pb
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from rolling_law import design

FACTORS = ["static_friction", "rolling_friction", "surface_energy"]


def bbd_points() -> list[dict[str, float]]:
    """The 13 distinct points of the paper's Table 7 as `rolling_law.py --design bbd` simulates
    them (surface energy x 0.4 on the 40 mm rig)."""
    return design(argparse.Namespace(design="bbd", g=None, g_factor=0.4))[1]


def pairs(results: pd.DataFrame) -> pd.DataFrame:
    """One row per (shear modulus, point, seed) simulated with both laws: pull-off caps off, the
    floor following the grains (the designs' default)."""
    r = results[(results["status"] == "ok")].copy()
    for c in ("caps_pulloff", "rolling_own_spin"):
        if c in r:
            r = r[r[c].fillna(0) == 0]
    for c in ("floor_static_friction", "floor_rolling_friction", "wall_static_friction", "wall_rolling_friction"):
        if c in r:
            r = r[r[c].isna()]
    points = {tuple(round(p[c], 3) for c in FACTORS) for p in bbd_points()}
    r = r[[tuple(x) in points for x in r[FACTORS].round(3).itertuples(index=False)]]
    r["G"] = r["shear_modulus"].fillna(5e6) if "shear_modulus" in r else 5e6
    r["law"] = np.where(r["rolling_spring"].fillna(0) == 1, "spring", "torque") if "rolling_spring" in r else "torque"
    r["creep"] = r["angle_drift_deg_s"] * (r["t_end"] - r["t_lift_end"])
    key = ["G", *FACTORS, "seed"]
    r = r.drop_duplicates([*key, "law"])  # the BBD's five centre runs are one heap per seed
    p = r.pivot(index=key, columns="law", values=["repose_angle", "creep"]).dropna()
    p.columns = [f"{a}_{b}" for a, b in p.columns]
    p["difference"] = p["repose_angle_spring"] - p["repose_angle_torque"]
    return p


def main():
    run = Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/calib-pb")
    p = pairs(pd.read_parquet(run / "simulate" / "results.parquet"))
    for G, g in p.groupby(level="G"):
        r = np.corrcoef(g["difference"], g["creep_torque"])[0, 1]
        print(f"shear modulus {G:.0e} Pa: {len(g)} heap pairs; spring - torque {g['difference'].mean():+.2f} deg "
              f"(sd {g['difference'].std():.2f}); the torque heap's creep after the lift, median "
              f"{g['creep_torque'].median():+.2f} deg; correlation {r:+.2f}")
        means = g.groupby(level=FACTORS).mean()
        print(means[["repose_angle_torque", "repose_angle_spring", "difference", "creep_torque"]].round(2)
              .to_string(), "\n")


if __name__ == "__main__":
    main()
