import os
from pathlib import Path

# the GPU engine's kernels run under numba's CUDA simulator unless told otherwise (CI has no GPU; on a
# machine with one, NUMBA_ENABLE_CUDASIM=0 runs tests/test_gpu.py on it). Before numba reads its config.
os.environ.setdefault("NUMBA_ENABLE_CUDASIM", "1")

import pandas as pd  # noqa: E402
import pytest  # noqa: E402

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
