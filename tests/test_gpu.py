"""The GPU engine's kernels (calib_cli.dem.gpu) against the CPU kernel: the same steps on the same
heaps give the same state. In make test they run under numba's CUDA simulator (tests/conftest.py), in
blocks of one thread run one after another (gpu.SIM_THREADS; tests/simulator_blocks.py runs them on the
launching thread), so its atomic sums come in a fixed order and the states agree bit for bit; on a GPU
(NUMBA_ENABLE_CUDASIM=0) the order varies and the compiler fuses multiply-adds, so only the tolerances
below hold."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from calib_cli.dem import gpu
from calib_cli.dem.materials import Interaction, Material
from calib_cli.dem.system import Particles, System, UnstableError, Walls
from calib_cli.errors import CalibError

R = 1.5e-3
MAT = Material(5e6, 0.25, 2600)
#: on a GPU the tolerances widen by this factor (atomic sums in varying order, fused multiply-adds): the
#: simulator checks the arithmetic, a GPU that the engine runs the same heap
LOOSE = 1.0 if gpu.SIMULATOR else 1e4
#: the stepping modes a test runs on a GPU: all. Under the simulator the persistent kernel (one thread: fast
#: there); the kernel-a-phase modes share its device functions and their own thin kernels, which the
#: collision test and every run_heaps test (conftest sets "launch" there) exercise; "graph" is "device"'s
#: launches there (no graphs), and "device" is "launch" without the host's read (30 s more a test); "blocks"
#: (a thread block a heap) for the tests that batch more than one heap, where heaps as blocks could mix
MODES = ["persistent"] if gpu.SIMULATOR else list(gpu.MODES)
MANY = ["persistent", "blocks"] if gpu.SIMULATOR else list(gpu.MODES)


@pytest.fixture(autouse=True)
def _a_thread_a_grain(monkeypatch):
    """The tests' tiny batches would get a thread a neighbour slot by the engine's own rule (``auto``): each
    test here runs a thread a grain unless it names the layout, which
    :func:`test_the_layout_is_chosen_by_the_batchs_grains` and the slot layout's own test cover."""
    monkeypatch.setenv("CALIB_GPU_CONTACTS", "grain")


def pair():
    p = Particles([[0, 0, 0.1], [2 * R - 1e-5, 1e-4, 0.1]], [R, R], vel=[[0.3, 0, 0], [-0.3, 0, 0.01]],
                  omg=[[0, 5, 0], [1, 0, 0]])
    return System(p, material=MAT, gravity=(0, 0, 0), walls=Walls(floor=False),
                  pp=Interaction(static_friction=0.5, rolling_friction=0.1))


def column(seed: int, mu: float, gamma: float = 0.0, kick: float = 0.05, precision: str = "double") -> System:
    """18 grains stacked in a 11 mm cylinder on the floor, the cylinder lifted from t = 4 ms."""
    rng = np.random.default_rng(seed)
    pts = [[2.2e-3 * np.cos(2 * np.pi * q / 3 + layer), 2.2e-3 * np.sin(2 * np.pi * q / 3 + layer), R + layer * 2.9e-3]
           for layer in range(6) for q in range(3)]
    pos = np.array(pts) + rng.uniform(-2e-4, 2e-4, (len(pts), 3))
    p = Particles(pos, rng.uniform(0.9 * R, R, len(pts)), vel=rng.normal(0, kick, pos.shape))
    grains = Interaction(static_friction=mu, rolling_friction=0.2, surface_energy=gamma, restitution=0.5)
    cylinder = Interaction(static_friction=0.3, surface_energy=gamma, restitution=0.5)
    return System(p, material=MAT, pp=grains, floor=grains, cylinder=cylinder, walls=Walls(True, 5.5e-3, 0.05, 0.004),
                  precision=precision)


def same_state(a: System, b: System, tol: float) -> None:
    for x, y in ((a.particles.pos, b.particles.pos), (a.particles.vel, b.particles.vel),
                 (a.particles.omg, b.particles.omg)):
        assert np.max(np.abs(x - y)) <= tol * np.max(np.abs(x)), np.max(np.abs(x - y))
    assert a.t == b.t and a.n_steps == b.n_steps
    # the rim is the highest grain under the cylinder: on a GPU its last bits follow the positions' (fused multiply-adds)
    assert abs(a.rim_height - b.rim_height) <= (0.0 if gpu.SIMULATOR else 1e-8) * abs(a.rim_height)


def run_both(cpu: list[System], on_gpu: list[System], steps: int, chunk: int, **batch) -> np.ndarray:
    b = gpu.Batch(on_gpu, **batch)
    for _ in range(steps // chunk):
        for s in cpu:
            s.advance(chunk)
        status = b.advance(chunk)
    b.pull()
    return status


@pytest.mark.parametrize("mode", ["persistent", "launch"] if gpu.SIMULATOR else gpu.MODES)
def test_a_collision_matches_the_cpu_kernel_to_the_last_bit(mode):
    cpu, on_gpu = pair(), pair()
    status = run_both([cpu], [on_gpu], 300, 300, mode=mode)
    assert list(status) == [gpu.OK]
    same_state(cpu, on_gpu, 1e-12 * LOOSE)
    assert np.abs(cpu.particles.omg).max() > 1.0  # the grains spun: tangential and rolling laws took part


def test_launching_every_kernel_without_the_hosts_look_steps_as_the_host_gated_launches():
    """"device" (and "graph", its launches captured) against "launch": the same kernels, the rebuild's run every
    step and skipped on the device where no heap asked; 40 steps of a column (two neighbour rebuilds)."""
    runs = {}
    for mode in ("launch", "device"):
        s = column(5, 0.4)
        b = gpu.Batch([s], mode=mode)
        b.advance(40)
        b.pull()
        runs[mode] = s
    same_state(runs["launch"], runs["device"], 1e-12 * LOOSE)


@pytest.mark.parametrize("gamma,mode", [(g, m) for g in (0.0, 0.5) for m in MANY])
def test_two_heaps_in_one_batch_match_the_cpu_kernel_heap_by_heap(gamma, mode):
    """Floor, cylinder, the lift, neighbour-list rebuilds and history carried over them: each heap of
    the batch as the CPU kernel steps it alone, with its own friction, whichever way the steps launch."""
    cpu = [column(0, 0.3, gamma), column(1, 0.7, gamma)]
    on_gpu = [column(0, 0.3, gamma), column(1, 0.7, gamma)]
    status = run_both(cpu, on_gpu, 300, 100, mode=mode)
    assert list(status) == [gpu.OK, gpu.OK]
    for a, b in zip(cpu, on_gpu):
        assert a.n_rebuilds >= 4 and a.rim_height > 0  # the lists were rebuilt and the rim rose
        same_state(a, b, 1e-9 * LOOSE)
        assert b.max_overlap == pytest.approx(a.max_overlap, rel=1e-12 * LOOSE)


@pytest.mark.parametrize("mode", MANY)
def test_neighbour_slots_that_overflow_are_grown_and_the_chunk_rerun(mode):
    cpu, on_gpu = [column(2, 0.5)], [column(2, 0.5)]
    b = gpu.Batch(on_gpu, width=1, cell_cap=1, mode=mode)
    for _ in range(2):
        cpu[0].advance(100)
        b.advance(100)
    b.pull()
    assert b.width > 1 and b.cell_cap > 1
    same_state(cpu[0], on_gpu[0], 1e-9 * LOOSE)


@pytest.mark.parametrize("mode", MANY)
def test_a_heap_that_blows_up_stops_alone(mode):
    """A heap that blows up stops, its neighbour goes on; it stops where the CPU kernel stops it: after the
    step that blew up, every grain's half kick of that step done (a grain's thread once switched the heap off
    while others of it had yet to read the switch)."""
    wild_cpu, wild = column(3, 0.5, kick=80.0), column(3, 0.5, kick=80.0)  # above the speed limit at once
    calm_cpu, calm = column(4, 0.5), column(4, 0.5)
    b = gpu.Batch([wild, calm], mode=mode)
    status = b.advance(50)
    calm_cpu.advance(50)
    with pytest.raises(UnstableError):
        wild_cpu.advance(50)
    b.pull()
    assert list(status) == [gpu.SPEED, gpu.OK] and list(b.host["active"]) == [0, 1]
    same_state(calm_cpu, calm, 1e-9 * LOOSE)
    for x, y in ((wild_cpu.particles.pos, wild.particles.pos), (wild_cpu.particles.vel, wild.particles.vel)):
        assert np.max(np.abs(x - y)) <= 1e-12 * LOOSE * np.max(np.abs(x))


def test_a_grains_tallies_fold_its_contacts_as_the_per_contact_atomics_did():
    """A grain's largest overlap (passing over a NaN, as numba's atomic maximum does) and its contact count,
    added to the heap's once: the same maximum and sum as one atomic per contact, whose order never mattered."""
    values = np.array([0.01, -0.2, 0.05, np.nan, 0.03])
    out = np.zeros(2)
    worst, cnew = np.array([0.02, 0.0]), np.zeros(2)

    @gpu.cuda.jit
    def fold(values, out, worst, cnew):
        most, count = 0.0, 0.0
        for k in range(values.shape[0]):
            most = gpu._fold(most, values[k])
            count += 1.0
        out[0], out[1] = most, count
        gpu._settle(1, 0, most, count, cnew, worst)  # 0.05 > 0.02: the heap's maximum grows
        gpu._settle(0, 0, 0.01, 0.0, cnew, worst)  # 0.01 < 0.05: nothing to add, no atomic

    fold[1, 1](values, out, worst, cnew)
    assert list(out) == [0.05, 5.0]
    assert list(worst) == [0.05, 0.0] and list(cnew) == [0.0, 5.0]


def test_a_heaps_threads_share_its_grains_between_barriers(monkeypatch):
    """The blocks mode with four threads a heap under the simulator (its tests run one): the threads stride
    over their heap's grains and meet at each phase's barrier, a rebuild on the steps their heap asks for;
    each heap still steps as the CPU kernel steps it alone."""
    monkeypatch.setattr(gpu, "SIM_BLOCK_THREADS", 4)
    cpu = [column(0, 0.3, 0.5), column(1, 0.7, 0.5)]
    on_gpu = [column(0, 0.3, 0.5), column(1, 0.7, 0.5)]
    status = run_both(cpu, on_gpu, 200, 100, mode="blocks")
    assert list(status) == [gpu.OK, gpu.OK]
    for a, b in zip(cpu, on_gpu):
        assert a.n_rebuilds >= 2
        same_state(a, b, 1e-9 * LOOSE)


def lattice(seed: int) -> System:
    """27 touching grains in a cube, jostled: each has up to three pairs j > i in contact."""
    rng = np.random.default_rng(seed)
    pos = np.array([[x, y, z] for x in range(3) for y in range(3) for z in range(3)]) * (2 * R - 2e-6) + 0.1
    p = Particles(pos, np.full(27, R), vel=rng.normal(0, 0.02, pos.shape))
    return System(p, material=MAT, gravity=(0, 0, 0), walls=Walls(floor=False),
                  pp=Interaction(static_friction=0.5, rolling_friction=0.1, surface_energy=0.3))


@pytest.mark.skipif(not gpu.SIMULATOR, reason="the window is compiled in on a GPU")
def test_pairs_marked_in_windows_give_the_one_pass_sums(monkeypatch):
    """The forces run the contact law on the pairs within reach, marked a window of slots at a time: with
    windows of one slot (each grain's pairs spread over several), a heap still steps bit for bit as the CPU
    kernel steps it."""
    monkeypatch.setattr(gpu, "WINDOW", 1)
    cpu, on_gpu = lattice(0), lattice(0)
    b = gpu.Batch([on_gpu], mode="launch")
    most = 0
    for _ in range(3):
        cpu.advance(40)
        status = b.advance(40)
        most = max(most, b.d["nnb"].copy_to_host().max())
    assert most >= 3
    b.pull()
    assert list(status) == [gpu.OK]
    same_state(cpu, on_gpu, 0.0)


@pytest.mark.parametrize("case", ["two heaps", "overflow", "lattice"])
def test_a_thread_a_neighbour_slot_steps_as_the_cpu_kernel(case):
    """The pair layout (a thread a neighbour slot, then a thread a grain for the walls) against the CPU kernel:
    two heaps with cohesion through the lift and their list rebuilds; slots and cells that overflow (the
    threads a launch grow with the slots); a lattice whose grains have several pairs each. Each grain's sums
    come in the grain layout's order (its pairs, then its walls), so under the simulator bit for bit."""
    if case == "lattice":
        cpu, on_gpu, batch, steps = [lattice(1)], [lattice(1)], {}, 40
    else:
        cpu = [column(0, 0.3, 0.5), column(1, 0.7, 0.5)][:2 if case == "two heaps" else 1]
        on_gpu = [column(0, 0.3, 0.5), column(1, 0.7, 0.5)][:len(cpu)]
        # 8 slots hold a column grain's pairs: the simulator's threads a launch are grains x slots
        batch, steps = ({"width": 1, "cell_cap": 1} if case == "overflow" else {"width": 8}), 200
    b = gpu.Batch(on_gpu, mode="launch" if gpu.SIMULATOR else "graph", contacts="pair", **batch)
    for _ in range(2):
        for s in cpu:
            s.advance(steps // 2)
        status = b.advance(steps // 2)
    b.pull()
    assert list(status) == [gpu.OK] * len(cpu)
    assert case != "overflow" or b.width > 1
    for a, g in zip(cpu, on_gpu):
        assert case == "lattice" or a.n_rebuilds >= 2
        same_state(a, g, 0.0 if gpu.SIMULATOR else 1e-9 * LOOSE)
        assert g.max_overlap == pytest.approx(a.max_overlap, rel=1e-12 * LOOSE)


def test_the_layout_is_chosen_by_the_batchs_grains(monkeypatch):
    """``auto``: a thread a slot below :data:`gpu.PAIR_BELOW_GRAINS` grains a batch (where it measured faster on
    an H200), a thread a grain from there; a named layout is kept whatever the batch."""
    monkeypatch.delenv("CALIB_GPU_CONTACTS")
    assert gpu.DEFAULT_CONTACTS == "auto"
    few, many = gpu.PAIR_BELOW_GRAINS - 1, gpu.PAIR_BELOW_GRAINS
    assert (gpu.contact_layout(None, few), gpu.contact_layout(None, many)) == ("pair", "grain")
    assert gpu.contact_layout("grain", few) == "grain" and gpu.contact_layout("pair", many) == "pair"
    assert gpu.Batch([column(0, 0.3)]).contacts == "pair"  # 18 grains
    monkeypatch.setattr(gpu, "PAIR_BELOW_GRAINS", 36)
    assert gpu.Batch([column(0, 0.3), column(1, 0.3)]).contacts == "grain"  # 36 grains
    monkeypatch.setenv("CALIB_GPU_CONTACTS", "pair")
    assert gpu.Batch([column(0, 0.3), column(1, 0.3)]).contacts == "pair"


def test_a_known_contact_layout_and_register_cap(monkeypatch):
    with pytest.raises(CalibError, match="unknown GPU contact layout 'pairs'.*auto, grain, pair"):
        gpu.Batch([column(0, 0.3)], contacts="pairs")
    for bad in ("abc", "16", "300", "-1"):
        monkeypatch.setenv("CALIB_GPU_MAXREG", bad)
        with pytest.raises(CalibError, match="CALIB_GPU_MAXREG must be a whole number of registers from 32 to 255"):
            gpu.register_cap()
    monkeypatch.setenv("CALIB_GPU_MAXREG", "96")
    assert gpu.register_cap() == (0 if gpu.SIMULATOR else 96)  # the simulator has no registers to cap
    monkeypatch.setenv("CALIB_GPU_MAXREG", "0")
    assert gpu.register_cap() == 0
    with pytest.raises(CalibError, match="from 32 to 255"):  # a batch's own cap, checked alike
        gpu.Batch([column(0, 0.3)], max_registers=16)


def test_one_composition_a_batch_and_a_known_stepping_mode(monkeypatch):
    with pytest.raises(CalibError, match="one composition"):
        gpu.Batch([column(0, 0.3), column(0, 0.3, gamma=0.5)])
    monkeypatch.setenv("CALIB_GPU_STEP", "graphs")
    with pytest.raises(CalibError, match="unknown GPU stepping mode 'graphs'.*persistent"):
        gpu.Batch([column(0, 0.3)])


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


def heap_tests_both_ways(num):
    from calib_cli.dem.heap import HeapCondition, HeapTest, run_heap

    cond = HeapCondition(6.0, 8.0, 32.0, 16.0, 1000.0)  # ~40 grains
    params = [{"static_friction": 0.5, "rolling_friction": 0.1}, {"static_friction": 0.3, "rolling_friction": 0.2}]
    cpu = [run_heap(p, cond, num, seed) for seed, p in enumerate(params)]
    on_gpu = gpu.run_heaps([HeapTest(p, cond, num, seed) for seed, p in enumerate(params)])
    for a, b in zip(cpu, on_gpu):
        assert (a.status, a.message, a.system.n_steps, a.t_settled, len(a.energy)) == \
               (b.status, b.message, b.system.n_steps, b.t_settled, len(b.energy))
        assert a.t_lift_end == b.t_lift_end or (np.isnan(a.t_lift_end) and np.isnan(b.t_lift_end))
        assert np.max(np.abs(a.system.particles.pos - b.system.particles.pos)) < 1e-9 * LOOSE
    return cpu, on_gpu


@pytest.mark.parametrize("mode", [None, "blocks"])
def test_heap_tests_run_together_as_the_cpu_engine_runs_each(mode, monkeypatch):
    """The heap protocol (settle, lift, rest) driving a batch: every phase change on the device as
    on the CPU, in the default mode and with a thread block a heap (whose heaps never wait for each
    other). Cut short (90 steps) for make test; the slow test below runs a whole short heap."""
    from calib_cli.dem.heap import Numerics

    if mode:
        monkeypatch.setenv("CALIB_GPU_STEP", mode)
    cpu, _ = heap_tests_both_ways(Numerics(time_max=0.004, settle_time_max=0.0015, rest_time_min=0.001, chunk=30))
    assert all(np.isfinite(r.t_settled) and len(r.energy) >= 3 for r in cpu)  # settled, then lifted


@pytest.mark.slow
def test_a_whole_short_heap_test_on_the_gpu_engine_as_on_the_cpu():
    """2,200 steps: settle, the lift to its end, the rest phase; the same statuses, phase times and
    coordinate angles (4 min under the simulator)."""
    from calib_cli.dem.heap import Numerics

    cpu, on_gpu = heap_tests_both_ways(Numerics(time_max=0.1, settle_time_max=0.02, rest_time_min=0.02, chunk=200))
    assert all(np.isfinite(r.t_lift_end) for r in cpu)
    assert on_gpu[1].angle.angle == pytest.approx(cpu[1].angle.angle, abs=1e-9 * LOOSE)


def test_a_campaign_on_the_gpu_engine_writes_the_rows_and_cache_the_cpu_engine_writes(tmp_path, monkeypatch):
    """simulate-heap's library call with engine="gpu": the same statuses and angles as the built-in
    engine on the same requests, rows marked gpu, heaps under their own keys, a rerun from the cache."""
    import dataclasses

    from calib_cli.dem.heap import Numerics
    from calib_cli.heaps import runner as heap_runner
    from calib_cli.stages.simulate import plan_simulation, run_simulation

    short = Numerics(time_max=0.004, settle_time_max=0.0015, rest_time_min=0.001, chunk=30)
    tiny = ["particle_d_min_mm=6", "particle_d_max_mm=8", "cylinder_diameter_mm=32", "fill_height_mm=16",
            "lift_speed_mm_s=1000"]

    def run(engine):
        plan = plan_simulation(tmp_path / engine, ["static_friction=0.4"], preset="smoke", repeats=2, condition=tiny,
                               engine=engine)
        plan.requests = [dataclasses.replace(r, numerics=short) for r in plan.requests]
        return plan, run_simulation(plan).rows.sort_values("repeat")

    _, cpu = run("builtin")
    plan, rows = run("gpu")
    assert list(rows["engine"]) == ["gpu", "gpu"] and list(rows["status"]) == list(cpu["status"])
    assert np.allclose(rows["angle_coords"], cpu["angle_coords"], atol=1e-9 * LOOSE, equal_nan=True)
    assert set(rows["run_hash"]).isdisjoint(cpu["run_hash"])  # its own cache keys
    monkeypatch.setattr(heap_runner, "_execute_on_gpu", lambda *a: pytest.fail("a cached GPU heap ran again"))
    again = run_simulation(plan).rows.sort_values("repeat")
    assert list(again["run_hash"]) == list(rows["run_hash"])


def test_simulate_heap_engine_gpu_without_a_gpu_is_a_one_line_error(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from calib_cli.cli import app

    monkeypatch.setattr(gpu, "SIMULATOR", False)
    monkeypatch.setattr(gpu.cuda, "is_available", lambda: False, raising=False)
    r = CliRunner().invoke(app, ["simulate-heap", "--run", str(tmp_path / "r"), "--preset", "smoke", "--engine", "gpu"])
    assert r.exit_code == 2 and "no usable NVIDIA GPU" in r.output, r.output
    assert not (tmp_path / "r" / "simulate").exists()


def test_a_run_directory_set_to_the_gpu_engine_simulates_every_heap_there(tmp_path):
    """``[heap] engine = "gpu"`` in a run's settings: simulate-heap (and compare, diagnose, invert
    --validate, which build their requests the same way) ask for the GPU without an option; an option
    still wins; a bad value is refused in one line."""
    from typer.testing import CliRunner

    from calib_cli.cli import app
    from calib_cli.heaps.inputs import heap_engine, run_heap_settings
    from calib_cli.stages.simulate import plan_simulation

    runner = CliRunner()
    run = tmp_path / "r"
    assert runner.invoke(app, ["init", "--run", str(run), "-s", "heap.engine=gpu"]).exit_code == 0
    assert {r.engine for r in plan_simulation(run, ["static_friction=0.4"], preset="smoke", repeats=2).requests} == {"gpu"}
    assert {r.engine for r in plan_simulation(run, ["static_friction=0.4"], preset="smoke", engine="builtin").requests} \
        == {"builtin"}
    assert run_heap_settings({"heap": {"engine": "gpu"}}) == {"engine": "gpu"}
    assert run_heap_settings({"heap": {"engine": "builtin"}}) == {}  # the locks made before keep their hashes
    with pytest.raises(CalibError, match="engine must be one of builtin, gpu"):
        heap_engine({"heap": {"engine": "cuda"}})
    r = runner.invoke(app, ["synth-lab", "--out", str(tmp_path / "lab"), "--engine", "cuda"])
    assert r.exit_code == 2 and "unknown engine 'cuda'" in r.output


def test_a_gpu_batch_checkpoints_its_heaps_and_goes_on_from_them(tmp_path):
    """run_heaps saves each unfinished heap's state (its slots turned back into the CPU kernel's pair
    list and histories); a test resumed from the last one ends where the uninterrupted one did, and
    where the CPU engine does."""
    from calib_cli.dem.heap import HeapCondition, HeapTest, Numerics, resume, run_heap

    params = {"static_friction": 0.5, "rolling_friction": 0.1, "surface_energy": 0.3}
    cond = HeapCondition(6.0, 8.0, 32.0, 16.0, 3000.0)
    num = Numerics(time_max=0.014, settle_time_max=0.006, rest_time_min=0.005, chunk=100)  # 3 chunks
    ck = tmp_path / "heap.npz"
    whole = gpu.run_heaps([HeapTest(params, cond, num, 3)], checkpoints=[ck], every=0.0)[0]
    assert ck.is_file()  # the state after the last chunk but one
    again = gpu.run_heaps([resume(HeapTest(params, cond, num, 3), ck)])[0]
    cpu = run_heap(params, cond, num, 3)
    for r in (again, cpu):
        assert np.max(np.abs(r.system.particles.pos - whole.system.particles.pos)) < 1e-12 * LOOSE
        assert (r.status, r.system.n_steps, r.t_settled, len(r.energy)) == \
               (whole.status, whole.system.n_steps, whole.t_settled, len(whole.energy))
