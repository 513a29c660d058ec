"""A law composition's kernel compiles once per machine (calib_cli.dem.compile)."""

import contextlib
import os
import subprocess
import sys
import time
from pathlib import Path

from calib_cli.dem.compile import compiled
from calib_cli.dem.forces import forces_of
from calib_cli.dem.integrate import stepper
from calib_cli.dem.laws import ContactModel
from calib_cli.dem.materials import Interaction, Material
from calib_cli.dem.system import Particles, System, Walls

ROOT = Path(__file__).resolve().parents[1]


def test_the_ahead_compile_has_the_types_a_system_calls_with():
    """After compiled(), a system of that composition (grains, floor, cylinder) adds no second machine
    code to the step or the force function: what was compiled (or loaded) is what runs."""
    spec = ContactModel(normal="jkr").spec
    compiled(spec, "forces")
    compiled(spec, "steps")
    before = len(stepper(spec).signatures), len(forces_of(spec).signatures)
    r = 2e-3
    p = Particles([[0, 0, r], [2.5 * r, 0, r]], [r, r], vel=[[0.1, 0, 0], [0, 0, 0]])
    it = Interaction(0.3, 0.1, 0.5, 0.4, 0.0, 0.0, 0.0)
    s = System(p, material=Material(5e6, 0.25, 2600.0), pp=it, floor=it, cylinder=it,
               walls=Walls(True, 0.02, 0.01, 0.0))
    assert s.model.spec == spec
    s.advance(20)
    assert min(before) >= 1  # one machine code a precision another test of this process asked for
    assert (len(stepper(spec).signatures), len(forces_of(spec).signatures)) == before


@contextlib.contextmanager
def holding(spec: str, env: dict, kernel: str = "steps"):
    """A process that holds ``spec``'s lock (as one compiling it would) until its input is written or closed;
    yields it once it holds the lock."""
    hold = ("import sys\nfrom calib_cli.dem.compile import _machine_lock\n"
            f"with _machine_lock({spec!r}, {kernel!r}):\n    print('held', flush=True)\n    sys.stdin.readline()\n")
    holder = subprocess.Popen([sys.executable, "-c", hold], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        yield holder
    finally:
        holder.stdin.close()  # the holder lets go when its input ends
        holder.wait(timeout=60)


def seconds(code: str, env: dict) -> float:
    """What a python process running ``code`` prints (a duration)."""
    return float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                                check=True).stdout)


def test_a_second_process_waits_for_the_composition_another_compiles(tmp_path):
    """While one process holds a composition's lock (compiling it), another asking for the same one waits
    until it is released (then finds the machine code in the cache instead of compiling it again); a
    different composition has a lock of its own."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}
    wait = ("import time\nfrom calib_cli.dem.compile import _machine_lock\n"
            "with _machine_lock('another-spec'):\n    pass\n"
            "print('asking', flush=True)\nt = time.perf_counter()\n"
            "with _machine_lock('a-spec'):\n    print(time.perf_counter() - t, flush=True)\n")
    with holding("a-spec", env) as holder:
        waiter = subprocess.Popen([sys.executable, "-c", wait], env=env, stdout=subprocess.PIPE, text=True)
        try:
            assert waiter.stdout.readline().strip() == "asking"  # the other composition's lock was free
            time.sleep(1.0)
            holder.stdin.write("\n")
            holder.stdin.flush()
            assert float(waiter.stdout.readline()) > 0.9  # it waited until the holder let go
        finally:
            waiter.wait(timeout=60)
    assert len(list(tmp_path.glob("compile-*.lock"))) == 2  # one lock file per composition


def test_a_holder_that_never_lets_go_delays_the_others_only_so_long(tmp_path):
    """A process stopped or hung while holding a composition's lock makes the others wait LOCK_WAIT_S at
    most; then they compile it themselves."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}
    wait = ("import time\nimport calib_cli.dem.compile as c\nc.LOCK_WAIT_S = 1.0\nt = time.perf_counter()\n"
            "with c._machine_lock('a-spec'):\n    print(time.perf_counter() - t, flush=True)\n")
    with holding("a-spec", env):
        assert 0.9 < seconds(wait, env) < 10  # it gave up waiting after LOCK_WAIT_S, the lock still held


def test_a_compiled_kernel_is_loaded_without_waiting_for_the_lock():
    """Once a kernel is marked compiled, a process loads it without the lock: a holder stuck on it (here:
    one that holds it until told) delays nobody after the first compile. The loading process is told to
    fail if it reaches for the lock at all, so the check does not depend on how long a load takes (a load
    next to two busy test workers on a fresh machine took over 120 s)."""
    from calib_cli.dem.compile import _files

    spec = ContactModel().spec
    compiled(spec, "forces")
    assert _files(spec, "forces")[1].is_file()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    load = ("import calib_cli.dem.compile as c\n"
            "def refuse(*a, **k):\n    raise SystemExit('reached for the lock')\n"
            f"c._machine_lock = refuse\nc.compiled({spec!r}, 'forces')\nprint('loaded', flush=True)\n")
    with holding(spec, env, "forces"):
        run = subprocess.run([sys.executable, "-c", load], env=env, capture_output=True, text=True, timeout=900)
    assert (run.returncode, run.stdout.strip()) == (0, "loaded"), run.stderr[-300:]


def test_a_filesystem_that_does_not_lock_compiles_without_the_lock():
    """flock failing otherwise than "held by another" (ENOLCK on some network filesystems): no wait."""
    import errno

    from calib_cli.dem.compile import _acquire

    class NoLocks:
        LOCK_EX, LOCK_NB = 2, 4

        @staticmethod
        def flock(handle, how):
            raise OSError(errno.ENOLCK, "no locks available")

    t = time.perf_counter()
    assert _acquire(NoLocks, None) is False
    assert time.perf_counter() - t < 1.0
