"""Where a GPU step's time goes: each kernel of the per-phase modes timed alone, replayed from a CUDA graph
(so the time is the GPU's, not Python's launch), for batches of `default` heaps, beside the share of
steps on which a heap asked for a neighbour rebuild. One run prints, per batch size:

- each kernel's time a launch (and the ``pair`` contact layout's two kernels in place of ``forces``), the
  rebuild's (bin, search) as most steps run them (no heap asked: every thread returns at once, the cost of
  the graph node itself), and a rebuild of every heap;
- the share of steps with a rebuild (from a stretch of --probe steps, the host reading the flag), and
  the step's time these add up to, beside a whole step's time replayed from the engine's graph.

Each batch is B heaps in contact (copies of up to --distinct fills settled and lifted by the heap test's protocol
on the GPU engine, benchmarks/heap_states.py; --state fresh: the fills as poured, whose grains hardly touch, as
timed before 2026-11-29), stepped for --warmup steps first; each kernel's replays start from the same state (restored
on the device), no heap rebuilding. The replays leave the heaps in no physical state (the same step's forces
added --reps times): the batch is thrown away after.

    python benchmarks/gpu_kernel_times.py --batches 1,64,256 [--precisions double,mixed]
    NUMBA_ENABLE_CUDASIM=1 python benchmarks/gpu_kernel_times.py --preset smoke --batches 1 --warmup 2 \
        --probe 2 --reps 2     # the simulator (no graphs: launched one by one): checks the script, not a time
"""
import argparse
import importlib
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from calib_cli.dem import gpu
from heap_states import STATES, fresh_systems, settled_states, systems_from

GATED = {"bin_grains", "find_neighbours"}


def replayed(batch: gpu.Batch, launches: list, reps: int) -> float:
    """Seconds a replay of ``launches`` (kernel names with their thread counts), captured once ``reps`` times
    over in one graph (under the simulator, which has no graphs: launched one by one, to check the script)."""
    if gpu.SIMULATOR:
        t = time.perf_counter()
        for _ in range(reps):
            for name, threads in launches:
                batch._launch(name, threads)
        return time.perf_counter() - t
    from cuda.core import Device

    dev = Device()
    dev.set_current()
    stream = dev.create_stream()
    builder = dev.create_graph_builder()
    builder.begin_building()
    for _ in range(reps):
        for name, threads in launches:
            batch._launch(name, threads, builder)
    graph = builder.end_building().complete()
    batch.cuda.synchronize()
    graph.launch(stream)  # a first replay uploads it
    stream.sync()
    t = time.perf_counter()
    graph.launch(stream)
    stream.sync()
    return time.perf_counter() - t


def rebuild_share(batch: gpu.Batch, steps: int) -> tuple[float, float]:
    """Shares of ``steps`` steps with any heap's rebuild, and of heap-steps with one."""
    n = len(batch.host["heap"])
    anyh, heaps = 0, 0
    for _ in range(steps):
        batch._launch("kick_drift", n)
        reb = batch.d["rebuild"].copy_to_host()
        anyh += bool(reb.any())
        heaps += int((reb != 0).sum())
        batch._rebuild(n)
        batch._launch("forces", n)
        batch._launch("kick", n)
    batch.cuda.synchronize()
    return anyh / steps, heaps / (steps * len(batch.systems))


def profile(preset: str, count: int, warmup: int, probe: int, reps: int, precision: str = "double",
            states: list | None = None) -> None:
    fills = fresh_systems(preset, count, precision) if states is None else systems_from(states, preset, count, precision)
    batch = gpu.Batch(fills, mode="graph")
    batch.advance(warmup)
    n = len(batch.host["heap"])
    whole = 2 if gpu.SIMULATOR else gpu.GRAPH_STEPS * 20  # the simulator's steps take seconds
    t = time.perf_counter()
    batch.advance(whole)
    step = (time.perf_counter() - t) / whole
    share, heap_share = rebuild_share(batch, probe)
    print(f"{count} heaps, {n} grains, {precision} precision: a whole step {step * 1e6:.1f} us (graph); a rebuild "
          f"on {share:.1%} of steps ({heap_share:.1%} of heap-steps)")
    batch._keep()  # every replay starts from this state, no heap rebuilding, the cells empty

    def fresh():
        for k, v in batch._kept.items():
            batch.d[k].copy_to_device(v)
        batch._set("rebuild", np.zeros(len(fills), np.int64))
        batch._set("count", np.zeros_like(batch.host["count"]))

    off = {}
    for name in ("kick_drift", "bin_grains", "find_neighbours", "forces", "kick"):
        fresh()
        off[name] = replayed(batch, [(name, n)], reps) / reps * 1e6
        print(f"  {name:16} {off[name]:9.1f} us a launch{' (no heap rebuilding)' if name in GATED else ''}")
    # every heap rebuilding: bin, search and the forces (which empty the cells again), less the forces alone
    fresh()
    batch._set("rebuild", np.ones(len(fills), np.int64))
    trio = replayed(batch, [("bin_grains", n), ("find_neighbours", n), ("forces", n)], reps) / reps * 1e6
    # the pair layout's two kernels in place of forces (CALIB_GPU_CONTACTS=pair), from the same state
    pair = {}
    for name, threads in (("pair_forces", n * batch.width), ("wall_forces", n)):
        fresh()
        pair[name] = replayed(batch, [(name, threads)], reps) / reps * 1e6
    print(f"  {'pair layout':16} {sum(pair.values()):9.1f} us a step's contacts: pair_forces {pair['pair_forces']:.1f} "
          f"({n * batch.width} threads) + wall_forces {pair['wall_forces']:.1f}, against forces {off['forces']:.1f}")
    fresh()
    on = trio - off["forces"]
    total = sum(off.values()) + heap_share * (on - off["bin_grains"] - off["find_neighbours"])
    if not gpu.SIMULATOR:
        regs = {k: sorted(set(batch.k[k].get_regs_per_thread().values()))
                for k in ("forces", "pair_forces", "wall_forces", "find_neighbours")}
        print(f"  registers a thread: {regs}")
    print(f"  {'a rebuild':16} {on:9.1f} us for every heap's bin and search (and emptied cells)")
    print(f"  {'sum':16} {total:9.1f} us: the kernels of a step, a rebuild on {heap_share:.1%} of heaps (the graph's "
          f"whole step above)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="default")
    ap.add_argument("--batches", default="1,64,256")
    ap.add_argument("--warmup", type=int, default=300)
    ap.add_argument("--probe", type=int, default=200, help="steps the host reads the rebuild flag on")
    ap.add_argument("--reps", type=int, default=50, help="launches of a kernel a replay")
    ap.add_argument("--state", choices=STATES, default="settled")
    ap.add_argument("--distinct", type=int, default=16, help="fills settled; a larger batch repeats them")
    ap.add_argument("--settle-on", choices=("gpu", "cpu"), default="gpu", help="the engine that settles them")
    ap.add_argument("--precisions", default="double", help="comma separated, of double and mixed (float32 "
                    "velocities, spins, forces, torques and contact histories)")
    a = ap.parse_args()
    if gpu.SIMULATOR:
        print("numba's CUDA simulator: the script checked, its times are not a GPU's")
    else:
        d = gpu.cuda_module().get_current_device()
        print(f"GPU: {d.name.decode() if isinstance(d.name, bytes) else d.name}")
    states = {}
    for precision in a.precisions.split(","):
        if a.state == "settled":
            t = time.perf_counter()
            states[precision] = settled_states(a.preset, range(a.distinct), precision, engine=a.settle_on)
            print(f"{a.distinct} fills settled and lifted ({a.settle_on}, {precision}) in {time.perf_counter() - t:.0f} s")
    for b in a.batches.split(","):
        for precision in a.precisions.split(","):
            profile(a.preset, int(b), a.warmup, a.probe, a.reps, precision, states.get(precision))


if __name__ == "__main__":
    main()
