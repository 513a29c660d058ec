"""Time 4,000 steps of a smoke fill in this process (the compile happens before the clock starts).

    NUMBA_NUM_THREADS=1 python benchmarks/smoke_steps.py
    NUMBA_NUM_THREADS=2 python benchmarks/smoke_steps.py

Run both while other processes load the cores to see what numba's parallel pair loop costs on a
busy machine (docs/performance.md, "Two numba threads on a loaded machine").
"""

import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from calib_cli.dem.heap import PRESETS, fill_cylinder, interactions
from calib_cli.dem.materials import Material
from calib_cli.dem.system import System, Walls

pre = PRESETS["smoke"]
cond, num = pre.condition, pre.numerics
pp, pf, pc = interactions({"static_friction": 0.5, "rolling_friction": 0.1, "restitution": 0.3}, cond)
parts = fill_cylinder(cond, num.packing_fraction, np.random.default_rng(3))
t = time.time()
s = System(parts, material=Material(num.shear_modulus, num.poisson, num.density),
           wall_material=Material(num.wall_shear_modulus, num.poisson, num.density), pp=pp, floor=pf, cylinder=pc,
           walls=Walls(True, 0.025, 0.1, np.inf), safety=num.safety)
s.advance(10)
t1 = time.time()
s.advance(4000)
t2 = time.time()
print(f"n={s.n} setup+compile {t1 - t:.1f}s, 4000 steps {t2 - t1:.2f}s -> {s.n * 4000 / (t2 - t1):.3g} p-steps/s")
