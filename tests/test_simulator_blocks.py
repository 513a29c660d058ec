"""The test suite's runner for the CUDA simulator's one-thread blocks (tests/simulator_blocks.py): the same
indices, barriers and results as the simulator's own threads, and the launching thread left as it was."""
import threading

import numpy as np
import pytest
from numba import cuda  # a global: the simulator swaps the kernels' module for its own

from calib_cli.dem import gpu

pytestmark = pytest.mark.skipif(not gpu.SIMULATOR, reason="a runner for numba's CUDA simulator")


def test_the_runner_is_installed_once():
    from numba.cuda.simulator import kernel
    from simulator_blocks import run_single_thread_blocks_inline

    assert getattr(kernel.BlockManager.run, "_inline", False)  # by conftest.py
    assert run_single_thread_blocks_inline() is False  # a second call changes nothing


@pytest.mark.parametrize("grid, block", [(7, 1), (3, 4), (1, 1)])
def test_blocks_see_their_indices_and_pass_their_barriers(grid, block):
    """Each thread writes its grid index, block and thread index after a barrier, and adds one atomically:
    a one-thread block (the runner) gives what the simulator's threads give for a block of several."""
    @cuda.jit
    def mark(out, total):
        i = cuda.grid(1)
        cuda.syncthreads()
        out[i, 0] = cuda.blockIdx.x
        out[i, 1] = cuda.threadIdx.x
        out[i, 2] = cuda.blockDim.x
        cuda.atomic.add(total, 0, 1)

    out, total = np.full((grid * block, 3), -1), np.zeros(1, np.int64)
    mark[grid, block](out, total)
    i = np.arange(grid * block)
    assert (out[:, 0] == i // block).all() and (out[:, 1] == i % block).all() and (out[:, 2] == block).all()
    assert total[0] == grid * block
    here = threading.current_thread()
    assert not any(hasattr(here, k) for k in ("blockIdx", "threadIdx", "thread_id", "syncthreads"))


def test_an_error_in_a_one_thread_block_reaches_the_launcher_and_leaves_its_thread_clean():
    @cuda.jit
    def fails(out):
        out[cuda.grid(1) + 10] = 1.0  # past the end

    with pytest.raises(IndexError):
        fails[2, 1](np.zeros(2))
    assert not hasattr(threading.current_thread(), "blockIdx")
