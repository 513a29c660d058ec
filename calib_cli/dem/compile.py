"""Compiling a law composition's kernel once per machine, not once per process.

numba compiles the step loop once per composition of laws (:attr:`.laws.ContactModel.spec`), 10-20 s of
one core each, and keeps the machine code in its disk cache. Processes that start together on a cold
cache (a campaign's pool workers, a test session's workers) would each compile the same composition;
here the first takes a lock file beside the cache while it compiles, the others wait for it and then
load the machine code (milliseconds).
"""

from __future__ import annotations

import contextlib
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

#: the longest a process waits for another's compile of the same composition (one takes 10-60 s) before
#: compiling it itself: a holder that was stopped (Ctrl-Z) or hangs must not stop every other process
LOCK_WAIT_S = 600.0


@contextlib.contextmanager
def _machine_lock(spec: str):
    """Held while this process compiles ``spec``: another process of this machine that asks for it waits
    here, at most LOCK_WAIT_S. Best effort: without fcntl (not POSIX) or a writable cache folder, no lock."""
    try:
        import fcntl

        folder = Path(numba.config.CACHE_DIR or tempfile.gettempdir())
        folder.mkdir(parents=True, exist_ok=True)
        handle = open(folder / f"compile-{hashlib.sha256(spec.encode()).hexdigest()[:16]}.lock", "a")
    except (ImportError, OSError):
        yield
        return
    with handle:
        deadline, held = time.monotonic() + LOCK_WAIT_S, False
        while not held:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                held = True
            except BlockingIOError:
                if time.monotonic() > deadline:
                    break
                time.sleep(0.1)
        try:
            yield
        finally:
            if held:
                fcntl.flock(handle, fcntl.LOCK_UN)


@functools.cache
def compile_composition(spec: str) -> str:
    """Compile (or load from numba's disk cache) :func:`.integrate.stepper` and :func:`.forces.forces_of` of
    ``spec`` with the argument types :class:`.system.System` calls them with, under the machine's lock
    for ``spec``; runs no step. Once per process and composition."""
    n, cap, hist = 1, 4, columns.HIST
    pos, vel, omg, force, torque, ref = (np.zeros((n, 3)) for _ in range(6))
    rad, mass, inv, ncont, cnew = np.ones(n), np.ones(n), np.ones(n), np.zeros(n), np.zeros(n)
    pi, pj, si, sj = (np.zeros(cap, np.int64) for _ in range(4))
    ht, sh, hf, hc = np.zeros((cap, hist)), np.zeros((cap, hist)), np.zeros((n, hist)), np.zeros((n, hist))
    prm, gap, geo, grav = np.zeros((3, columns.NCOL)), np.zeros(3), np.zeros(6), np.zeros(3)
    npairs, pf = np.zeros(1, np.int64), np.zeros((cap, 11))
    with _machine_lock(spec):
        stepper(spec)(0, 0.0, 1e-6, pos, vel, omg, force, torque, rad, mass, inv, pi, pj, npairs, ht, ref, 0.0, 0.0,
                      hf, hc, prm, gap, geo, float(np.inf), grav, 0.1, 50.0, si, sj, sh, ncont, cnew, pf)
        forces_of(spec)(pos, vel, omg, rad, mass, inv, pi, pj, npairs[0], ht, hf, hc, prm, gap, geo, grav, 1e-6,
                        force, torque, ncont, cnew, pf)
    return spec
