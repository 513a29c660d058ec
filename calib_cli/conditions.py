"""A conditions table as a user writes it (CSV: a row per photograph or per condition, a condition_id
and the rig's variables), read and checked where it enters: by ``measure-angle --conditions`` and
``simulate-heap --conditions`` alike (docs/artefacts.md, 'Conditions table')."""

from __future__ import annotations

import difflib
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import CalibError, reason
from .parameters import CONDITION_VARIABLES, check, check_rig

#: the columns a conditions table may have beside free ones (notes, dates): a column close to one of
#: these but not one is a typo, whose values would silently be dropped
KNOWN = ("image", "condition_id", "floor", *CONDITION_VARIABLES)


def outside_range(values, lo: float, hi: float) -> np.ndarray:
    """Where condition variable ``values`` lie beyond ``[lo, hi]``, a range some heaps or a surrogate's
    training spanned: by more than 1e-9 of the range (at least 1e-9), the noise of a value written
    and read back, or NaN, a value no range places. The one test that `invert`, `suggest-conditions`
    and the posterior's evidence apply before trusting a surrogate at a condition."""
    x = np.asarray(values, dtype=float)
    tol = 1e-9 * max(abs(hi - lo), 1.0)
    with np.errstate(invalid="ignore"):
        return ~((x >= lo - tol) & (x <= hi + tol))


def read_conditions_csv(path: Path, need: tuple[str, ...] = ("condition_id",), what: str = "conditions file") -> pd.DataFrame:
    """The table at ``path``, or a one-line error: missing or unreadable file, another delimiter than
    the comma, a lacking column, a column name that is a typo of a known one, an empty condition_id,
    a rig value that is not a number or not plausible (:func:`calib_cli.parameters.check`), one
    condition with two values of a variable."""
    path = Path(path)
    if not path.is_file():
        raise CalibError(f"{what} not found: {path}")
    try:
        df = pd.read_csv(path, comment="#", dtype={"condition_id": str, "image": str, "floor": str})
    except Exception as e:  # pandas raises several types for a file that is not CSV
        raise CalibError(f"{what} {path} could not be read as CSV ({reason(e)})") from None
    df.columns = [str(c).strip() for c in df.columns]
    _delimiter(df, path, what)
    return check_conditions(df, path, need, what)


def check_conditions(df: pd.DataFrame, path: Path, need: tuple[str, ...] = ("condition_id",),
                     what: str = "conditions table") -> pd.DataFrame:
    """A conditions table's checks, whatever file it came from (:func:`read_conditions_csv`'s; a Parquet table
    once skipped them and ran heaps under a misspelt column's or a NaN fill's default): its columns, names,
    condition ids, values, one value each and rigs."""
    df = df.copy()
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise CalibError(f"{what} {path} lacks column(s) {', '.join(missing)} (its columns: {', '.join(df.columns)}; "
                         "docs/artefacts.md lists them)")
    _typos(df, path, what)
    if df.empty:
        raise CalibError(f"{what} {path} has no rows")
    df["condition_id"] = condition_ids(df, path, what)
    for c in CONDITION_VARIABLES:
        if c in df.columns:
            df[c] = _numbers(df, c, path, what)
    _one_value_each(df, path, what)
    _rigs(df, path, what)
    return df


def _rigs(df: pd.DataFrame, path: Path, what: str) -> None:
    """Each condition's sizes against each other, as a simulated heap's are (8 mm grains in a 5 mm cylinder
    are a typo, whichever column holds it)."""
    if not {"particle_d_min_mm", "particle_d_max_mm"} <= set(df.columns):
        return
    first = df.drop_duplicates("condition_id")
    for i, r in first.iterrows():
        check_rig(r["particle_d_min_mm"], r["particle_d_max_mm"], r.get("cylinder_diameter_mm"), r.get("fill_height_mm"),
                  f"{what} {path}, condition {r['condition_id']} on line {int(i) + 2}")


def condition_ids(df: pd.DataFrame, path: Path, what: str) -> pd.Series:
    """A table's condition_id column as text, stripped; one line naming the rows where it is empty."""
    ids = df["condition_id"].astype("string").str.strip()
    if ids.isna().any() or (ids == "").any():
        rows = np.flatnonzero(ids.isna() | (ids == "")) + 2  # the header is line 1
        raise CalibError(f"{what} {path}: condition_id is empty on line(s) {', '.join(map(str, rows[:5]))}: "
                         "every row needs its condition")
    return ids.astype(str)


def _delimiter(df: pd.DataFrame, path: Path, what: str) -> None:
    if len(df.columns) == 1:
        for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars")):
            if sep in df.columns[0]:
                raise CalibError(f"{what} {path} separates its columns with {name}: save it with commas")


def _typos(df: pd.DataFrame, path: Path, what: str) -> None:
    for c in df.columns:
        if c not in KNOWN:
            close = difflib.get_close_matches(c, KNOWN, n=1, cutoff=0.8)
            if close:
                raise CalibError(f"{what} {path}: column {c!r} is not a known one: did you mean {close[0]}? "
                                 "(its values would be ignored)")


def _numbers(df: pd.DataFrame, c: str, path: Path, what: str) -> pd.Series:
    v = pd.to_numeric(df[c], errors="coerce")
    bad = ~np.isfinite(v)  # a floor's value too: every condition gives it, or the column is left out
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raw = df[c].iloc[i]
        shown = "empty or NaN" if pd.isna(raw) else repr(str(raw))
        raise CalibError(f"{what} {path}: column {c} has a missing or non-numeric value on line {i + 2} ({shown})")
    for i, x in enumerate(v):
        check(c, x, f"{what} line {i + 2}")
    return v


def _one_value_each(df: pd.DataFrame, path: Path, what: str) -> None:
    """Every row of one condition gives it the same rig (else the first row would silently win)."""
    for c in (*CONDITION_VARIABLES, "floor"):
        if c in df.columns:
            n = df.groupby("condition_id")[c].nunique(dropna=False)
            if (n > 1).any():
                cid = n.index[n > 1][0]
                vals = sorted(map(str, df.loc[df["condition_id"] == cid, c].unique()))
                raise CalibError(f"{what} {path}: condition {cid} has {c} {' and '.join(vals[:3])} on different rows: "
                                 "one condition is one rig (give the rows their own condition_id)")
