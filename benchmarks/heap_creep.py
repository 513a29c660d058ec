"""How static is a finished heap? Runs one heap with the rest criterion switched off and
prints, every ~0.1 s after the cylinder leaves, the median and 99th-percentile grain speed,
the coordinate angle and the heap height: the creep of the constant-directional-torque
rolling law (docs/physics.md, "Creep").

`--rig calibration` runs the 40 mm rig of `benchmarks/rolling_law.py` instead of the preset's
geometry, and `--repeat N` its N-th seed (derive_seed(11, 0, N)), so that the heap is the one a
`rolling_law.py` run simulated (the usual-protocol angle printed first shows it). `--during`
samples from the start of the lift, every ~0.05 s, with the cylinder's rim height: when two laws'
heaps part, during the lift or after it.

Usage:  python benchmarks/heap_creep.py [--preset default] [--rig calibration] [--set surface_energy=1.25 ...]
        [--after 3.0] [--seed 0 | --repeat 0] [--during] [--modulus 5e8]
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

import calib_cli.dem.heap as heap
from calib_cli.heaps.inputs import heap_preset
from calib_cli.heaps.keys import derive_seed


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="default")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--after", type=float, default=3.0, help="seconds of rest to follow after the lift")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rig", choices=["preset", "calibration"], default="preset")
    ap.add_argument("--repeat", type=int, help="rolling_law.py's seed of this repeat (instead of --seed)")
    ap.add_argument("--during", action="store_true", help="sample during the lift too")
    ap.add_argument("--modulus", type=float, help="shear modulus of grains and walls [Pa] (the preset's: 5e6)")
    a = ap.parse_args()
    if a.repeat is not None:
        a.seed = derive_seed(11, 0, a.repeat)
    params = {"static_friction": 0.275, "rolling_friction": 0.215, "surface_energy": 1.25, "restitution": 0.2}
    for kv in a.set:
        k, v = kv.split("=", 1)
        params[k] = float(v)
    pre = heap_preset(a.preset, a.modulus)
    if a.rig == "calibration":
        from rolling_law import RIGS

        pre = dataclasses.replace(pre, condition=RIGS["calibration"])
    # the heap is first run as usual to find its lift end, then again (same seed: bitwise the
    # same trajectory) with a fixed rest of --after seconds, sampled every chunk
    t0 = time.perf_counter()
    first = heap.run_heap(params, pre.condition, pre.numerics, seed=a.seed)
    num = dataclasses.replace(pre.numerics, rest_speed=0.0, rest_time_min=a.after,
                              time_max=first.t_lift_end + a.after + 1e-9)
    samples = []
    orig = heap.System.advance

    def advance(self, n):
        orig(self, n)
        lifting = self.walls.lift_start <= self.t and self.geo[2] != 0.0
        if self.walls.lift_start < np.inf and (self.geo[2] == 0.0 or (a.during and lifting)):  # gone, or lifting
            p = self.particles
            sp = np.linalg.norm(p.vel, axis=1)
            ang = heap.repose_angle_coords(p.pos, p.rad)
            samples.append((self.t, np.median(sp), np.percentile(sp, 99), ang.angle, ang.height, self.geo[1]))

    heap.System.advance = advance
    try:
        r = heap.run_heap(params, pre.condition, num, seed=a.seed)
    finally:
        heap.System.advance = orig
    print(f"preset {a.preset}, {r.n_particles} grains, dt {r.system.dt:.3g} s, {params}")
    print(f"usual protocol: angle {first.angle.angle:.2f} deg at {first.t_end - first.t_lift_end:.2f} s after the "
          f"lift, drift {first.angle_drift:+.2f} deg/s ({first.status})")
    print(f"{'t after lift [s]':>17}{'median v [mm/s]':>17}{'p99 v [mm/s]':>14}{'angle [deg]':>13}{'height [mm]':>13}"
          f"{'rim [mm]':>10}")
    next_t = -np.inf
    for t, med, p99, ang, h, rim in samples:
        if t - r.t_lift_end >= next_t - 1e-9:
            print(f"{t - r.t_lift_end:17.2f}{med * 1e3:17.2f}{p99 * 1e3:14.2f}{ang:13.2f}{h * 1e3:13.1f}"
                  f"{rim * 1e3:10.1f}")
            dt_print = 0.05 if t < r.t_lift_end else 0.1 if t - r.t_lift_end < 0.5 else 0.25
            next_t = max(next_t, t - r.t_lift_end) + dt_print
    print(f"wall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
