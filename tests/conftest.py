import importlib
import os

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
from pathlib import Path

# the GPU engine's kernels run under numba's CUDA simulator unless told otherwise (CI has no GPU; on a
# machine with one, NUMBA_ENABLE_CUDASIM=0 runs tests/test_gpu.py on it). Before numba reads its config.
os.environ.setdefault("NUMBA_ENABLE_CUDASIM", "1")
if os.environ["NUMBA_ENABLE_CUDASIM"] == "1":
    # the simulator starts a Python thread per GPU thread per launch, so the default mode ("graph", which
    # there launches all five kernels every step) runs a heap test 5x slower than "launch" (9 s against 55 s
    # for the checkpoint test); tests/test_gpu.py checks every mode's states against the CPU kernel itself
    os.environ.setdefault("CALIB_GPU_STEP", "launch")
    from simulator_blocks import run_single_thread_blocks_inline

    run_single_thread_blocks_inline()
# the CLI's tables are 120 columns wide unless $COLUMNS says otherwise (xdist's workers may inherit one)
os.environ.pop("COLUMNS", None)
if os.environ.get("PYTEST_XDIST_WORKER"):
    # one core per test process, as each of a campaign's pool workers (results do not depend on threads):
    # torch's and numba's threads would otherwise spin against the other worker's
    os.environ["OMP_NUM_THREADS"] = "1"

import pandas as pd  # noqa: E402
import pytest  # noqa: E402


def pytest_configure(config):
    """In each pytest-xdist worker (``-n N``, as make test runs the suite): one numba thread. The kernel's
    law compositions compile once for all workers (calib_cli.dem.compile's lock)."""
    if hasattr(config, "workerinput"):
        import numba

        numba.set_num_threads(1)


ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "sample_data" / "paper"
SETTINGS_DIR = ROOT / "stages" / "settings"


@pytest.fixture
def paper_dir() -> Path:
    return PAPER


@pytest.fixture
def table3() -> pd.DataFrame:
    return pd.read_csv(PAPER / "table3_pb.csv")


@pytest.fixture
def table5() -> pd.DataFrame:
    return pd.read_csv(PAPER / "table5_ascent.csv")


@pytest.fixture
def table7() -> pd.DataFrame:
    return pd.read_csv(PAPER / "table7_bbd.csv")
