"""The CPU kernel's throughput in double and in mixed precision side by side (calib_cli.dem.system.PRECISIONS:
mixed stores velocities, spins, forces, torques and contact histories as float32): a `default` cohesive heap
(JKR, constant torque) in contact, settled and lifted for 0.05 s by the heap protocol (benchmarks/heap_states.py;
--state fresh: the fill after 200 steps, hardly any contact, as timed before 2026-11-29), then 3,000 steps
timed on one numba thread, each precision in its own process, alternating (which goes first swaps every
repeat), median of the repeats. Compilation happens before the timed steps.

    python benchmarks/precision_speed.py --repeats 3
"""
import argparse
import os
import statistics as st
import subprocess
import sys

CODE = r'''
import sys, time
sys.path.insert(0, "benchmarks")
from heap_states import fresh_systems, settled_states, systems_from
precision, state = sys.argv[1], sys.argv[2]
if state == "fresh":
    s = fresh_systems("default", 1, precision, first=3)[0]
    s.drag = 10.0
    s.advance(200)
else:
    s = systems_from(settled_states("default", [3], precision), "default", 1, precision, seeds=[3])[0]
t = time.perf_counter(); s.advance(3000); dt = time.perf_counter() - t
print(s.n * 3000 / dt)
'''


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--state", choices=("settled", "fresh"), default="settled")
    a = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, NUMBA_NUM_THREADS="1", PYTHONPATH=root)
    res: dict[str, list[float]] = {"double": [], "mixed": []}
    for rep in range(a.repeats):
        for precision in (list(res) if rep % 2 == 0 else list(res)[::-1]):  # the second of a pair runs slower
            out = subprocess.run([sys.executable, "-c", CODE, precision, a.state], cwd=root, env=env, capture_output=True,
                                 text=True, check=True).stdout.split()[-1]
            res[precision].append(float(out))
            print(f"{precision:7} {float(out):.3g} particle-steps/s", flush=True)
    med = {k: st.median(v) for k, v in res.items()}
    print(f"median: double {med['double']:.3g}, mixed {med['mixed']:.3g} particle-steps/s; "
          f"mixed/double {med['mixed'] / med['double']:.3f}")


if __name__ == "__main__":
    main()
