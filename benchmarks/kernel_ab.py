"""Kernel throughput of two source trees side by side: a `default` cohesive heap (JKR, constant torque) in
contact, settled and lifted for 0.05 s by each tree's own heap protocol (benchmarks/heap_states.py says why:
a fresh fill steps about 5x faster and runs no contact law; --state fresh times it, as this script did
before 2026-11-29), then 3,000 steps on one numba thread, each tree in its own process, alternating (which
goes first swaps every repeat: use an even --repeats), median of the repeats.

    git worktree add --detach /tmp/old <commit>
    python benchmarks/kernel_ab.py /tmp/old . --repeats 4

The compile happens before the timed steps (and is cached on disk after the first run).
"""
import subprocess, sys, os
code = r'''
import sys, time, numpy as np
from calib_cli.dem.heap import PRESETS, HeapTest, fill_cylinder, interactions
from calib_cli.dem.system import System, Walls
from calib_cli.dem.materials import Material
pre = PRESETS["default"]; cond, num = pre.condition, pre.numerics
P = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}
if sys.argv[1] == "fresh":
    pp, pf, pc = interactions(P, cond)
    parts = fill_cylinder(cond, num.packing_fraction, np.random.default_rng(3))
    s = System(parts, material=Material(num.shear_modulus, num.poisson, num.density), wall_material=Material(num.wall_shear_modulus, num.poisson, num.density), pp=pp, floor=pf, cylinder=pc, walls=Walls(True, 0.025, 0.05, np.inf), safety=num.safety)
    s.drag = 10.0
    s.advance(200)
else:
    test = HeapTest(P, cond, num, seed=3)
    while not (test.stage != "settle" and test.system.t >= test.t_settled + 0.05):
        test.system.advance(num.chunk); test.advanced()
    s = test.system
t = time.perf_counter(); s.advance(3000); dt = time.perf_counter() - t
print(s.n * 3000 / dt)
'''
import argparse
ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("old")
ap.add_argument("new")
ap.add_argument("--repeats", type=int, default=3)
ap.add_argument("--state", choices=("settled", "fresh"), default="settled")
a = ap.parse_args()
env = dict(os.environ, NUMBA_NUM_THREADS="1")
res = {"old": [], "new": []}
trees = [("old", os.path.abspath(a.old)), ("new", os.path.abspath(a.new))]
for rep in range(a.repeats):
    # old-new, then new-old: the second process of a pair runs ~2 % slower here (`. .` gave 0.977 with the
    # old one first every time, 2026-11-29), and one order throughout would charge that to the change
    for name, path in (trees if rep % 2 == 0 else trees[::-1]):
        out = subprocess.run([sys.executable, "-c", code, a.state], cwd=path, env={**env, "PYTHONPATH": path},
                             capture_output=True, text=True, check=True).stdout.split()[-1]
        res[name].append(float(out))
        print(name, f"{float(out):.3g}", flush=True)
import statistics as st
print({k: f"{st.median(v):.3g}" for k, v in res.items()}, "new/old", f"{st.median(res['new'])/st.median(res['old']):.3f}")
