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
    """Every measured condition of ``run`` with an angle. One where every photographed pile stood as a column
    has none and is left out here (the share of columns reads it: :func:`standing_conditions`); one without
    an angle otherwise (every photograph unreadable or flagged) is refused."""
    p = Path(run) / CONDITIONS
    c = art.read_table(p, columns=["condition_id", "mean", "sd", "n"],
                       what="measured conditions (run `calib measure-angle` first)")
    _check_values(c, p)
    none = (c["n"] < 1).to_numpy()
    if none.any():
        stood = set(standing_conditions(run, c)["condition_id"])
        other = c.loc[none & ~c["condition_id"].isin(stood), "condition_id"]
        if len(other):
            raise CalibError(f"condition(s) {', '.join(other)} have no measured angle")
        if none.all():
            raise CalibError(f"every pile of every measured condition in {p} stood as a column: there is no angle "
                             "to calibrate on; measure a condition whose piles form heaps")
        c = c[~none].reset_index(drop=True)
    return c


def standing_conditions(run: Path, conds: pd.DataFrame | None = None) -> pd.DataFrame:
    """The measured conditions (``conds``: RUN/measure/conditions.parquet's rows) without an angle because every
    photographed pile stood as a column, with their piles (``piles``; a pile is its ``pile`` label, else a
    photograph): the strongest sign a fill stands there, which only the share of columns can weigh."""
    if conds is None:
        conds = art.read_table(Path(run) / CONDITIONS, columns=["condition_id", "n"], what="measured conditions")
    none = conds[conds["n"] < 1]
    path = Path(run) / "measure" / "angles.parquet"
    if none.empty or not path.is_file():
        return none.iloc[:0].assign(piles=pd.Series(dtype=float))
    a = art.read_table(path, columns=["image", "condition_id", "status"], what="measured angles")
    # every photograph measured (formed, stood, or flagged as no cone): a flagged heap is a pile that did not stand
    from .imaging.measure import FLAGS

    a = a[a["condition_id"].astype(str).isin(set(none["condition_id"].astype(str))) & a["status"].isin(("ok", *FLAGS))]
    if a.empty:
        return none.iloc[:0].assign(piles=pd.Series(dtype=float))
    per = a.assign(pile=photo_piles(a)).groupby("condition_id").agg(
        stood=("status", lambda s: bool((s == "column").all())), piles=("pile", "nunique"))
    ids = per.index[per["stood"].to_numpy(bool)].astype(str)
    out = none[none["condition_id"].astype(str).isin(set(ids))].copy()
    out["piles"] = per.loc[out["condition_id"].astype(str), "piles"].to_numpy(float)
    return out.reset_index(drop=True)


def photo_piles(angles: pd.DataFrame) -> pd.Series:
    """Each photograph's pile in an angles table, as text: its ``pile`` label, else (no such column, or a blank
    cell in a table written before labels were filled in) the photograph itself, a pile of one view."""
    if "pile" not in angles.columns:
        return angles["image"].astype(str)
    return angles["pile"].astype(object).where(angles["pile"].notna(), angles["image"]).astype(str)


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
