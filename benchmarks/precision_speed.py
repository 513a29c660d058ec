"""The CPU kernel's throughput in double and in mixed precision side by side (calib_cli.dem.system.PRECISIONS:
mixed stores velocities, spins, forces, torques and contact histories as float32): a `default` cohesive fill
(JKR, constant torque) settled for 200 steps, then 3,000 steps timed on one numba thread, each precision in
its own process, alternating, median of the repeats. Compilation happens before the timed steps.

    python benchmarks/precision_speed.py --repeats 3
"""
import argparse
import os
import statistics as st
import subprocess
import sys

CODE = r'''
import sys, time
from dataclasses import replace
from calib_cli.dem.heap import PRESETS, heap_system
pre = PRESETS["default"]
s = heap_system({"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6},
                pre.condition, replace(pre.numerics, precision=sys.argv[1]), seed=3)
s.drag = 10.0
s.advance(200)
t = time.perf_counter(); s.advance(3000); dt = time.perf_counter() - t
print(s.n * 3000 / dt)
'''


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, NUMBA_NUM_THREADS="1", PYTHONPATH=root)
    res: dict[str, list[float]] = {"double": [], "mixed": []}
    for _ in range(a.repeats):
        for precision in res:
            out = subprocess.run([sys.executable, "-c", CODE, precision], cwd=root, env=env, capture_output=True,
                                 text=True, check=True).stdout.split()[-1]
            res[precision].append(float(out))
            print(f"{precision:7} {float(out):.3g} particle-steps/s", flush=True)
    med = {k: st.median(v) for k, v in res.items()}
    print(f"median: double {med['double']:.3g}, mixed {med['mixed']:.3g} particle-steps/s; "
          f"mixed/double {med['mixed'] / med['double']:.3f}")


if __name__ == "__main__":
    main()
