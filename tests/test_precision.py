"""Mixed precision (calib_cli.dem.system.PRECISIONS): velocities, spins, forces, torques and contact
histories stored as float32, positions float64: what the arrays hold, momentum, the heap keys and compile
markers it leaves alone, and the GPU engine's batch in mixed precision against the CPU kernel's. The kernel
in mixed precision against analytic results (restitution, JKR zero-load overlap, a sphere on an incline) is
in tests/test_dem_physics.py, beside double's."""

import dataclasses

import numpy as np
import pytest

from calib_cli.dem import gpu
from calib_cli.dem.heap import Numerics, get_preset, run_key
from calib_cli.errors import CalibError
from test_dem_physics import pair
from test_gpu import column


def cohesive(seed: int, precision: str):
    """test_gpu's column of 18 grains, cohesive (0.5 J/m2), friction 0.4, in ``precision``."""
    return column(seed, 0.4, 0.5, precision=precision)


def test_mixed_precision_stores_the_state_as_float32_and_the_positions_as_float64():
    s = pair(precision="mixed")
    for a in (s.particles.vel, s.particles.omg, s.force, s.torque, s.ht, s.spare_h, s.hf, s.hc):
        assert a.dtype == np.float32
    assert s.particles.pos.dtype == s.mass.dtype == s.prm.dtype == np.float64
    s._alloc(2 * len(s.pi), keep=int(s.npairs[0]))  # grown lists keep the precision
    assert s.ht.dtype == s.spare_h.dtype == np.float32
    assert pair(precision="double").ht.dtype == np.float64
    with pytest.raises(CalibError, match="precision must be one of double, mixed"):
        pair(precision="single")


def test_a_collision_keeps_its_momentum_to_float32s_resolution():
    """A pair's forces are equal and opposite in float64; each grain's sum is stored rounded to float32."""
    s = pair(e=0.5, mu=0.5, v=0.3, precision="mixed")
    P0 = (s.mass[:, None] * s.particles.vel).sum(0)
    s.advance(int(1.5e-3 / s.dt))
    P = (s.mass[:, None] * s.particles.vel).sum(0)
    scale = s.mass[0] * 0.3
    assert np.abs(P - P0).max() <= 1e-6 * scale


def test_the_heap_keys_of_double_precision_are_those_made_before_the_choice():
    pre = get_preset("smoke")
    key = run_key({"static_friction": 0.5}, pre.condition, pre.numerics, 0)
    assert "precision" not in key["numerics"]
    mixed = run_key({"static_friction": 0.5}, pre.condition, dataclasses.replace(pre.numerics, precision="mixed"), 0)
    assert mixed["numerics"]["precision"] == "mixed"
    assert {k: v for k, v in mixed["numerics"].items() if k != "precision"} == key["numerics"]
    assert Numerics().precision == "double"


def test_a_gpu_batch_in_mixed_precision_steps_as_the_cpu_kernel_in_mixed_precision():
    """The same arrays and laws: under the simulator a float32 times a constant is float32 arithmetic (numpy's
    rule), where compiled code computes it in float64 and rounds the store, so the two agree to float32's
    resolution, not bit for bit: over 300 steps (lift, rebuilds) within 1e-7 of the positions' scale (1.5e-9
    measured), where double against mixed precision differ by 3e-7. On a GPU (fused multiply-adds, atomic
    sums in varying order) within 1e-5."""
    tol = 1e-7 if gpu.SIMULATOR else 1e-5
    cpu, on_gpu, double = cohesive(0, "mixed"), cohesive(0, "mixed"), cohesive(0, "double")
    b = gpu.Batch([on_gpu], mode="persistent" if gpu.SIMULATOR else None)
    assert b.d["hist"].dtype == b.d["vel"].dtype == np.float32 and b.d["pos"].dtype == np.float64
    for _ in range(3):
        cpu.advance(100)
        assert list(b.advance(100)) == [gpu.OK]
    b.pull()
    double.advance(300)
    assert cpu.n_rebuilds >= 2 and cpu.rim_height > 0
    scale = np.abs(cpu.particles.pos).max()
    assert np.abs(cpu.particles.pos - on_gpu.particles.pos).max() <= tol * scale
    if gpu.SIMULATOR:  # the check tells the precisions apart
        assert np.abs(cpu.particles.pos - double.particles.pos).max() > tol * scale
    assert on_gpu.particles.vel.dtype == np.float32


def test_a_batch_of_one_precision():
    with pytest.raises(CalibError, match="one precision"):
        gpu.Batch([cohesive(0, "mixed"), cohesive(1, "double")])


def test_each_precision_compiles_under_its_own_marker(monkeypatch):
    """A process that finds double's kernel compiled must not take it for mixed's (it would compile that
    outside the machine's lock); nor one checkout's or numba's for another's, whose cache is its own."""
    from calib_cli.dem import compile as kernels
    from calib_cli.dem.laws import ContactModel

    spec = ContactModel().spec
    here = kernels._files(spec, "steps")
    assert kernels._files(spec, "steps", "mixed") != here
    monkeypatch.setattr(kernels, "TREE", "/another/clone/calib_cli/dem|0.61.0")
    assert kernels._files(spec, "steps") != here


def test_a_run_set_to_mixed_precision_simulates_every_heap_there_in_it(tmp_path):
    """``[heap] precision = "mixed"`` in a run's settings: simulate-heap (and calibrate, compare, diagnose,
    invert --validate, which take their presets from heap_preset the same way) steps every heap in mixed
    precision under its own keys, the rows say so, a row rebuilds its request; a bad value and LAMMPS are
    refused in one line."""
    from typer.testing import CliRunner

    from calib_cli.cli import app
    from calib_cli.heaps.inputs import heap_precision, request_from_row, run_heap_settings
    from calib_cli.stages.simulate import plan_simulation, run_simulation

    runner = CliRunner()
    run, plain = tmp_path / "mixed", tmp_path / "double"
    assert runner.invoke(app, ["init", "--run", str(run), "-s", "heap.precision=mixed"]).exit_code == 0
    short = Numerics(time_max=0.004, settle_time_max=0.0015, rest_time_min=0.001, chunk=30)
    tiny = ["particle_d_min_mm=6", "particle_d_max_mm=8", "cylinder_diameter_mm=32", "fill_height_mm=16",
            "lift_speed_mm_s=1000"]
    said = []
    plan = plan_simulation(run, ["static_friction=0.4"], preset="smoke", condition=tiny, say=said.append)
    assert {r.numerics.precision for r in plan.requests} == {"mixed"} and "mixed precision" in said[0]
    other = plan_simulation(plain, ["static_friction=0.4"], preset="smoke", condition=tiny)
    assert {r.hash for r in plan.requests}.isdisjoint(r.hash for r in other.requests)  # heaps of their own
    plan.requests = [dataclasses.replace(r, numerics=dataclasses.replace(short, precision="mixed"))
                     for r in plan.requests]
    rows = run_simulation(plan).rows
    assert list(rows["precision"]) == ["mixed"]
    assert request_from_row(rows.iloc[0]).numerics.precision == "mixed"
    mixed = {"heap": {"engine": "builtin", "precision": "mixed"}}
    assert run_heap_settings(mixed) == {"precision": "mixed"}
    assert run_heap_settings({"heap": {"engine": "builtin", "precision": "double"}}) == {}  # locks keep their hashes
    assert run_heap_settings(mixed, "gpu") == {"engine": "gpu", "precision": "mixed"}  # calibrate --engine gpu
    for refused in (lambda: heap_precision({"heap": {"precision": "mixed"}}, "lammps"),
                    lambda: run_heap_settings(mixed, "lammps")):  # calibrate --engine lammps on a mixed run
        with pytest.raises(CalibError, match="LAMMPS computes in double precision"):
            refused()
    r = runner.invoke(app, ["init", "--run", str(tmp_path / "bad"), "-s", "heap.precision=single"])
    assert r.exit_code == 2 and "heap.precision = 'single'" in r.output and "double, mixed" in r.output, r.output
