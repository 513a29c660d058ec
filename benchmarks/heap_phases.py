"""The CPU kernel's throughput through one heap test, phase by phase, in one run: why the throughput
benchmarks time heaps in contact (benchmarks/heap_states.py), not fresh fills.

One `default` cohesive heap (JKR, constant torque; seed 0) goes through the heap test's protocol; at the
fresh fill (after 200 steps, as the benchmarks timed it before 2026-11-29), at the end of the settle, in the
lift, at the lift's end and at rest, --steps steps are timed on this process's numba threads, beside the
listed pairs and the contacts (overlapping pairs) a grain. Prints each phase's rate and its ratio to the
fresh fill's.

    NUMBA_NUM_THREADS=1 python benchmarks/heap_phases.py [--steps 2000]
"""
import argparse
import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numba

from calib_cli.dem.heap import PRESETS, HeapTest
from heap_states import PARAMS, per_grain


def looked(tag: str, s, steps: int, rows: list) -> None:
    pairs, contacts = per_grain(s)
    t = time.perf_counter()
    s.advance(steps)
    rate = s.n * steps / (time.perf_counter() - t)
    rows.append((tag, s.t, pairs, contacts, rate))
    print(f"{tag:10} t = {s.t:6.3f} s  pairs {pairs:4.2f}  contacts {contacts:4.2f} a grain  "
          f"{rate:9.3g} particle-steps/s  {rate / rows[0][4]:5.2f}x the fresh fill's", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=2000)
    a = ap.parse_args()
    pre = PRESETS["default"]
    test = HeapTest(PARAMS, pre.condition, pre.numerics, seed=0)
    s, rows = test.system, []
    print(f"{s.n} grains, {numba.config.NUMBA_NUM_THREADS} numba threads, {a.steps} steps timed a phase")
    s.advance(200)
    looked("fresh", s, a.steps, rows)
    seen = set()
    while not test.done:
        s.advance(test.numerics.chunk)
        test.advanced()
        if test.stage == "lift" and "settled" not in seen:
            seen.add("settled")
            looked("settled", s, a.steps, rows)
        elif test.stage == "lift" and "lift" not in seen and s.t > test.t_settled + 0.25:
            seen.add("lift")
            looked("lifting", s, a.steps, rows)
        elif test.stage == "rest" and "rest" not in seen:
            seen.add("rest")
            looked("lift end", s, a.steps, rows)
    looked("at rest", s, a.steps, rows)
    later = [r[4] for r in rows[1:]]
    print(f"whole test: {s.n_steps} steps; the fresh fill steps {rows[0][4] / max(later):.1f}-"
          f"{rows[0][4] / min(later):.1f}x faster than the heap in contact")


if __name__ == "__main__":
    main()
