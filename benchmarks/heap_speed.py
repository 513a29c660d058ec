"""A whole `default` heap on this tree against the same heap on an earlier revision, side by side.

    python benchmarks/heap_speed.py --baseline main --seeds 0 1
    python benchmarks/heap_speed.py --baseline main --rig calibration --seeds 0 1

The baseline revision is checked out into a temporary git worktree. For each seed both
versions run the same heap (the `default` preset at the centre of the paper's Table 6:
mu_s 0.275, mu_r 0.215, g 1.25 J/m2) at the same time, one process and one numba thread
each, so the two share the machine alike; each first runs a `smoke` heap to compile.
``--rig calibration`` runs instead the sample calibration's photographed rig (4-5 mm grains,
40 mm cylinder filled 75 mm, ~1,200 grains) at the centre of its ranges (stages/settings/calibration.toml).
Where the kernels' floating-point results differ in the last bits the heaps take slightly
different paths: then compare time per step, not total time ("same bits" says which).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHILD = """
import json, sys, time
from calib_cli.dem import heap
heap.run_heap({}, heap.get_preset("smoke").condition, heap.get_preset("smoke").numerics)
if sys.argv[2] == "calibration":
    params = dict(static_friction=0.35, rolling_friction=0.225, surface_energy=0.6, restitution=0.25)
    cond = heap.HeapCondition(particle_d_min_mm=4.0, particle_d_max_mm=5.0, cylinder_diameter_mm=40.0,
                              fill_height_mm=75.0, lift_speed_mm_s=50.0)
else:
    params, cond = dict(static_friction=0.275, rolling_friction=0.215, surface_energy=1.25), None
t = time.perf_counter()
r = heap.run_heap(params, cond, seed=int(sys.argv[1]))
print(json.dumps(dict(wall=time.perf_counter() - t, steps=r.n_steps, n=r.n_particles, angle=r.angle.angle,
                      drift=r.angle_drift, src=heap.__file__)))
"""


def start(tree: Path, seed: int, rig: str) -> subprocess.Popen:
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "PYTHONPATH": str(tree)}
    env.pop("NUMBA_CACHE_DIR", None)
    return subprocess.Popen([sys.executable, "-c", CHILD, str(seed), rig], cwd=tree, env=env, stdout=subprocess.PIPE,
                            text=True)


def same(out: list[dict]) -> str:
    keys = ("steps", "angle", "drift")
    return "yes" if all(out[0][k] == out[1][k] for k in keys) else "no"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default="main", help="git revision to compare with")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--rig", choices=["default", "calibration"], default="default")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(base), a.baseline], check=True)
        try:
            print(f"{'seed':>4} {'grains':>6} | {'baseline us/step':>16} {'angle':>6} | {'this tree us/step':>17} "
                  f"{'angle':>6} | speed-up")
            for seed in a.seeds:
                procs = [start(base, seed, a.rig), start(ROOT, seed, a.rig)]
                out = [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]
                assert out[0]["src"].startswith(str(base)) and out[1]["src"].startswith(str(ROOT)), out
                us = [o["wall"] / o["steps"] * 1e6 for o in out]
                print(f"{seed:>4} {out[1]['n']:>6} | {us[0]:>16.0f} {out[0]['angle']:>6.2f} | {us[1]:>17.0f} "
                      f"{out[1]['angle']:>6.2f} | {us[0] / us[1]:.2f}x  ({out[0]['wall']:.1f} s -> {out[1]['wall']:.1f} s; "
                      f"same bits: {same(out)})")
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)], check=False)


if __name__ == "__main__":
    main()
