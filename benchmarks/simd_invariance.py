"""Does a heap depend on the SIMD level numpy dispatches on? The same heaps, twice, side by side.

    python benchmarks/simd_invariance.py --heaps 8

Runs the same `smoke` heaps (a spread of friction, rolling friction and cohesion, fixed seeds)
in two processes at once, one numba thread each: one with numpy as this CPU sets it up, one
with every numpy dispatch target switched off (``NPY_DISABLE_CPU_FEATURES``), as numpy runs on
an older CPU. On a CPU with AVX-512 this is the difference between a machine with AVX-512 and
one without, measured on one machine. Prints per heap the angle and step count of each and
whether the final particle positions are bitwise equal. A heap amplifies a difference of one
unit in the last place until it settles differently, so only "equal" means portable.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = """
import hashlib, json, sys
import numba
from calib_cli.campaign import host
from calib_cli.dem import heap
numba.set_num_threads(1)
p = heap.get_preset("smoke")
out = []
for i, prm in enumerate(json.loads(sys.argv[1])):
    r = heap.run_heap(prm, p.condition, p.numerics, seed=100 + i)
    out.append(dict(angle=r.angle.angle, steps=r.n_steps,
                    pos=hashlib.sha256(r.system.particles.pos.tobytes()).hexdigest()))
print(json.dumps(dict(host=host(), heaps=out)))
"""


def points(n: int) -> list[dict]:
    """n points spread over the smoke stage's ranges (stages/smoke.toml), half of them cohesive."""
    out = []
    for i in range(n):
        f = (i * 0.618034) % 1.0
        out.append(dict(static_friction=round(0.1 + 0.5 * f, 3), rolling_friction=round(0.05 + 0.35 * (1 - f), 3),
                        surface_energy=0.0 if i % 2 == 0 else round(0.2 + 0.8 * f, 3), restitution=0.25))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heaps", type=int, default=8)
    a = ap.parse_args()
    from numpy._core._multiarray_umath import __cpu_dispatch__ as targets

    prm = points(a.heaps)
    env_off = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(targets), "NUMBA_NUM_THREADS": "1"}
    env_on = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, json.dumps(prm)], env=e, stdout=subprocess.PIPE, text=True)
             for e in (env_on, env_off)]
    on, off = (json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs)
    print(f"A: {on['host']}\nB: {off['host']} (NPY_DISABLE_CPU_FEATURES: every numpy dispatch target)")
    equal = 0
    for p, x, y in zip(prm, on["heaps"], off["heaps"]):
        same = x["pos"] == y["pos"]
        equal += same
        print(f"mu_s {p['static_friction']:.3f} mu_r {p['rolling_friction']:.3f} g {p['surface_energy']:.3f} | "
              f"A {x['angle']:6.3f} deg {x['steps']:6d} steps | B {y['angle']:6.3f} deg {y['steps']:6d} steps | "
              f"{'bitwise equal' if same else 'DIFFERENT'}")
    print(f"{equal} of {len(prm)} heaps bitwise equal")


if __name__ == "__main__":
    main()
