"""Compiling a law composition's kernels once per machine, not once per process.

numba compiles the step loop once per composition of laws (:attr:`.laws.ContactModel.spec`), 10-20 s of
one core each, and keeps the machine code in its disk cache. Processes that start together on a cold
cache (a campaign's pool workers, a test session's workers) would each compile the same composition;
here the first takes a lock file beside the cache while it compiles, the others wait for it and then
load the machine code (milliseconds). A marker beside the lock says a kernel is compiled: later
processes load it without taking the lock.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from .forces import forces_of
from .integrate import stepper
from .laws import columns

#: the longest a process waits for another's compile of the same kernel (one takes 10-60 s) before
#: compiling it itself: a holder that was stopped (Ctrl-Z) or hangs must not stop every other process
LOCK_WAIT_S = 600.0
#: the kernels of a composition: the force evaluation (every System) and the step loop (a System that steps)
KERNELS = ("forces", "steps")
_BUSY = (errno.EAGAIN, errno.EWOULDBLOCK, errno.EACCES)
#: the dtype of the state arrays (velocities, spins, forces, torques, contact histories) in each precision
#: (calib_cli.dem.system.PRECISIONS), as System allocates them and the kernels are compiled for
STATE_DTYPES = {"double": np.float64, "mixed": np.float32}


#: what a marker holds for besides its kernel: numba caches machine code per source tree (its __pycache__,
#: or a folder per source path under NUMBA_CACHE_DIR) and per numba version, while the markers of every
#: checkout on a machine share one folder: another checkout's markers sent a fresh clone's test workers
#: past the lock onto a cold cache, where both compiled the same compositions
TREE = f"{Path(__file__).resolve().parent}|{numba.__version__}"


def _files(spec: str, kernel: str, precision: str = "double") -> tuple[Path, Path]:
    """The lock file and the compiled marker of ``spec``'s ``kernel`` in ``precision`` for this source tree
    and numba (:data:`TREE`), beside numba's cache."""
    folder = Path(numba.config.CACHE_DIR or tempfile.gettempdir())
    name = f"{TREE}|{spec}|{kernel}" + ("" if precision == "double" else f"|{precision}")
    stem = f"compile-{hashlib.sha256(name.encode()).hexdigest()[:16]}"
    return folder / f"{stem}.lock", folder / f"{stem}.done"


def _acquire(fcntl, handle) -> bool:
    """Take the lock, waiting at most LOCK_WAIT_S; False where it was not taken (the wait ran out, or the
    filesystem does not lock, as some network ones)."""
    deadline = time.monotonic() + LOCK_WAIT_S
    while True:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except OSError as e:
            if e.errno not in _BUSY or time.monotonic() > deadline:
                return False
            time.sleep(0.1)


@contextlib.contextmanager
def _machine_lock(spec: str, kernel: str = "steps", precision: str = "double"):
    """Held while this process compiles ``spec``'s ``kernel``: another process of this machine that asks
    for it waits here (at most LOCK_WAIT_S). Best effort: without fcntl (not POSIX), a writable cache
    folder or a filesystem that locks, no lock."""
    try:
        import fcntl

        lock, _ = _files(spec, kernel, precision)
        lock.parent.mkdir(parents=True, exist_ok=True)
        handle = open(lock, "a")
    except (ImportError, OSError):
        yield
        return
    with handle:
        held = _acquire(fcntl, handle)
        try:
            yield
        finally:
            if held:
                fcntl.flock(handle, fcntl.LOCK_UN)


def _compile(spec: str, kernel: str, precision: str = "double") -> None:
    """Call ``spec``'s ``kernel`` once with the argument types :class:`.system.System` gives it in
    ``precision``, running no step: numba compiles it, or loads it from its disk cache."""
    n, cap, hist = 1, 4, columns.HIST
    f = STATE_DTYPES[precision]
    pos, ref = np.zeros((n, 3)), np.zeros((n, 3))
    vel, omg, force, torque = (np.zeros((n, 3), f) for _ in range(4))
    rad, mass, inv, ncont, cnew = np.ones(n), np.ones(n), np.ones(n), np.zeros(n), np.zeros(n)
    pi, pj, si, sj = (np.zeros(cap, np.int64) for _ in range(4))
    ht, sh, hf, hc = np.zeros((cap, hist), f), np.zeros((cap, hist), f), np.zeros((n, hist), f), np.zeros((n, hist), f)
    prm, gap, geo, grav = np.zeros((3, columns.NCOL)), np.zeros(3), np.zeros(6), np.zeros(3)
    npairs, pf = np.zeros(1, np.int64), np.zeros((cap, 11))
    if kernel == "forces":
        forces_of(spec)(pos, vel, omg, rad, mass, inv, pi, pj, npairs[0], ht, hf, hc, prm, gap, geo, grav, 1e-6,
                        force, torque, ncont, cnew, pf)
    else:
        stepper(spec)(0, 0.0, 1e-6, pos, vel, omg, force, torque, rad, mass, inv, pi, pj, npairs, ht, ref, 0.0, 0.0,
                      hf, hc, prm, gap, geo, float(np.inf), grav, 0.1, 50.0, si, sj, sh, ncont, cnew, pf)


@functools.cache
def compiled(spec: str, kernel: str, precision: str = "double") -> str:
    """Compile (or load from numba's disk cache) ``spec``'s ``kernel`` (:data:`KERNELS`: ``forces``,
    :func:`.forces.forces_of`; ``steps``, :func:`.integrate.stepper`) for ``precision``'s arrays
    (:data:`.system.PRECISIONS`) under the machine's lock for it, then mark it compiled. Once per process,
    kernel, composition and precision."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    done = _files(spec, kernel, precision)[1]
    if done.is_file():  # compiled by another process: a cache load, no lock to wait for
        _compile(spec, kernel, precision)
        return spec
    with _machine_lock(spec, kernel, precision):
        _compile(spec, kernel, precision)
        with contextlib.suppress(OSError):
            done.touch()
    return spec
