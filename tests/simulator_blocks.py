"""numba's CUDA simulator, with a block of one thread run on the calling thread.

The simulator starts a Python thread for every GPU thread of every block, and its block manager polls
them until they end: about 0.4 ms a block on this project's machines, most of a simulated heap test's time,
since the engine launches its kernels in blocks of one thread there (``calib_cli.dem.gpu.SIM_THREADS``,
the blocks mode's ``SIM_BLOCK_THREADS``, the persistent kernel's one thread). One thread needs no
scheduling: its barriers (``syncthreads``, a grid's ``sync``) are passed as soon as reached, and the blocks
already run one after another. So such a block runs here on the thread that launched it, which carries the
block's indices while it does; a block of more threads is the simulator's own.
"""

from __future__ import annotations

import threading

_KEYS = ("blockIdx", "threadIdx", "thread_id", "syncthreads")


def run_single_thread_blocks_inline() -> bool:
    """Install the runner on the simulator's block manager; False (and nothing changed) where it is installed
    already or this numba has no simulator block manager. A manager without the attributes it reads keeps the
    simulator's threads."""
    try:
        from numba.cuda.simulator import kernel
        from numba.cuda.simulator.kernelapi import Dim3
    except ImportError:
        return False
    manager = getattr(kernel, "BlockManager", None)
    if manager is None or getattr(manager.run, "_inline", False):
        return False
    threaded = manager.run

    def run(self, grid_point, *args):
        f, dims = getattr(self, "_f", None), getattr(self, "_block_dim", None)
        if f is None or dims is None or tuple(dims) != (1, 1, 1) or getattr(self, "_debug", True):
            return threaded(self, grid_point, *args)  # not laid out as expected, or debugging: the simulator's
        here = threading.current_thread()
        saved = {k: here.__dict__[k] for k in _KEYS if k in here.__dict__}
        here.blockIdx, here.threadIdx, here.thread_id = Dim3(*grid_point), Dim3(0, 0, 0), 0
        here.syncthreads = _passed
        try:
            f(*args)
        finally:
            for k in _KEYS:
                here.__dict__.pop(k, None)
            here.__dict__.update(saved)

    run._inline = True
    manager.run = run
    return True


def _passed() -> None:
    """A barrier of one thread: nothing to wait for."""
