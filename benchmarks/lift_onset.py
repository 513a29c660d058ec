"""When does the fill start to flow during the lift, with each rolling law?

Followed on four heaps (`heap_creep.py --during`), the rolling spring's cohesive fill stood as a
column through more of the lift at 5 MPa and then collapsed faster, leaving a lower heap, and at
500 MPa did the opposite (docs/physics.md, "Rolling spring"). This measures it over the paper's
Box-Behnken design (Table 7's 13 distinct points, surface energy x 0.4, restitution 0.2) on the
40 mm rig of `rolling_law.py`, with its seeds (derive_seed(11, 0, repeat)), so each heap is the one
`rolling_law.py --compare spring --design bbd` simulated: per heap, the rim height at which the
median grain speed first exceeds 20 mm/s, the peak median speed, the coordinate angle 0.1 s after
the cylinder has gone and the measured angle; then, over the pairs (same point and seed), how the
spring-minus-torque difference in the measured angle follows the difference in onset and in the
angle at the lift's end.

Usage:  python benchmarks/lift_onset.py [--seeds 3] [--modulus 5e6] [--workers 2] [--csv FILE]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
import importlib

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

from calib_cli.heaps.inputs import heap_preset
from calib_cli.heaps.keys import derive_seed
from spring_vs_creep import FACTORS, bbd_points

ONSET = 0.02  # m/s: the median grain speed at which the fill counts as flowing


def follow(job):
    """One heap, sampled at every chunk from the start of the lift."""
    import calib_cli.dem.heap as heap
    from rolling_law import RIGS

    params, law, repeat, modulus = job
    num = heap_preset("default", modulus).numerics
    rec = {"onset_rim_mm": np.nan, "peak_median_mm_s": 0.0, "angle_after_lift": np.nan}
    gone = []
    orig = heap.System.advance

    def advance(self, n):
        orig(self, n)
        if self.walls.lift_start > self.t:
            return
        med = float(np.median(np.linalg.norm(self.particles.vel, axis=1)))
        rec["peak_median_mm_s"] = max(rec["peak_median_mm_s"], med * 1e3)
        if np.isnan(rec["onset_rim_mm"]) and med > ONSET:
            rec["onset_rim_mm"] = self.geo[1] * 1e3
        if self.geo[2] == 0.0:  # the cylinder has gone
            gone.append(self.t)
            if np.isnan(rec["angle_after_lift"]) and self.t >= gone[0] + 0.1:
                rec["angle_after_lift"] = heap.repose_angle_coords(self.particles.pos, self.particles.rad).angle

    heap.System.advance = advance
    try:
        r = heap.run_heap({**params, "rolling_spring": float(law == "spring")},
                          RIGS["calibration"], num, seed=derive_seed(11, 0, repeat))
    finally:
        heap.System.advance = orig
    return {**params, "law": law, "repeat": repeat, "shear_modulus": modulus, "status": r.status,
            "angle_coords": r.angle.angle if r.status == "ok" else np.nan, **rec}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--modulus", type=float, default=5e6)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--csv", help="write one row per heap to this CSV file")
    a = ap.parse_args()
    jobs = [(p, law, s, a.modulus) for p in bbd_points() for s in range(a.seeds) for law in ("torque", "spring")]
    with ProcessPoolExecutor(a.workers) as ex:
        df = pd.DataFrame(list(ex.map(follow, jobs)))
    if a.csv:
        df.to_csv(a.csv, index=False)
    cols = ["onset_rim_mm", "peak_median_mm_s", "angle_after_lift", "angle_coords"]
    print(f"shear modulus {a.modulus:.0e} Pa, {len(df)} heaps ({a.seeds} seeds x 13 points x 2 laws); "
          f"onset: median grain speed > {ONSET * 1e3:g} mm/s")
    print(df.groupby("law")[cols].mean().round(2).to_string())
    key = [*FACTORS, "repeat"]
    w = df.pivot(index=key, columns="law", values=cols).dropna()
    d = pd.DataFrame({c: w[(c, "spring")] - w[(c, "torque")] for c in cols})
    print(f"\nspring - torque over {len(d)} pairs (mean, sd):")
    print(d.agg(["mean", "std"]).round(2).to_string())
    for c in ("onset_rim_mm", "angle_after_lift"):
        print(f"correlation of the measured-angle difference with the {c} difference: "
              f"{np.corrcoef(d[c], d['angle_coords'])[0, 1]:+.2f}")


if __name__ == "__main__":
    main()
