"""Where does a heap's scatter come from, and could a surrogate learn more from each heap? (issue 47: the
posterior needs fewer heaps only if each teaches more.) Two measurements on the same heaps, side by side:

- **views**: a heap's angle as the lab measures it, one side view (two flanks, ``repose_angle``), against the
  mean of K side views at azimuths k * 180 / K deg of the same heap (rendering is free beside the DEM). Its
  expectation is the same (the rig is axisymmetric; a photograph's azimuth is arbitrary), so the pile-to-pile
  variance the K-view mean removes is variance a surrogate of the mean angle need not average away.
- **seeds**: the same fill (seed) at nearby parameter points (static friction +0, +0.03, +0.15): how
  correlated are their angles? Correlated scatter (common random numbers) would let a surrogate with a
  per-seed effect learn the angle's trend from fewer heaps.

Two cases at one lab condition of ``make hidden-effect`` (5-6 mm grains, 40 mm cylinder, 75 mm fill): cohesive
(surface energy 0.6 J/m2, that lab's truth) and dry (0). Each heap as ``calib simulate`` runs it.

    .venv/bin/python benchmarks/heap_noise.py --seeds 16 --workers 2
"""
from __future__ import annotations

import argparse
import importlib
import time
from concurrent.futures import ProcessPoolExecutor

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

CONDITION = (5.0, 6.0, 40.0, 75.0, 50.0)
BASE = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3}
CASES = {"cohesive": 0.6, "dry": 0.0}
SHIFTS = (0.0, 0.03, 0.15)


def views(pos: np.ndarray, rad: np.ndarray, k: int) -> np.ndarray:
    """The measured angle of ``k`` side views, the heap turned by pi * j / k about its axis (NaN where a view
    has no angle)."""
    from calib_cli.dem.render import render_side_view
    from calib_cli.imaging.measure import measure_image

    out = np.full(k, np.nan)
    for j in range(k):
        c, s = np.cos(np.pi * j / k), np.sin(np.pi * j / k)
        p = pos.copy()
        p[:, 0], p[:, 1] = c * pos[:, 0] - s * pos[:, 1], s * pos[:, 0] + c * pos[:, 1]
        m = measure_image(render_side_view(p, rad).image, limits=None)  # as the campaign's rows
        out[j] = m.repose_angle if m.status == "ok" else np.nan
    return out


def heap(job: tuple) -> dict:
    import numba

    from calib_cli.dem.heap import HeapCondition, Numerics, run_heap

    numba.set_num_threads(1)  # one heap per core, as a campaign's workers
    case, shift, seed, k = job
    params = {**BASE, "surface_energy": CASES[case]}
    params["static_friction"] += shift
    r = run_heap(params, HeapCondition(*CONDITION), Numerics(), seed)
    v = views(r.system.particles.pos, r.system.particles.rad, k) if r.status == "ok" else np.full(k, np.nan)
    return {"case": case, "shift": shift, "seed": seed, "status": r.status, **{f"v{j}": v[j] for j in range(k)}}


def pooled_variance(d: pd.DataFrame, col: str) -> float:
    """The piles' variance about their parameter point's mean, pooled over the points."""
    g = d.groupby(["case", "shift"])[col]
    dev = d[col] - g.transform("mean")
    return float((dev ** 2).sum() / (d[col].notna().sum() - g.ngroups))


def report(d: pd.DataFrame, k: int) -> None:
    d = d[d.status == "ok"].copy()
    d["one"], d["mean_k"] = d["v0"], d[[f"v{j}" for j in range(k)]].mean(axis=1)
    print(f"\nviews: pile-to-pile variance (deg^2), one side view against the mean of {k}")
    rows = []
    for case, sub in d.groupby("case"):
        one, many = pooled_variance(sub, "one"), pooled_variance(sub, "mean_k")
        within = float(np.nanmean(sub[[f"v{j}" for j in range(k)]].std(axis=1, ddof=1)))
        rows.append({"case": case, "piles": len(sub), "one view": round(one, 2), f"{k} views": round(many, 2),
                     "ratio": round(many / one, 2), "sd between views": round(within, 2)})
    print(pd.DataFrame(rows).to_string(index=False))
    print("\nseeds: correlation of one view's angle between parameter points, paired by seed (95 % interval)")
    rows = []
    for case, sub in d.groupby("case"):
        w = sub.pivot(index="seed", columns="shift", values="one").dropna()
        for i, a in enumerate(SHIFTS):
            for b in SHIFTS[i + 1:]:
                r = float(np.corrcoef(w[a], w[b])[0, 1])
                half = 1.96 / np.sqrt(max(len(w) - 3, 1))
                lo, hi = np.tanh(np.arctanh(r) - half), np.tanh(np.arctanh(r) + half)
                rows.append({"case": case, "static friction shift": f"+{a:g} vs +{b:g}", "seeds": len(w),
                             "r": round(r, 2), "95 %": f"{lo:.2f} to {hi:.2f}"})
    print(pd.DataFrame(rows).to_string(index=False))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--csv", default="", help="keep the heaps' angles here (and read them back with --pool)")
    ap.add_argument("--pool", action="store_true", help="only print the tables of --csv")
    a = ap.parse_args()
    if a.pool:
        report(pd.read_csv(a.csv), a.views)
        return
    jobs = [(c, s, seed, a.views) for c in CASES for s in SHIFTS for seed in range(1, a.seeds + 1)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.workers) as ex:
        d = pd.DataFrame(list(ex.map(heap, jobs)))
    print(f"{len(jobs)} heaps on {a.workers} workers: {time.perf_counter() - t0:.0f} s")
    if a.csv:
        d.to_csv(a.csv, index=False)
    report(d, a.views)


if __name__ == "__main__":
    main()
