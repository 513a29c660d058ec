"""The measured conditions a run's analyses read: RUN/measure/conditions.parquet, one row per condition
with its mean angle, sd, number of piles and condition variables (written by ``calib measure-angle``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from . import artifacts as art
from .errors import CalibError

CONDITIONS = Path("measure") / "conditions.parquet"


def measured_conditions(run: Path) -> pd.DataFrame:
    """Every measured condition of ``run``; refuses one without a measured angle."""
    p = Path(run) / CONDITIONS
    c = art.read_table(p, columns=["condition_id", "mean", "sd", "n"],
                       what="measured conditions (run `calib measure-angle` first)")
    if (c["n"] < 1).any():
        raise CalibError(f"condition(s) {', '.join(c.loc[c['n'] < 1, 'condition_id'])} have no measured angle")
    return c
