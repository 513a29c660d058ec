"""GPU engine throughput against batch size and stepping mode, beside the CPU kernel on every core of
the same machine, in one run.

Each batch is B heaps of the preset's fill (the paper's Table 6 centre point) in contact: up to --distinct fills
settled and lifted by the heap test's protocol on the GPU engine (benchmarks/heap_states.py; --state fresh: the
fills as poured, seeds 0..B-1, whose grains hardly touch, as timed before 2026-11-29), stepped for a warm-up
(and the kernels' compilation), then timed over --steps steps, once per stepping mode
(calib_cli.dem.gpu.MODES: a kernel a phase launched from Python with the host's look at the rebuild flag,
the same without it, those launches replayed from a CUDA graph, one persistent cooperative kernel a
chunk, one launch a chunk with a thread block a heap), each mode from the same fills; the CPU kernel
steps the same fills two ways: one after another on all its threads, and a heap per core at once (one
thread each, as a campaign's --workers run). Prints particle-steps per second, the time a step and the
ratios.

    python benchmarks/gpu_throughput.py                       # 1, 4, 16, 64, 256 default heaps; 1, 4 paper
    NUMBA_ENABLE_CUDASIM=1 python benchmarks/gpu_throughput.py --preset smoke --batches 1,3 --steps 20 \\
        --paper-batches "" --cpu-heaps 1 --cpu-workers 2 --distinct 2 --settle-on cpu \\
        --modes graph,graph+pair          # the simulator: checks the script, not a speed
"""
import argparse
import importlib
import os
import platform
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numba
import numpy as np

from calib_cli.dem import gpu
from heap_states import STATES, fresh_systems, settled_states, systems_from

_STATES: dict = {}


def systems(preset: str, count: int, precision: str = "double", state: str = "settled", distinct: int = 16,
            engine: str = "gpu"):
    """``count`` heaps of ``preset`` in ``state`` (settled: copies of up to ``distinct`` fills settled once per
    preset and precision on ``engine``, kept for the next batch)."""
    if state == "fresh":
        return fresh_systems(preset, count, precision)
    key = (preset, precision)
    if key not in _STATES:
        t = time.perf_counter()
        _STATES[key] = settled_states(preset, range(distinct), precision, engine=engine)
        print(f"{preset}: {distinct} fills settled and lifted ({engine}) in {time.perf_counter() - t:.0f} s "
              f"({precision})", flush=True)
    return systems_from(_STATES[key], preset, count, precision)


def gpu_rate(fills: list, steps: int, warmup: int, mode: str) -> tuple[float, int]:
    """``mode``: ``NAME[:T][+LAYOUT][@CAP][/mixed]``: a stepping mode, T threads a block (a heap for ``blocks``),
    the contact layout (``+pair``: a thread a neighbour slot; ``+auto``: the engine's choice by the batch's grains;
    none: a thread a grain), the force kernels' register cap (``@96``) and
    the precision (``fills`` are made in it: see :func:`precision_of`)."""
    mode = mode.partition("/")[0]
    mode, _, cap = mode.partition("@")
    mode, _, layout = mode.partition("+")
    name, _, threads = mode.partition(":")
    batch = gpu.Batch(fills, mode=name, contacts=layout or "grain", max_registers=int(cap or 0),
                      **({"block": int(threads)} if threads else {}))
    if name == "blocks" and threads and batch.heap_threads != int(threads):  # the kernel's registers allow fewer
        print(f"blocks:{threads} runs {batch.heap_threads} threads a heap, as many as the kernel's registers allow")
    batch.advance(warmup)
    t = time.perf_counter()
    status = batch.advance(steps)
    dt = time.perf_counter() - t
    n = len(batch.host["heap"])
    assert (status == gpu.OK).all(), status
    return n * steps / dt, n


def precision_of(mode: str) -> str:
    """``/mixed`` at a mode's end: velocities, spins, forces, torques and contact histories as float32."""
    return mode.partition("/")[2] or "double"


def _timed(s, steps: int, warmup: int) -> float:
    """Seconds for ``steps`` steps of system ``s`` after ``warmup`` untimed ones."""
    s.advance(warmup)
    t = time.perf_counter()
    s.advance(steps)
    return time.perf_counter() - t


def cpu_rate(fills: list, steps: int, warmup: int) -> float:
    runs = [(s.n * steps, _timed(s, steps, warmup)) for s in fills]
    return sum(w for w, _ in runs) / sum(dt for _, dt in runs)


def _one_core(preset: str, seed: int, steps: int, warmup: int, state) -> float:
    s = fresh_systems(preset, 1, first=seed)[0] if state is None else systems_from([state], preset, 1, seeds=[seed])[0]
    return s.n * steps / _timed(s, steps, warmup)


def cpu_pool_rate(preset: str, workers: int, steps: int, warmup: int, states: list | None) -> float:
    """A heap per core, one thread each, all at once (how a campaign's --workers use a machine): the sum
    of their rates."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    os.environ["NUMBA_NUM_THREADS"] = "1"  # read by each worker's numba as it starts
    try:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as ex:
            ex.submit(_one_core, "smoke", 0, 1, 1, None).result()  # not timed: the workers start and compile
            k = len(states) if states else 1
            picked = [states[w % k] if states else None for w in range(workers)]
            return sum(ex.map(_one_core, [preset] * workers, [w % k if states else w for w in range(workers)],
                              [steps] * workers, [warmup] * workers, picked))
    finally:
        os.environ.pop("NUMBA_NUM_THREADS")


def device_name() -> str:
    if gpu.SIMULATOR:
        return "numba CUDA simulator (on the CPU)"
    d = gpu.cuda_module().get_current_device()
    name = d.name.decode() if isinstance(d.name, bytes) else d.name
    return f"{name} (compute capability {d.compute_capability[0]}.{d.compute_capability[1]})"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="default")
    ap.add_argument("--batches", default="1,4,16,64,256")
    ap.add_argument("--paper-batches", default="1,4")
    ap.add_argument("--modes", default=",".join(gpu.MODES), help="stepping modes, comma-separated, each NAME[:T]"
                    "[+LAYOUT][@CAP][/mixed]: T threads a block (a heap for blocks; default 128), +pair a thread a "
                    "neighbour slot for the contacts (+auto: the engine's choice; none: a thread a grain), @CAP "
                    "the force kernels' registers a thread, /mixed float32 velocities, forces and contact histories")
    ap.add_argument("--state", choices=STATES, default="settled", help="settled: fills settled and lifted (grains "
                    "in contact, as through most of a heap test); fresh: as poured (hardly any contact)")
    ap.add_argument("--distinct", type=int, default=16, help="fills settled; a larger batch repeats them")
    ap.add_argument("--settle-on", choices=("gpu", "cpu"), default="gpu", help="the engine that settles them")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--cpu-heaps", type=int, default=2, help="heaps the CPU kernel steps for its rate")
    ap.add_argument("--cpu-workers", type=int, default=os.cpu_count(), help="heaps at once, a core each, for the "
                    "CPU's campaign rate (0: not measured)")
    a = ap.parse_args()
    print(f"GPU: {device_name()}; CPU: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"{numba.config.NUMBA_NUM_THREADS} numba threads; {a.steps} timed steps after {a.warmup}; fills {a.state}")
    runs = [(a.preset, int(b)) for b in a.batches.split(",") if b] + \
           [("paper", int(b)) for b in a.paper_batches.split(",") if b]
    presets = {a.preset, *(["paper"] if a.paper_batches else [])}
    most = {p: max([c for q, c in runs if q == p] + [a.cpu_heaps, 1]) for p in presets}

    def fill(preset: str, count: int, precision: str = "double") -> list:
        return systems(preset, count, precision, a.state, min(a.distinct, most[preset]), a.settle_on)

    cpu = {p: cpu_rate(fill(p, a.cpu_heaps), a.steps, a.warmup) for p in presets}
    pool = {p: cpu_pool_rate(p, a.cpu_workers, a.steps, a.warmup, _STATES.get((p, "double")))
            if a.cpu_workers else np.nan for p in presets}
    print("CPU 1 heap: one heap at a time on every thread; CPU per core: a heap per core at once (a campaign)")
    print(f"{'preset':8} {'heaps':>5} {'grains':>9} {'mode':>16} {'GPU p-steps/s':>14} {'a step [us]':>11} "
          f"{'CPU 1 heap':>11} {'GPU/that':>8} {'CPU per core':>12} {'GPU/that':>8}")
    for preset, count in runs:
        fills = {}  # each mode steps copies of the same fills (a batch packs their state), one set a precision
        for mode in a.modes.split(","):
            try:
                prec = precision_of(mode)
                fills.setdefault(prec, fill(preset, count, prec))
                rate, n = gpu_rate(fills[prec], a.steps, a.warmup, mode)
            except Exception as e:  # noqa: BLE001 - a mode that fails on this machine is reported, the rest go on
                print(f"{preset:8} {count:5d} {'':9} {mode:>16} FAILED {type(e).__name__}: {str(e)[:300]}", flush=True)
                continue
            print(f"{preset:8} {count:5d} {n:9d} {mode:>16} {rate:14.3g} {n / rate * 1e6:11.1f} {cpu[preset]:11.3g} "
                  f"{rate / cpu[preset]:8.1f} {pool[preset]:12.3g} {rate / pool[preset]:8.1f}", flush=True)


if __name__ == "__main__":
    main()
