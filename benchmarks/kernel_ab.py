"""Kernel throughput of two source trees side by side: a `default` cohesive fill (JKR, constant torque),
3,000 steps on one numba thread, each tree in its own process, alternating, median of the repeats.

    git worktree add --detach /tmp/old <commit>
    python benchmarks/kernel_ab.py /tmp/old . --repeats 3

The compile happens before the timed steps (and is cached on disk after the first run).
"""
import subprocess, sys, os
code = r'''
import time, numpy as np
from calib_cli.dem.heap import PRESETS, fill_cylinder, interactions
from calib_cli.dem.system import System, Walls
from calib_cli.dem.materials import Material
pre = PRESETS["default"]; cond, num = pre.condition, pre.numerics
pp, pf, pc = interactions({"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}, cond)
parts = fill_cylinder(cond, num.packing_fraction, np.random.default_rng(3))
s = System(parts, material=Material(num.shear_modulus, num.poisson, num.density), wall_material=Material(num.wall_shear_modulus, num.poisson, num.density), pp=pp, floor=pf, cylinder=pc, walls=Walls(True, 0.025, 0.05, np.inf), safety=num.safety)
s.drag = 10.0
s.advance(200)
t = time.perf_counter(); s.advance(3000); dt = time.perf_counter() - t
print(s.n * 3000 / dt)
'''
import argparse
ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("old")
ap.add_argument("new")
ap.add_argument("--repeats", type=int, default=3)
a = ap.parse_args()
env = dict(os.environ, NUMBA_NUM_THREADS="1")
res = {"old": [], "new": []}
for rep in range(a.repeats):
    for name, path in (("old", os.path.abspath(a.old)), ("new", os.path.abspath(a.new))):
        out = subprocess.run([sys.executable, "-c", code], cwd=path, env={**env, "PYTHONPATH": path},
                             capture_output=True, text=True, check=True).stdout.split()[-1]
        res[name].append(float(out))
        print(name, f"{float(out):.3g}", flush=True)
import statistics as st
print({k: f"{st.median(v):.3g}" for k, v in res.items()}, "new/old", f"{st.median(res['new'])/st.median(res['old']):.3f}")
