"""What a stiffer modulus costs: one `default` heap at several shear moduli, one after another.

    python benchmarks/modulus_cost.py                       # 5 and 150 MPa, seed 0
    python benchmarks/modulus_cost.py --moduli 5e6 5e7 1.5e8 5e8 --seed 1

Each heap is the centre of the paper's Table 6 (mu_s 0.275, mu_r 0.215, g 1.25 J/m2; restitution
the kernel's default) on the `default` preset with the modulus replaced as `--shear-modulus` and
`[heap] shear_modulus` replace it (`cli.common.heap_preset`), on all of numba's threads, as one
`calib simulate-heap` runs it. A `smoke` heap first compiles the kernel, so no row pays for it.
The table gives the wall time and the steps of each heap and both as ratios to the first modulus
(the machines are noisy, so the ratios come from one invocation); docs/physics.md, "Which modulus".
"""

from __future__ import annotations

import argparse
import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numba

from calib_cli.dem import heap
from calib_cli.heaps.inputs import heap_preset

CENTRE = dict(static_friction=0.275, rolling_friction=0.215, surface_energy=1.25)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--moduli", type=float, nargs="+", default=[5e6, 1.5e8], help="shear moduli [Pa]")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    smoke = heap.get_preset("smoke")
    heap.run_heap({}, smoke.condition, smoke.numerics)
    rows = []
    for g in a.moduli:
        pre = heap_preset("default", g)
        t = time.perf_counter()
        r = heap.run_heap(CENTRE, pre.condition, pre.numerics, seed=a.seed)
        wall = time.perf_counter() - t
        rows.append((g, wall, r.n_steps, r.n_particles, r.status, r.angle.angle if r.status == "ok" else float("nan")))
        print(f"  {g / 1e6:g} MPa: {wall:.0f} s", flush=True)
    w0, s0 = rows[0][1], rows[0][2]
    print(f"\n`default` heap at the Table 6 centre, seed {a.seed}, {numba.get_num_threads()} numba thread(s)")
    print("| shear modulus | grains | steps | wall [s] | wall / first | steps / first | angle [deg] | status |")
    print("|---|---|---|---|---|---|---|---|")
    for g, wall, steps, n, status, angle in rows:
        print(f"| {g / 1e6:g} MPa | {n:,} | {steps:,} | {wall:.0f} | {wall / w0:.2f} | {steps / s0:.2f} | "
              f"{angle:.1f} | {status} |")


if __name__ == "__main__":
    main()
