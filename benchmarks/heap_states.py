"""Heaps in contact, the state the throughput benchmarks time (imported by them; not a script).

A fresh fill is a loose lattice whose grains fall for the first few thousand of a `default` heap test's
~110,000 steps: after 200 steps it lists 0.55 pairs a grain and touches none, where the rest of the test
(settled, lifting, at rest) lists 2.6-3.0 and touches 1.8-1.9. The CPU kernel steps that fresh fill 4.6-5.0
times faster a particle-step than any later state (benchmarks/heap_phases.py, 2026-11-29, one thread: 1.79e7
against 3.56-3.88e6), so a rate timed on it is not a heap's. Here each fill goes through the heap test's own
protocol (:class:`calib_cli.dem.heap.HeapTest`: settle with the drag until the grains rest, then lift) for
``lift`` seconds of the lift, on the CPU kernel or the GPU engine; a batch larger than the fills settled is
made of copies of them.

    states = settled_states("default", seeds=range(4), engine="cpu")
    systems = systems_from(states, "default", count=16)     # 16 heaps, each a copy of one of the 4
"""
from __future__ import annotations

from dataclasses import replace
import importlib

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from calib_cli.dem.heap import PRESETS, HeapTest

PARAMS = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}
#: s of lift after the settle: the grains start to flow out of the cylinder
LIFT = 0.05
STATES = ("settled", "fresh")


def per_grain(s) -> tuple[float, float]:
    """System ``s``'s listed pairs and contacts (listed pairs whose spheres overlap), each a grain."""
    n = int(s.npairs[0])
    i, j = s.pi[:n], s.pj[:n]
    p, r = s.particles.pos, s.particles.rad
    return n / s.n, float((np.linalg.norm(p[i] - p[j], axis=1) < r[i] + r[j]).sum()) / s.n


def _tests(preset: str, seeds, precision: str) -> list[HeapTest]:
    pre = PRESETS[preset]
    return [HeapTest(PARAMS, pre.condition, replace(pre.numerics, precision=precision), seed) for seed in seeds]


def _lifted(t: HeapTest, lift: float) -> bool:
    return t.done or (t.stage != "settle" and t.system.t >= t.t_settled + lift)


def _settle_cpu(tests: list, lift: float) -> None:
    for t in tests:
        while not _lifted(t, lift):
            t.system.advance(t.numerics.chunk)
            t.advanced()


def _settle_gpu(tests: list, lift: float) -> None:
    """The GPU engine's own chunk loop (:func:`calib_cli.dem.gpu.run_heaps`), each heap stopped once lifted."""
    from calib_cli.dem import gpu

    batch = gpu.Batch([t.system for t in tests])
    going = [not _lifted(t, lift) for t in tests]
    for h, g in enumerate(going):
        if not g:
            batch.stop(h)
    while any(going):
        status = batch.advance(tests[0].numerics.chunk)
        if (status[going] != gpu.OK).any():
            raise RuntimeError(f"a heap blew up while settling (statuses {status.tolist()})")
        batch.pull()
        for h, t in enumerate(tests):
            if going[h]:
                t.advanced()
                if _lifted(t, lift):
                    going[h] = False
                    batch.stop(h)
        batch.push_walls()
    batch.pull(lists=True)


def settled_states(preset: str, seeds, precision: str = "double", engine: str = "cpu",
                   lift: float = LIFT) -> list[dict]:
    """Each seed's fill of ``preset`` settled and lifted for ``lift`` s (``engine``: ``cpu`` or ``gpu``), as
    :meth:`HeapTest.state` gives it (a checkpoint: every array the kernels step from)."""
    tests = _tests(preset, list(seeds), precision)
    (_settle_gpu if engine == "gpu" else _settle_cpu)(tests, lift)
    return [t.state() for t in tests]


def systems_from(states: list[dict], preset: str, count: int, precision: str = "double", seeds=None) -> list:
    """``count`` systems, the h-th restored from ``states[h % len(states)]`` (made from ``seeds``, by default
    0, 1, ...), each its own arrays."""
    seeds = list(range(len(states))) if seeds is None else list(seeds)
    k = len(states)
    return [_tests(preset, [seeds[h % k]], precision)[0].restore(states[h % k]).system for h in range(count)]


def fresh_systems(preset: str, count: int, precision: str = "double", first: int = 0) -> list:
    """``count`` fresh fills (seeds ``first``, ``first`` + 1, ...), as the benchmarks timed them before
    2026-11-29."""
    return [t.system for t in _tests(preset, range(first, first + count), precision)]
