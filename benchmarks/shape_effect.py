"""Is particle shape what makes the paper's heaps respond to rolling friction first?

The built-in kernel has spheres only, and its heaps respond to static friction (and cohesion)
far more than to rolling friction, where the paper's EDEM heaps of multi-sphere grains
(section 2.2.2: flattened, conical, block-like, spherical) respond to rolling friction most
(docs/physics.md, "Particle shape"). This runs the same two-level factorial in static and
rolling friction at the ends of the paper's BBD ranges (Table 6), on LAMMPS, once with spheres
and once with the paper's four shapes (calib_cli/engines/clumps.py) replacing the same fill,
and prints each factor's main effect per shape with its standard error.

Usage:  python benchmarks/shape_effect.py [--seeds 3] [--workers 2] [--surface-energy 0]
        [--rig calibration|smoke|default]
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import time
from concurrent.futures import ProcessPoolExecutor

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from calib_cli.dem.heap import HeapCondition, get_preset
from calib_cli.engines.clumps import PAPER_MIX
from factorial import effects

RIGS = {  # the photographed sample rig (sample_data/calibration) and two presets
    "calibration": HeapCondition(4.0, 5.0, 40.0, 75.0, 50.0),
    "smoke": get_preset("smoke").condition,
    "default": get_preset("default").condition,
}
LEVELS = {"static_friction": (0.112, 0.438), "rolling_friction": (0.122, 0.308)}  # Table 6, coded -1 / +1
SHAPES = {"spheres": ("sphere",), "paper mix": PAPER_MIX}


def _one(job):
    from calib_cli.engines.lammps import run_heap_lammps

    shape, point, seed, rig = job
    t = time.perf_counter()
    r = run_heap_lammps({**dict(point), "restitution": 0.2}, RIGS[rig], get_preset("default").numerics, seed=seed,
                        shapes=SHAPES[shape])
    a = r.angle.angle if r.status == "ok" else np.nan
    return job, a, r.status, r.system.n, time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--surface-energy", default="0.3,0.7",
                    help="J/m2: one value (held fixed) or low,high (a third factor)")
    ap.add_argument("--rig", choices=list(RIGS), default="calibration")
    a = ap.parse_args()
    levels = dict(LEVELS)
    g = [float(v) for v in a.surface_energy.split(",")]
    if len(g) == 2:
        levels["surface_energy"] = tuple(g)
    names = list(levels)
    print(f"rig {a.rig}: {RIGS[a.rig]}; " + ", ".join(f"{k} {v[0]:g} / {v[1]:g}" for k, v in levels.items())
          + (f", surface_energy {g[0]:g}" if len(g) == 1 else "") + f", restitution 0.2; {a.seeds} seeds a point; "
          f"LAMMPS, one rank per heap, {a.workers} at once; angle from coordinates (deg)")
    cells = list(itertools.product((-1, 1), repeat=len(names)))

    def point(c):
        p = {k: levels[k][(x + 1) // 2] for k, x in zip(names, c)}
        return tuple(sorted(({"surface_energy": g[0]} if len(g) == 1 else {}).items() | p.items()))

    jobs = [(s, point(c), seed, a.rig) for s in SHAPES for c in cells for seed in range(1, a.seeds + 1)]
    res = {}
    with ProcessPoolExecutor(a.workers) as ex:
        for job, ang, status, n, wall in ex.map(_one, jobs):
            res[job] = ang
            print(f"  {job[0]:<10} " + " ".join(f"{k} {v:g}" for k, v in job[1]) + f" seed {job[2]}: {ang:6.2f} "
                  f"({status}, {n} spheres, {wall:.0f} s)", flush=True)
    # coefficients per coded unit, as the paper's Eq. 7 (half the change from low to high)
    print("\ncoefficients per coded unit (+- 1 SE from the seed-to-seed scatter); the paper's Eq. 7: "
          "X1 1.90, X2 5.99, X3 1.12")
    head = [f"X{i + 1} {k}" for i, k in enumerate(names)]
    print(f"{'shape':<10}{'mean':>7}" + "".join(f"{h:>24}" for h in head) + f"{'seed sd':>9}")
    for s in SHAPES:
        y = np.array([[res[(s, point(c), k, a.rig)] for k in range(1, a.seeds + 1)] for c in cells])
        m, b, sd, se = effects(cells, y)
        print(f"{s:<10}{np.nanmean(m):7.2f}" + "".join(f"{v:17.2f} +-{se:4.2f}" for v in b) + f"{sd:9.2f}")
        print(f"{'':<10}{'':>7}  cell means: " + ", ".join(f"{v:.1f}" for v in m))


if __name__ == "__main__":
    main()
