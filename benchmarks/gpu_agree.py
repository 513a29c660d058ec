"""Do the GPU engine and the CPU kernel give the same heaps? The same requests (same fill from the same
seed, same condition, protocol and angle measurement) on both engines, side by side (issue: a GPU
engine that runs a whole design at once, item 5).

Three cases at a preset (`default` unless told): non-cohesive; cohesive (JKR, 0.5 J/m2); the rolling
spring (`rolling_spring = 1`). Each engine's heaps are appended to one CSV (case, engine, seed, angle,
status, steps, wall time), so that the two engines can run on different machines and be pooled:

    python benchmarks/gpu_agree.py --engine gpu --csv agree.csv        # every case's heaps in its own
                                                                       # batch, the batches in parallel
    python benchmarks/gpu_agree.py --engine cpu --csv agree.csv --workers 2
    python benchmarks/gpu_agree.py --pool agree.csv                    # the table: means, 2 SE, agree?
    python benchmarks/gpu_agree.py --engine cpu --precision mixed --csv agree.csv --workers 2

``--precision mixed`` stores velocities, spins, forces, torques and contact histories as float32
(calib_cli.dem.system.PRECISIONS); its heaps are labelled ``cpu-mixed`` / ``gpu-mixed``. The table sets
every engine and precision beside the CPU kernel in double precision, the reference.

The CPU engine's heaps are bitwise the same on any machine and thread count, so they may come from
another machine than the GPU's. A GPU heap's wall time is its batch's, shared by its heaps.
"""

from __future__ import annotations

import argparse
import csv
import importlib
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

CASES = {
    "non-cohesive": {"static_friction": 0.5, "rolling_friction": 0.1, "restitution": 0.3},
    "cohesive": {"static_friction": 0.5, "rolling_friction": 0.2, "restitution": 0.3, "surface_energy": 0.5},
    "rolling spring": {"static_friction": 0.5, "rolling_friction": 0.3, "restitution": 0.3, "rolling_spring": 1.0},
}
FIELDS = ["preset", "case", "engine", "seed", "angle", "status", "steps", "wall_s"]


def _record(path: str, rows: list[dict]) -> None:
    new = not os.path.exists(path)
    with open(path, "a", newline="") as f:
        w = csv.DictWriter(f, FIELDS)
        if new:
            w.writeheader()
        w.writerows(rows)
        f.flush()


def _row(preset: str, case: str, engine: str, r, wall: float) -> dict:
    angle = r.angle.angle if r.status == "ok" else float("nan")
    return {"preset": preset, "case": case, "engine": engine, "seed": r.seed, "angle": angle,
            "status": r.status, "steps": r.n_steps, "wall_s": round(wall, 1)}


def _numerics(pre, time_max: float | None, precision: str = "double"):
    from dataclasses import replace

    num = replace(pre.numerics, precision=precision)
    return num if time_max is None else replace(num, time_max=time_max,
                                                settle_time_max=min(num.settle_time_max, time_max / 3))


def _label(engine: str, precision: str) -> str:
    return engine if precision == "double" else f"{engine}-{precision}"


def gpu_case(preset: str, case: str, seeds: list[int], time_max: float | None = None,
             precision: str = "double") -> list[dict]:
    """One case's heaps in one GPU batch."""
    from calib_cli.dem import gpu
    from calib_cli.dem.heap import HeapTest, get_preset

    pre = get_preset(preset)
    t = time.perf_counter()
    tests = [HeapTest(CASES[case], pre.condition, _numerics(pre, time_max, precision), s) for s in seeds]
    results = gpu.run_heaps(tests)
    wall = time.perf_counter() - t
    return [_row(preset, case, _label("gpu", precision), r, wall) for r in results]


def cpu_heap(preset: str, case: str, seed: int, time_max: float | None = None,
             precision: str = "double") -> list[dict]:
    os.environ["NUMBA_NUM_THREADS"] = "1"
    from calib_cli.dem.heap import get_preset, run_heap

    pre = get_preset(preset)
    t = time.perf_counter()
    r = run_heap(CASES[case], pre.condition, _numerics(pre, time_max, precision), seed=seed)
    return [_row(preset, case, _label("cpu", precision), r, time.perf_counter() - t)]


def run(engine: str, preset: str, cases: list[str], seeds: list[int], path: str, workers: int,
        time_max: float | None = None, precision: str = "double") -> None:
    if engine == "gpu":  # a batch per case, in parallel: a step is launch-bound, each process launches its own
        jobs = [(gpu_case, preset, c, seeds, time_max, precision) for c in cases]
        workers = len(jobs)
    else:
        jobs = [(cpu_heap, preset, c, s, time_max, precision) for c in cases for s in seeds]
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as ex:
        futs = [ex.submit(*j) for j in jobs]
        for f in as_completed(futs):
            rows = f.result()
            _record(path, rows)
            print(f"{rows[0]['case']}: {len(rows)} {rows[0]['engine']} heap(s), {rows[0]['wall_s']} s, angles "
                  + " ".join(f"{r['angle']:.2f}" for r in rows), flush=True)


def pool(path: str) -> None:
    """The table: per case, the CPU kernel's mean and sd over seeds (double precision, the reference) beside
    each other engine's or precision's, their difference and 2 standard errors."""
    import pandas as pd

    df = pd.read_csv(path).drop_duplicates(["preset", "case", "engine", "seed"], keep="last")
    print(f"{'preset / case':<28}{'engine':>10}{'CPU [deg]':>16}{'it [deg]':>16}{'diff':>8}{'2 SE':>7}  agree  "
          "heaps cpu/it  wall a heap cpu / its [s]")
    for (preset, case), d in df.groupby(["preset", "case"], sort=False):
        a = d[d.engine == "cpu"]
        for engine in [e for e in d.engine.unique() if e != "cpu"]:
            b = d[d.engine == engine]
            x, y = a.angle.to_numpy(float), b.angle.to_numpy(float)
            x, y = x[np.isfinite(x)], y[np.isfinite(y)]
            if len(x) < 2 or len(y) < 2:
                print(f"{preset + ' / ' + case:<28}{engine:>10} too few heaps: {len(x)} cpu, {len(y)} {engine}")
                continue
            diff = y.mean() - x.mean()
            se2 = 2 * np.sqrt(x.var(ddof=1) / len(x) + y.var(ddof=1) / len(y))
            wall = b.wall_s.max() if engine.startswith("gpu") else b.wall_s.mean()  # a GPU batch's is shared
            print(f"{preset + ' / ' + case:<28}{engine:>10}{x.mean():>9.2f} +-{x.std(ddof=1):4.1f}"
                  f"{y.mean():>9.2f} +-{y.std(ddof=1):4.1f}{diff:>8.2f}{se2:>7.2f}  "
                  f"{'yes' if abs(diff) <= se2 else 'NO '}    {len(x):>3} / {len(y):<3}    "
                  f"{a.wall_s.mean():.0f} / {wall:.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--engine", choices=["cpu", "gpu"])
    ap.add_argument("--preset", default="default")
    ap.add_argument("--cases", default=",".join(CASES), help="comma separated, of: " + ", ".join(CASES))
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=os.cpu_count(), help="CPU engine: heaps at once")
    ap.add_argument("--csv", default="gpu_agree.csv")
    ap.add_argument("--time-max", type=float, help="cut every heap short at this simulated time [s] (a check of "
                    "the script, not of the physics)")
    ap.add_argument("--precision", default="double", choices=["double", "mixed"], help="what the state arrays "
                    "store: mixed keeps velocities, spins, forces, torques and contact histories as float32")
    ap.add_argument("--pool", metavar="CSV", help="print the table from this CSV, run nothing")
    a = ap.parse_args()
    if a.pool:
        return pool(a.pool)
    if not a.engine:
        ap.error("--engine cpu or gpu (or --pool CSV)")
    seeds = list(range(a.first_seed, a.first_seed + a.seeds))
    run(a.engine, a.preset, a.cases.split(","), seeds, a.csv, a.workers, a.time_max, a.precision)
    pool(a.csv)


if __name__ == "__main__":
    main()
