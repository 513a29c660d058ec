"""Can heaps under the hidden-effect lab's conditions tell a capillary bridge from JKR cohesion?

The discrepancy loop (`calib diagnose`) tells two candidate effects apart only where their
signatures differ: where the angle change each causes varies differently across the measured
conditions. Both are cohesive stresses that scale as (strength / grain size) against the weight's
rho g H, so on conditions that vary only grain size and heap size both may leave the same pattern.
This measures it directly: at the hidden-effect lab's truth (mu_s 0.45, mu_r 0.15, e 0.3) on its
rig (40 mm cylinder, `default` numerics), heaps dry, with capillary bridges (water: 0.072 N/m, a
bridge of 1 % of a grain's volume) and with JKR cohesion (the lab's 0.6 J/m2), on grain size x
fill height conditions. Per condition it prints each effect's angle change (+- 1 SE from the seed
scatter, the same seeds in every cell), and then whether the ratio of the two changes is one
constant across the conditions (chi2 about the weighted mean ratio): a constant ratio means one
signature up to scale, which no ranking on these conditions can split.

Every heap is a cached `simulate-heap` run in --run (rerunning skips finished heaps; Ctrl-C loses
none); the angle is the primary one (rendered side view, measured by the photograph code).

Usage:  python benchmarks/capillary_vs_jkr.py [--seeds 3] [--workers 2] [--sizes 4-5,5-6] [--fills 50,100]
        [--lift-speeds 50] [--run /tmp/calib-capillary-vs-jkr]
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
from scipy import stats

from calib_cli.dem.heap import HeapCondition, get_preset
from calib_cli.heaps.keys import Request, derive_seed
from calib_cli.heaps.runner import run_campaign

TRUTH = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3}
EFFECTS = {"dry": {}, "capillary": {"surface_tension": 0.072}, "jkr": {"surface_energy": 0.6}}


def conditions(sizes: str, fills: str, speeds: str) -> dict[str, HeapCondition]:
    out = {}
    for s, h, v in itertools.product(sizes.split(","), fills.split(","), speeds.split(",")):
        lo, hi = (float(x) for x in s.split("-"))
        out[f"d{s}_H{h}_v{v}"] = HeapCondition(lo, hi, 40.0, float(h), float(v))
    return out


def table(df, conds, effects):
    """{(condition, effect): (mean, se, n)} of the formed heaps."""
    out = {}
    for c, e in itertools.product(conds, effects):
        y = df[(df.cond == c) & (df.effect == e) & (df.status == "ok")].repose_angle.to_numpy()
        out[c, e] = (y.mean(), y.std(ddof=1) / np.sqrt(len(y)) if len(y) > 1 else np.nan, len(y))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sizes", default="4-5,5-6")
    ap.add_argument("--fills", default="50,100")
    ap.add_argument("--lift-speeds", default="50")
    ap.add_argument("--run", default="/tmp/calib-capillary-vs-jkr")
    a = ap.parse_args()
    conds = conditions(a.sizes, a.fills, a.lift_speeds)
    num = get_preset("default").numerics
    todo = [(c, e, s) for c in conds for e in EFFECTS for s in range(a.seeds)]
    reqs = [Request(params={**TRUTH, **EFFECTS[e]}, condition=conds[c], numerics=num, seed=derive_seed(13, 0, s),
                    preset="default", design=f"capjkr-{e}", run_id=i, repeat=s) for i, (c, e, s) in enumerate(todo)]
    print(f"truth {TRUTH}; effects {EFFECTS}; {len(conds)} conditions x {a.seeds} seeds; `default` numerics, "
          f"{a.workers} heaps at once, one thread each", flush=True)
    t0 = time.perf_counter()

    def done(req, row):
        c, e, s = todo[req.run_id]
        print(f"  {c} {e:<9} seed {s}: {row['repose_angle']:6.2f} deg ({row['status']}, {row['n_particles']} grains, "
              f"{row['wall_s']:.0f} s)", flush=True)

    df = run_campaign(reqs, a.run, workers=a.workers, on_done=done)
    print(f"\n{len(df)} heaps in {time.perf_counter() - t0:.0f} s (cached ones count 0)")
    df["cond"], df["effect"] = [c for c, _, _ in todo], [e for _, e, _ in todo]
    t = table(df, conds, EFFECTS)
    print(f"\n{'condition':<18}" + "".join(f"{e:>18}" for e in EFFECTS) + f"{'d capillary':>16}{'d jkr':>16}")
    ratios = []
    for c in conds:
        d = {e: (t[c, e][0] - t[c, "dry"][0], float(np.hypot(t[c, e][1], t[c, "dry"][1]))) for e in ("capillary", "jkr")}
        print(f"{c:<18}" + "".join(f"{t[c, e][0]:11.2f} +- {t[c, e][1]:4.2f}" for e in EFFECTS)
              + "".join(f"{d[e][0]:+9.2f} +- {d[e][1]:4.2f}" for e in ("capillary", "jkr")))
        (dc, sc), (dj, sj) = d["capillary"], d["jkr"]
        r = dc / dj
        ratios.append((r, abs(r) * np.hypot(sc / dc, sj / dj)))
    r, se = np.array(ratios).T
    w = 1 / se**2
    m = float((w * r).sum() / w.sum())
    chi2 = float((w * (r - m) ** 2).sum())
    print("\nratio d capillary / d jkr per condition: " + ", ".join(f"{x:.2f} +- {e:.2f}" for x, e in zip(r, se))
          + f"\none constant ratio {m:.2f} +- {w.sum() ** -0.5:.2f}: chi2 {chi2:.2f} on {len(r) - 1} dof, "
          f"p = {stats.chi2.sf(chi2, len(r) - 1):.3f} (small p: the signatures differ across these conditions)")


if __name__ == "__main__":
    main()
