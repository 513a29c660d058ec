"""Does a heap's angle depend on cohesion only through surface energy / heap size?

docs/physics.md ("Validity") argues that a small heap is more cohesive, relative to its weight,
than a large one of the same grains: the cohesive stress scales as g / d (pull-off force
3 pi g R* over a grain's cross-section) and the gravitational stress as rho g H, so two heaps
of the same grains should have the same shape when g / H is the same. (This is the slope
stability number c / (gamma H) of a cohesive Mohr-Coulomb slope.) If it holds, a user can
emulate a large physical rig on a smaller model rig by scaling the surface energy down with
the heap size, g_model = g_rig x H_model / H_rig, and the `default` preset's BBD at half the
surface energy (`make default-bbd-half-g`) stands for a heap about twice as tall.

This tests the rule with the built-in kernel: rig A (40 mm cylinder filled 50 mm) and rig B,
twice its size in every length (80 mm filled 100 mm), the same 4-5 mm grains, lift speed and
`default` numerics, at the BBD centre's friction (mu_s 0.275, mu_r 0.215, e 0.3):

- A at g and B at 2g (same g / H): the rule predicts the same angle;
- A at g and B at g (B relatively half as cohesive): the contrast, B flatter;
- A and B at g = 0: what size does without cohesion (grains relative to the rig).

Every heap is a cached `simulate-heap` run in --run (rerunning skips finished heaps; Ctrl-C
loses none); the angle is the primary one (rendered side view, measured by the photograph code).

Usage:  python benchmarks/cohesion_scaling.py [--seeds 5] [--seeds-a 10] [--workers 2] [--g 0.25,0.5]
        [--run /tmp/calib-cohesion-scaling]
"""

from __future__ import annotations

import argparse
import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
from scipy import stats

from calib_cli.dem.heap import HeapCondition, get_preset
from calib_cli.heaps.keys import Request, derive_seed
from calib_cli.heaps.runner import run_campaign

FRICTION = {"static_friction": 0.275, "rolling_friction": 0.215, "restitution": 0.3}
RIGS = {"A": HeapCondition(4.0, 5.0, 40.0, 50.0, 50.0), "B": HeapCondition(4.0, 5.0, 80.0, 100.0, 50.0)}
SCALE = {"A": 1.0, "B": 2.0}  # every length of the rig, relative to A


def jobs(gs: list[float], seeds: dict[str, int]) -> list[tuple[str, float, int]]:
    """(rig, surface energy, repeat) at g = 0, gs and 2 gs on both rigs; B's heaps first (~12x longer)."""
    levels = sorted({0.0, *gs, *(2 * g for g in gs)})
    return [(rig, g, s) for rig in ("B", "A") for g in levels for s in range(seeds[rig])]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5, help="heaps a point on rig B")
    ap.add_argument("--seeds-a", type=int, default=10,
                    help="heaps a point on rig A (cheap, and 8x fewer grains scatter more)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--g", default="0.25,0.5", help="surface energies of rig A [J/m2]")
    ap.add_argument("--run", default="/tmp/calib-cohesion-scaling", help="run directory (the heaps' cache)")
    a = ap.parse_args()
    gs = [float(v) for v in a.g.split(",")]
    num = get_preset("default").numerics
    todo = jobs(gs, {"A": a.seeds_a, "B": a.seeds})
    # the same seeds (fills) in every cell of a rig: common random numbers sharpen the differences
    reqs = [Request(params={**FRICTION, "surface_energy": g}, condition=RIGS[rig], numerics=num,
                    seed=derive_seed(7, 0, s), preset="default", design=f"scaling-{rig}", run_id=i, repeat=s)
            for i, (rig, g, s) in enumerate(todo)]
    print(f"rigs: {RIGS}; " + ", ".join(f"{k} {v:g}" for k, v in FRICTION.items())
          + f"; {a.seeds} (B) and {a.seeds_a} (A) seeds a point; `default` numerics, {a.workers} heaps at once, one thread each")
    t0 = time.perf_counter()

    def done(req, row):
        print(f"  rig {todo[req.run_id][0]} g {req.params['surface_energy']:.3g} seed {req.repeat}: "
              f"{row['repose_angle']:6.2f} deg ({row['status']}, {row['n_particles']} grains, "
              f"heap {row['heap_height_mm']:.0f} mm, {row['wall_s']:.0f} s)", flush=True)

    df = run_campaign(reqs, a.run, workers=a.workers, on_done=done)
    print(f"\n{len(df)} heaps in {time.perf_counter() - t0:.0f} s (cached ones count 0)")
    df["rig"] = [rig for rig, _, _ in todo]  # run_campaign returns the rows in request order
    df["g"] = [g for _, g, _ in todo]

    def cell(rig, g):
        v = df[(df.rig == rig) & np.isclose(df.g, g) & (df.status == "ok")]
        return v.repose_angle.to_numpy(), v.heap_height_mm.to_numpy()

    print(f"\n{'rig':<4}{'g [J/m2]':>9}{'g / H (rel. A)':>16}{'angle [deg]':>20}{'heap [mm]':>11}  seeds")
    for rig, g in sorted({(r, g) for r, g, _ in todo}):
        y, h = cell(rig, g)
        print(f"{rig:<4}{g:9.3g}{g / SCALE[rig]:16.3g}{y.mean():12.2f} +- {y.std(ddof=1) / np.sqrt(len(y)):4.2f}"
              f"{h.mean():11.0f}  " + ", ".join(f"{v:.1f}" for v in y))

    def diff(p, q):
        (y1, _), (y2, _) = cell(*p), cell(*q)
        return y2.mean() - y1.mean(), float(np.sqrt(y1.var(ddof=1) / len(y1) + y2.var(ddof=1) / len(y2)))

    d0, se0 = diff(("A", 0.0), ("B", 0.0))
    print("\nangle differences B - A (+- 1 SE from the seed scatter); 'less size' subtracts the"
          " difference without cohesion, which comes from the grains' size relative to the rig:")
    print(f"  no cohesion  A g 0    -> B g 0    : {d0:+6.2f} +- {se0:4.2f} deg  (size alone)")
    for g in gs:
        d, se = diff(("A", g), ("B", 2 * g))
        print(f"  same g / H   A g {g:<5g}-> B g {2 * g:<5g}: {d:+6.2f} +- {se:4.2f} deg, less size "
              f"{d - d0:+6.2f} +- {np.hypot(se, se0):4.2f}  (rule: 0)")
    for g in sorted({*gs, *(2 * g for g in gs)}):
        d, se = diff(("A", g), ("B", g))
        print(f"  same g       A g {g:<5g}-> B g {g:<5g}: {d:+6.2f} +- {se:4.2f} deg, less size "
              f"{d - d0:+6.2f} +- {np.hypot(se, se0):4.2f}  (rule: B flatter)")

    # Two readings, each with one constant offset of B over A (the grains' size relative to the
    # rig): the angle is a function of g / H (the rule), or of g alone (cohesion acts at the grain
    # scale). Each predicts equal offsets wherever both rigs have a cell at the same argument.
    print("\nwhich argument makes B - A one constant offset? (weighted mean offset, chi2 of the cells about it)")
    for name, arg in (("g / H (the rule)", lambda rig, g: g / SCALE[rig]), ("g alone", lambda rig, g: g)):
        cells = {rig: {arg(rig, g): g for r, g, _ in todo if r == rig} for rig in ("A", "B")}
        d = [diff(("A", cells["A"][x]), ("B", cells["B"][x])) for x in sorted(set(cells["A"]) & set(cells["B"]))]
        v, w = np.array([x for x, _ in d]), 1 / np.array([e for _, e in d]) ** 2
        c = float((w * v).sum() / w.sum())
        chi2 = float((w * (v - c) ** 2).sum())
        print(f"  {name:<17} offsets " + ", ".join(f"{x:+.2f}" for x in v) + f": {c:+.2f} +- {w.sum() ** -0.5:.2f} deg, "
              f"chi2 {chi2:.2f} on {len(v) - 1} dof, p = {stats.chi2.sf(chi2, len(v) - 1):.3f}")


if __name__ == "__main__":
    main()
