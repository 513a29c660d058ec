"""Local process pools: the heap campaigns' workers, and the side process a posterior's fit scores its
surrogates' held-out errors in. Spawned (numba's threading layer is not fork-safe once the parent has
used it), tied to the parent (Ctrl-C is the parent's to act on; a worker dies with it), and ended at once
on a stop."""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import os
import sys
import time


def spawn_pool(workers: int) -> cf.ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes, each tied to this one (:func:`tie_to_parent`)."""
    import multiprocessing

    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                  initializer=tie_to_parent, initargs=(os.getpid(),))


def tie_to_parent(parent: int) -> None:
    """A pool worker's start: Ctrl-C is its parent's to act on (it ends the pool), and the worker dies with
    its parent (after a kill -9 of the pid a run's lock names, workers went on writing heaps into the run
    directory outside its lock; Linux's PR_SET_PDEATHSIG, elsewhere nothing)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # 1: PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the parent died before the line above could tie this worker to it
        os._exit(1)


def end_pool(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel the queued tasks and kill the workers, not waiting for the tasks in flight."""
    workers = list((getattr(pool, "_processes", None) or {}).values())  # the executor's only handle on them
    pool.shutdown(wait=False, cancel_futures=True)
    for p in workers:
        p.kill()
    # join() returns when a worker's pipe closes, which can come a moment before the kernel lets it be reaped:
    # wait until each has an exit code, so none is left behind as a zombie that still reads as alive
    deadline = time.monotonic() + 10
    for p in workers:
        p.join(timeout=max(deadline - time.monotonic(), 0))
        while p.exitcode is None and time.monotonic() < deadline:
            time.sleep(0.01)


@contextlib.contextmanager
def spawned(workers: int):
    """A :func:`spawn_pool` for a with-block: ended at once (:func:`end_pool`) on a stop in the block (Ctrl-C,
    an error), else shut down after its tasks finish."""
    pool = spawn_pool(workers)
    try:
        yield pool
    except BaseException:
        end_pool(pool)
        raise
    pool.shutdown(wait=True)


@contextlib.contextmanager
def beside(fn, *args, spawn: bool = True):
    """Run ``fn(*args)`` in a spawned process while the with-block runs here; yields its future. A stop in
    the block (Ctrl-C, an error) ends that process at once. For work a second core can do while this one is
    busy (a posterior's held-out scores beside its chains): the same numbers as in this process, since each
    computation runs whole in one process on one thread. ``spawn`` False: ``fn`` runs here, before the
    block (one core: the caller's code reads the same either way)."""
    if not spawn:
        done: cf.Future = cf.Future()
        done.set_result(fn(*args))
        yield done
        return
    with spawned(1) as pool:
        yield pool.submit(fn, *args)
