"""The GPU engine's kernels (calib_cli.dem.gpu) against the CPU kernel, run under numba's CUDA
simulator (every GPU thread a Python thread): the same steps on the same heaps give the same state.
The simulator runs threads one after another, so its atomic sums come in a fixed order; on a GPU the
order varies and only the last bits may differ."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from calib_cli.dem import gpu
from calib_cli.dem.materials import Interaction, Material
from calib_cli.dem.system import Particles, System, Walls
from calib_cli.errors import CalibError

R = 1.5e-3
MAT = Material(5e6, 0.25, 2600)
pytestmark = pytest.mark.skipif(not gpu.SIMULATOR, reason="runs the kernels under the simulator")


def pair():
    p = Particles([[0, 0, 0.1], [2 * R - 1e-5, 1e-4, 0.1]], [R, R], vel=[[0.3, 0, 0], [-0.3, 0, 0.01]],
                  omg=[[0, 5, 0], [1, 0, 0]])
    return System(p, material=MAT, gravity=(0, 0, 0), walls=Walls(floor=False),
                  pp=Interaction(static_friction=0.5, rolling_friction=0.1))


def column(seed: int, mu: float, gamma: float = 0.0, kick: float = 0.05) -> System:
    """18 grains stacked in a 11 mm cylinder on the floor, the cylinder lifted from t = 4 ms."""
    rng = np.random.default_rng(seed)
    pts = [[2.2e-3 * np.cos(2 * np.pi * q / 3 + layer), 2.2e-3 * np.sin(2 * np.pi * q / 3 + layer), R + layer * 2.9e-3]
           for layer in range(6) for q in range(3)]
    pos = np.array(pts) + rng.uniform(-2e-4, 2e-4, (len(pts), 3))
    p = Particles(pos, rng.uniform(0.9 * R, R, len(pts)), vel=rng.normal(0, kick, pos.shape))
    grains = Interaction(static_friction=mu, rolling_friction=0.2, surface_energy=gamma)
    return System(p, material=MAT, pp=grains, floor=grains, cylinder=Interaction(static_friction=0.3, surface_energy=gamma),
                  walls=Walls(True, 5.5e-3, 0.05, 0.004))


def same_state(a: System, b: System, tol: float) -> None:
    for x, y in ((a.particles.pos, b.particles.pos), (a.particles.vel, b.particles.vel),
                 (a.particles.omg, b.particles.omg)):
        assert np.max(np.abs(x - y)) <= tol * np.max(np.abs(x)), np.max(np.abs(x - y))
    assert a.t == b.t and a.n_steps == b.n_steps and a.rim_height == b.rim_height


def run_both(cpu: list[System], on_gpu: list[System], steps: int, chunk: int, **batch) -> np.ndarray:
    b = gpu.Batch(on_gpu, **batch)
    for _ in range(steps // chunk):
        for s in cpu:
            s.advance(chunk)
        status = b.advance(chunk)
    b.pull()
    return status


def test_a_collision_matches_the_cpu_kernel_to_the_last_bit():
    cpu, on_gpu = pair(), pair()
    status = run_both([cpu], [on_gpu], 300, 300)
    assert list(status) == [gpu.OK]
    same_state(cpu, on_gpu, 1e-12)
    assert np.abs(cpu.particles.omg).max() > 1.0  # the grains spun: tangential and rolling laws took part


@pytest.mark.parametrize("gamma", [0.0, 0.5], ids=["hertz", "jkr"])
def test_two_heaps_in_one_batch_match_the_cpu_kernel_heap_by_heap(gamma):
    """Floor, cylinder, the lift, neighbour-list rebuilds and history carried over them: each heap of
    the batch as the CPU kernel steps it alone, with its own friction."""
    cpu = [column(0, 0.3, gamma), column(1, 0.7, gamma)]
    on_gpu = [column(0, 0.3, gamma), column(1, 0.7, gamma)]
    status = run_both(cpu, on_gpu, 400, 100)
    assert list(status) == [gpu.OK, gpu.OK]
    for a, b in zip(cpu, on_gpu):
        assert a.n_rebuilds >= 5 and a.rim_height > 0  # the lists were rebuilt and the rim rose
        same_state(a, b, 1e-9)
        assert b.max_overlap == pytest.approx(a.max_overlap, rel=1e-12)


def test_neighbour_slots_that_overflow_are_grown_and_the_chunk_rerun():
    cpu, on_gpu = [column(2, 0.5)], [column(2, 0.5)]
    b = gpu.Batch(on_gpu, width=1, cell_cap=1)
    for _ in range(2):
        cpu[0].advance(100)
        b.advance(100)
    b.pull()
    assert b.width > 1 and b.cell_cap > 1
    same_state(cpu[0], on_gpu[0], 1e-9)


def test_a_heap_that_blows_up_stops_alone():
    wild = column(3, 0.5, kick=80.0)  # faster than any heap test: above the speed limit at once
    calm_cpu, calm = column(4, 0.5), column(4, 0.5)
    b = gpu.Batch([wild, calm])
    status = b.advance(50)
    calm_cpu.advance(50)
    b.pull()
    assert list(status) == [gpu.SPEED, gpu.OK] and list(b.host["active"]) == [0, 1]
    same_state(calm_cpu, calm, 1e-9)


def test_one_composition_a_batch():
    with pytest.raises(CalibError, match="one composition"):
        gpu.Batch([column(0, 0.3), column(0, 0.3, gamma=0.5)])


def test_without_a_gpu_the_engine_says_so_in_one_line(monkeypatch):
    monkeypatch.setattr(gpu, "SIMULATOR", False)
    monkeypatch.setattr(gpu.cuda, "is_available", lambda: False, raising=False)
    with pytest.raises(CalibError, match="no usable NVIDIA GPU") as e:
        gpu.cuda_module()
    assert "\n" not in str(e.value)


def test_the_kernels_compile_for_an_h100_from_the_cpu_kernels_laws():
    """PTX for compute capability 9.0 of every kernel, for four compositions (every law of every family
    at least once), by numba-cuda's compiler: no GPU needed, but numba-cuda and CUDA's NVVM are (the
    [gpu] extra); skipped without them."""
    code = ("import numba.cuda as c, sys; sys.exit(0 if getattr(c, 'implementation', '') == 'NVIDIA' else 3)")
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "0"}
    if subprocess.run([sys.executable, "-c", code], env=env).returncode != 0:
        pytest.skip("numba-cuda (the [gpu] extra) is not installed")
    r = subprocess.run([sys.executable, "benchmarks/gpu_compile.py"], env=env, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.count("sm_90 ok") == 4, r.stdout
