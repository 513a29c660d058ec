"""The measured conditions a run's analyses read: RUN/measure/conditions.parquet, one row per condition
with its mean angle, sd, number of piles and condition variables (written by ``calib measure-angle``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from . import artifacts as art
from .errors import CalibError

CONDITIONS = Path("measure") / "conditions.parquet"


def measured_conditions(run: Path) -> pd.DataFrame:
    """Every measured condition of ``run``; refuses one without a measured angle."""
    p = Path(run) / CONDITIONS
    c = art.read_table(p, columns=["condition_id", "mean", "sd", "n"],
                       what="measured conditions (run `calib measure-angle` first)")
    _check_values(c, p)
    if (c["n"] < 1).any():
        raise CalibError(f"condition(s) {', '.join(c.loc[c['n'] < 1, 'condition_id'])} have no measured angle")
    return c


def _check_values(c: pd.DataFrame, p: Path) -> None:
    """Each condition named, its mean angle in (0, 90) deg, its sd >= 0 (empty for one pile) and its piles a
    count: a table edited by hand (its stage lock gone) met the posterior as NaN or text, an internal error."""
    from pandas.api.types import is_numeric_dtype

    text = [k for k in ("mean", "sd", "n") if not is_numeric_dtype(c[k])]
    if text:
        raise CalibError(f"measured conditions {p}: column(s) {', '.join(text)} hold text where numbers belong")
    if c["condition_id"].isna().any() or not c["condition_id"].map(lambda v: isinstance(v, str) and v != "").all():
        raise CalibError(f"measured conditions {p}: every condition needs a condition_id")
    n, mean, sd = (c[k].to_numpy(float) for k in ("n", "mean", "sd"))
    measured = n >= 1  # n 0: every photograph of the condition flagged (measure-angle writes it; refused below)
    bad = ~np.isfinite(n) | (n != np.round(n)) | (measured & (~((mean > 0) & (mean < 90)) | (sd < 0)
                                                             | np.isinf(sd) | (np.isnan(sd) & (n > 1))))
    if bad.any():
        r = c[bad].iloc[0]
        raise CalibError(f"measured conditions {p}: condition {r['condition_id']} has mean {r['mean']:g} deg, "
                         f"sd {r['sd']:g}, n {r['n']:g}: a mean angle in (0, 90) deg, an sd >= 0 and a whole number "
                         "of piles are needed (`calib measure-angle` writes them)")
