from pathlib import Path

import pandas as pd
import pytest

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
