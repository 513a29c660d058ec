"""Does a heap depend on the SIMD level numpy dispatches on? The same heaps, twice, side by side.

    python benchmarks/simd_invariance.py --heaps 8
    python benchmarks/simd_invariance.py --heaps 8 --as baseline

Runs the same `smoke` heaps (a spread of friction, rolling friction and cohesion, fixed seeds)
in two processes at once, one numba thread each: A as this CPU sets the libraries up, B as
they run on a CPU without AVX-512 (``--as avx2``: numpy's AVX-512 dispatch targets off with
``NPY_DISABLE_CPU_FEATURES``, OpenCV's with ``OPENCV_CPU_DISABLE``, OpenBLAS on its Haswell
kernels) or with numpy on its baseline (``--as baseline``). On an AVX-512 CPU this measures on
one machine the difference between two machines. Prints per heap the angle and step count of
each and whether the final particle positions, the coordinate angle, its creep rate and the
rendered side view's angle are bitwise equal. A heap amplifies a difference of one unit in the
last place until it settles differently, so only "equal" means portable.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

from calib_cli.heaps.keys import numpy_dispatch_targets

CHILD = """
import hashlib, json, sys
import numba
from calib_cli.dem import heap
from calib_cli.dem.render import render_side_view
from calib_cli.heaps.keys import host
from calib_cli.imaging.measure import measure_image
numba.set_num_threads(1)
p = heap.get_preset("smoke")
out = []
for i, prm in enumerate(json.loads(sys.argv[1])):
    r = heap.run_heap(prm, p.condition, p.numerics, seed=100 + i)
    q = r.system.particles
    img = measure_image(render_side_view(q.pos, q.rad).image)
    out.append(dict(angle=r.angle.angle, steps=r.n_steps, drift=r.angle_drift, image=img.repose_angle,
                    pos=hashlib.sha256(q.pos.tobytes()).hexdigest()))
print(json.dumps(dict(host=host(), heaps=out)))
"""


def points(n: int) -> list[dict]:
    """n points spread over the sample calibration's ranges (stages/settings/calibration.toml), half of them cohesive."""
    out = []
    for i in range(n):
        f = (i * 0.618034) % 1.0
        out.append(dict(static_friction=round(0.1 + 0.5 * f, 3), rolling_friction=round(0.05 + 0.35 * (1 - f), 3),
                        surface_energy=0.0 if i % 2 == 0 else round(0.2 + 0.8 * f, 3), restitution=0.25))
    return out


def environments(mode: str = "avx2") -> tuple[dict, dict]:
    """(as this CPU sets the libraries up, as on a CPU without AVX-512 or with numpy on its baseline)."""
    targets = numpy_dispatch_targets()
    # A keeps the kernels OpenBLAS picks for this CPU, which importing calib_cli would pin (calib_cli/blas.py)
    env_on = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    env_on.update(NUMBA_NUM_THREADS="1", CALIB_NATIVE_BLAS="1")
    if mode == "avx2":
        return env_on, {**env_on, "NPY_DISABLE_CPU_FEATURES": " ".join(t for t in targets if t not in ("X86_V3", "AVX2")),
                        "OPENCV_CPU_DISABLE": "AVX512-SKX", "OPENBLAS_CORETYPE": "Haswell",
                        "CALIB_NATIVE_BLAS": "0"}
    return env_on, {**env_on, "NPY_DISABLE_CPU_FEATURES": " ".join(targets)}


def compare(prm: list[dict], mode: str = "avx2") -> tuple[dict, dict, list[list[str]]]:
    """Simulate the heaps at `prm` in two processes at once (:func:`environments`); return both
    outputs and, per heap, the quantities that differ (empty: bitwise equal)."""
    envs = environments(mode)
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, json.dumps(prm)], env=e, stdout=subprocess.PIPE, text=True)
             for e in envs]
    on, off = (json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs)
    diffs = [[k for k in ("pos", "steps", "angle", "drift", "image")
              if not (x[k] == y[k] or (x[k] != x[k] and y[k] != y[k]))]  # NaN equals NaN here
             for x, y in zip(on["heaps"], off["heaps"])]
    return on, off, diffs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--heaps", type=int, default=8)
    ap.add_argument("--as", dest="mode", choices=["avx2", "baseline"], default="avx2")
    a = ap.parse_args()
    prm = points(a.heaps)
    env_on, env_off = environments(a.mode)
    on, off, diffs = compare(prm, a.mode)
    off_env = {k: v for k, v in env_off.items() if k not in env_on}
    print(f"A: {on['host']}\nB: {off['host']} {off_env}")
    for p, x, y, diff in zip(prm, on["heaps"], off["heaps"], diffs):
        print(f"mu_s {p['static_friction']:.3f} mu_r {p['rolling_friction']:.3f} g {p['surface_energy']:.3f} | "
              f"A {x['angle']:6.3f} deg {x['steps']:6d} steps | B {y['angle']:6.3f} deg {y['steps']:6d} steps | "
              f"{'bitwise equal' if not diff else 'DIFFERENT: ' + ', '.join(diff)}")
    equal = sum(not d for d in diffs)
    print(f"{equal} of {len(prm)} heaps bitwise equal (positions, steps, coordinate angle, creep rate, image angle)")


if __name__ == "__main__":
    main()
