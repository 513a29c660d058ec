"""Compile the GPU engine's kernels to PTX for an H100/H200 (compute capability 9.0), with no GPU:
every kernel of four compositions that together use every contact law, from the same law functions
the CPU kernel runs. Needs the [gpu] extra (numba-cuda and CUDA's NVVM).

    NUMBA_ENABLE_CUDASIM=0 python benchmarks/gpu_compile.py
"""
import os
import sys
import time

os.environ["NUMBA_ENABLE_CUDASIM"] = "0"
import numpy as np  # noqa: E402

from calib_cli.dem import gpu  # noqa: E402
from calib_cli.dem.materials import Interaction, Material  # noqa: E402
from calib_cli.dem.system import Particles, System, Walls  # noqa: E402

COMPOSITIONS = [  # (grains' values, walls' values): every law of every family at least once
    ({}, {}),
    ({"surface_energy": 0.5}, {"surface_energy": 0.5}),
    ({"surface_energy": 0.5, "rolling_spring": 1.0, "caps_pulloff": 1.0}, {"rolling_spring": 1.0, "caps_pulloff": 1.0}),
    ({"surface_tension": 0.072, "rolling_own_spin": 1.0, "friction_net_force": 1.0},
     {"rolling_own_spin": 1.0, "friction_net_force": 1.0}),
]


def system(grains: dict, walls: dict) -> System:
    rng = np.random.default_rng(0)
    pos = np.column_stack([rng.uniform(-3e-3, 3e-3, (8, 2)), 1.5e-3 + 3.1e-3 * np.arange(8)])
    it = Interaction(static_friction=0.5, rolling_friction=0.2, **grains)
    w = Interaction(static_friction=0.3, **walls)
    return System(Particles(pos, np.full(8, 1.5e-3)), material=Material(5e6, 0.25, 2600), pp=it, floor=w, cylinder=w,
                  walls=Walls(True, 6e-3, 0.05, 0.0))


failed = 0
for grains, walls in COMPOSITIONS:
    s = system(grains, walls)
    t = time.perf_counter()
    try:
        ptx = gpu.compile_ptx(s.model.spec, [s], cc=(9, 0))
    except Exception as e:  # noqa: BLE001 - report and go on to the next composition
        failed += 1
        print(f"{s.model.spec}: FAILED {type(e).__name__}: {str(e).splitlines()[0][:200]}")
        continue
    ok = all(".target sm_90" in p for p in ptx.values())
    failed += not ok
    print(f"{s.model.spec}: {len(ptx)} kernels, sm_90 {'ok' if ok else 'MISSING'}, "
          f"{sum(map(len, ptx.values())) / 1e3:.0f} kB of PTX, {time.perf_counter() - t:.0f} s")
sys.exit(1 if failed else 0)
