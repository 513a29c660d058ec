"""One heap test end to end on the GPU engine (default: a `paper` heap, the rig's 150 mm cylinder with
44,669 grains of 3-5 mm, lifted at 5 mm/s): the fill built on the CPU, then settle, lift and rest on the
device, as `calib simulate-heap --engine gpu` runs it. Prints the simulated time every --every seconds
of wall time as it goes, then the heap's status, angle, steps and wall time, and the CPU kernel's rate
on the same fill for scale (one chunk on every thread).

    python benchmarks/gpu_paper_heap.py                       # the paper heap, the default stepping mode
    python benchmarks/gpu_paper_heap.py --mode graph --csv paper_heap.csv
    NUMBA_ENABLE_CUDASIM=1 python benchmarks/gpu_paper_heap.py --preset smoke --time-max 0.006 --every 1   # checks the script
"""
import argparse
import dataclasses
import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from calib_cli.dem import gpu
from calib_cli.dem.heap import PRESETS, HeapTest

PARAMS = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--mode", default=None, help="stepping mode (default: CALIB_GPU_STEP, else the engine's default)")
    ap.add_argument("--time-max", type=float, default=None, help="simulated seconds at most (default: the preset's)")
    ap.add_argument("--every", type=float, default=15.0, help="wall seconds between progress lines")
    ap.add_argument("--csv", default=None, help="append the result as a row here")
    a = ap.parse_args()
    pre = PRESETS[a.preset]
    num = pre.numerics
    if a.time_max is not None:  # a short test: each phase fits in it
        num = dataclasses.replace(num, time_max=a.time_max, settle_time_max=min(num.settle_time_max, a.time_max / 3),
                                  rest_time_min=min(num.rest_time_min, a.time_max / 3))
    mode = gpu.step_mode(a.mode)
    t0, last = time.perf_counter(), [0.0]

    def progress(t, t_max, phase):
        now = time.perf_counter() - t0
        if now - last[0] >= a.every:
            last[0] = now
            print(f"{now:7.1f} s wall: t = {t:.3f} of {t_max:.3g} s simulated ({phase})", flush=True)

    test = HeapTest(PARAMS, pre.condition, num, seed=0, progress=progress)
    built = time.perf_counter() - t0
    print(f"{a.preset} heap: {test.system.n} grains, dt {test.system.dt:.3g} s, fill built in {built:.1f} s; "
          f"stepping mode {mode}, contacts a thread a {gpu.contact_layout(None, test.system.n)}, force kernels' "
          f"registers {gpu.register_cap() or 'uncapped'} (CALIB_GPU_CONTACTS, CALIB_GPU_MAXREG)", flush=True)
    r = gpu.run_heaps([test], mode=mode)[0]
    wall = time.perf_counter() - t0
    s = r.system
    cpu = _cpu_rate(a.preset, num)
    print(f"status {r.status} ({r.message}); angle {r.angle.angle:.2f} deg; {s.n_steps} steps to t = {s.t:.3f} s "
          f"(settled {r.t_settled:.3f} s, lift ended {r.t_lift_end:.3f} s); wall {wall:.1f} s "
          f"({s.n * s.n_steps / (wall - built):.3g} particle-steps/s on the GPU)")
    print(f"the CPU kernel on every thread steps this fill at {cpu:.3g} particle-steps/s: "
          f"{s.n * s.n_steps / cpu / 60:.0f} min for these steps")
    if a.csv:
        import pandas as pd

        row = dict(preset=a.preset, mode=mode, contacts=gpu.contact_layout(None, s.n),
                   register_cap=gpu.register_cap(),
                   grains=s.n, steps=s.n_steps, t_end=s.t, status=r.status, angle=r.angle.angle,
                   t_settled=r.t_settled, t_lift_end=r.t_lift_end, wall_s=wall, fill_s=built, cpu_rate=cpu)
        pd.DataFrame([row]).to_csv(a.csv, index=False)


def _cpu_rate(preset: str, num, steps: int = 200) -> float:
    """Particle-steps per second of the CPU kernel on a fresh fill of ``preset`` (after one untimed chunk)."""
    s = HeapTest(PARAMS, PRESETS[preset].condition, num, seed=0).system
    s.advance(20)
    t = time.perf_counter()
    s.advance(steps)
    return s.n * steps / (time.perf_counter() - t)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
