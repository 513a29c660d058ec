"""Re-simulate committed heaps on this machine and compare them with the committed results, bit for bit.

    python benchmarks/reproduce_heaps.py sample_runs/smoke --limit 12
    NUMBA_CPU_NAME=generic python benchmarks/reproduce_heaps.py sample_runs/smoke --limit 12
    python benchmarks/reproduce_heaps.py sample_runs/smoke --query "surface_energy == 0"

Every row of ``RUN/simulate/results.parquet`` holds what determines its heap (parameters,
condition, preset, seed, physics version); this runs the same heap with the kernel of this
tree, one process and one numba thread (as a campaign worker does), and prints, per heap, the
committed and the new coordinate angle and step count. A heap is a chaotic many-body system: a
difference of one unit in the last place anywhere grows until the heap settles differently, so
the figure that matters is how many heaps come out bitwise equal. Rows made under another
physics version are skipped (their run hash would not match either).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numba
import numpy as np
import pandas as pd

from calib_cli.dem import heap
from calib_cli.heaps.inputs import request_from_row
from calib_cli.heaps.keys import CACHE_SOURCE, host


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--limit", type=int, default=12, help="heaps to re-simulate (the first N of this kernel)")
    ap.add_argument("--query", default="", help="a pandas query on the results rows, e.g. 'surface_energy == 0'")
    args = ap.parse_args()
    res = pd.read_parquet(args.run / "simulate" / "results.parquet")
    res = res[(res["source"] == CACHE_SOURCE) & (res["engine"] == "builtin") & (res["status"] == "ok")]
    if args.query:
        res = res.query(args.query)
    if res.empty:
        sys.exit(f"no builtin heaps of this physics version ({CACHE_SOURCE}) in {args.run} {args.query}")
    numba.set_num_threads(1)
    made = sorted(res["host"].dropna().unique()) if "host" in res else []
    print(f"here: {host()}, NUMBA_CPU_NAME={numba.config.CPU_NAME or 'host'}; "
          f"made on: {', '.join(made) or 'not recorded (rows made before the host column)'}")
    equal, diffs = 0, []
    rows = res.drop_duplicates("run_hash").head(args.limit)
    for _, row in rows.iterrows():
        req = request_from_row(row)
        if req.hash != row["run_hash"]:
            sys.exit(f"run {row['run_hash']}: its inputs could not be rebuilt from the results row")
        r = heap.run_heap(req.params, req.condition, req.numerics, req.seed)
        same = r.n_steps == row["n_steps"] and r.angle.angle == row["angle_coords"]
        equal += same
        diffs.append(r.angle.angle - row["angle_coords"])
        print(f"{row['run_hash']}  committed {row['angle_coords']:7.3f} deg {row['n_steps']:6d} steps   "
              f"here {r.angle.angle:7.3f} deg {r.n_steps:6d} steps   {'bitwise equal' if same else 'DIFFERENT'}")
    d = np.abs(np.array(diffs))
    print(f"{equal} of {len(rows)} heaps bitwise equal; mean |difference| {d.mean():.2f} deg, max {d.max():.2f} deg")


if __name__ == "__main__":
    main()
