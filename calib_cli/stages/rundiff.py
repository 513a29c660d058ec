"""Two run directories side by side: a fresh calibration's headline numbers against a reference run's
(`make calibrate` compares its new run with the committed sample run), and why they differ where they do.

The numbers compared are what a user reads off a calibration: the measured target, the screening's
significant factors, the ascent's bracket, the BBD's fit, the chosen surrogate, the calibrated
parameters, their validation and the comparison per condition. Where they differ, the simulation
index says why: other requests (other settings or code), or the same requests with other bits
(another machine's floating point), or the same heaps and another analysis.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..heaps.index import load_results
from ..surrogate.inversion import solution_parameters
from ..errors import CalibError
from .common import checked


@dataclass
class RunDiff:
    """The headline numbers of ``run`` and ``reference`` side by side (``table``: quantity, this run,
    reference, same) and why they differ (``reasons``); ``same`` when every number agrees to ``rtol``."""

    run: Path
    reference: Path
    table: pd.DataFrame
    reasons: list[str] = field(default_factory=list)

    @property
    def same(self) -> bool:
        return bool((self.table["same"] == "yes").all()) if len(self.table) else False

    def summary(self) -> pd.DataFrame:
        return self.table


def _read(run: Path, table: str) -> pd.DataFrame | None:
    path = run / table
    if not path.is_file():
        return None
    try:  # as it is on disk (a table edited by hand is compared too); an unreadable one was exit 70
        return pd.read_parquet(path)
    except Exception as e:  # pyarrow raises several types for a corrupt file
        raise CalibError(f"{path} is not a readable Parquet file ({type(e).__name__}): rerun the command that "
                         "writes it") from None


def _measured(run: Path) -> dict[str, tuple]:
    df = _read(run, "measure/conditions.parquet")
    return {} if df is None else {f"measured angle, {r.condition_id} [deg]": (r.mean, r.sd)
                                  for r in df.itertuples()}


def _screening(run: Path) -> dict[str, tuple]:
    df = _read(run, "pb/effects.parquet")
    if df is None:
        return {}
    return {"screening: significant factors": (", ".join(df.loc[df["significant"], "factor"]) or "none",),
            **{f"screening effect, {r.factor} [deg]": (r.effect,) for r in df.itertuples()}}


def _bracket(run: Path) -> dict[str, tuple]:
    df = _read(run, "ascent/bracket.parquet")
    return {} if df is None else {f"ascent bracket, {r.factor}": (r.low, r.high) for r in df.itertuples()}


def _fits(run: Path) -> dict[str, tuple]:
    out = {}
    bbd = _read(run, "bbd/fit.parquet")
    if bbd is not None:
        out["BBD surface R2, R2 predicted"] = (bbd["r2"].iloc[0], bbd["r2_pred"].iloc[0])
    m = _read(run, "surrogate/metrics.parquet")
    try:
        best = json.loads((run / "surrogate" / "best.json").read_text())["best"]
    except (OSError, ValueError, KeyError, TypeError):  # TypeError: a JSON list, not the object calib writes
        best = None
    if m is not None and isinstance(best, str):  # a model's name; anything else is a file edited by hand
        loo = m[(m["model"] == best) & (m["split"] == "loo")]["r2"]
        out["surrogate chosen, its leave-one-out R2"] = (best, float(loo.iloc[0]) if len(loo) else np.nan)
    return out


def _calibrated(run: Path) -> dict[str, tuple]:
    df = _read(run, "invert/solution.parquet")
    if df is None:
        return {}
    r = df.iloc[0]
    out = {f"calibrated {c}": (r[c],) for c in solution_parameters(df)}
    if "predicted_angle" in df.columns:
        out["surrogate's angle at it [deg]"] = (r["predicted_angle"],)
    v = _read(run, "invert/validation.parquet")
    if v is not None and len(v):
        last = v[v["round"] == v["round"].max()]["repose_angle"]
        out["validation heaps, last round: mean, sd [deg]"] = (last.mean(), last.std())
    return out


def _compared(run: Path) -> dict[str, tuple]:
    df = _read(run, "compare/residuals.parquet")
    return {} if df is None else {f"compare, {r.condition_id}: simulated [deg], z": (r.simulated, r.z)
                                  for r in df.itertuples()}


#: the headline numbers of a run, in the order a calibration makes them
HEADLINES = (_measured, _screening, _bracket, _fits, _calibrated, _compared)


def _text(vals: tuple | None) -> str:
    if vals is None:
        return "-"
    return ", ".join(f"{v:.4g}" if isinstance(v, (float, np.floating)) else str(v) for v in vals)


def _same(a: tuple | None, b: tuple | None, rtol: float) -> bool:
    if a is None or b is None or len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if isinstance(x, str) or isinstance(y, str):
            if x != y:
                return False
        elif not np.isclose(float(x), float(y), rtol=rtol, atol=1e-12, equal_nan=True):
            return False
    return True


def _headline(headline, run: Path, problems: list[str]) -> dict[str, tuple]:
    """One headline's numbers; a table without the columns or rows it needs (written by hand, or by
    another version) leaves that headline out and says so."""
    try:
        return headline(run)
    except (KeyError, IndexError, AttributeError, TypeError, ValueError) as e:
        problems.append(f"{run}: {headline.__name__.strip('_')} left out, its table is not as expected "
                        f"({type(e).__name__}: {e})")
        return {}


def _headline_rows(run: Path, reference: Path, rtol: float, problems: list[str]) -> list[dict]:
    rows = []
    for headline in HEADLINES:
        new, ref = _headline(headline, run, problems), _headline(headline, reference, problems)
        for key in dict.fromkeys([*ref, *new]):
            a, b = new.get(key), ref.get(key)
            rows.append({"quantity": key, "this run": _text(a), "reference": _text(b),
                         "same": "yes" if _same(a, b, rtol) else "NO"})
    return rows


def _heap_reasons(run: Path, reference: Path) -> list[str]:
    """Why the simulated heaps differ, from the two simulation indexes."""
    new, ref = load_results(run), load_results(reference)
    if new.empty or ref.empty or not {"run_hash", "repose_angle"} <= set(new.columns) & set(ref.columns):
        return []
    ref_by_hash = ref.drop_duplicates("run_hash").set_index("run_hash")
    shared = new[new["run_hash"].isin(ref_by_hash.index)].drop_duplicates("run_hash")
    other = len(set(new["run_hash"])) - len(shared)
    out = []
    if other:
        out.append(f"{other} of this run's {new['run_hash'].nunique()} heaps are other requests than the reference's "
                   "(other settings, data or physics versions): their angles are new draws")
    if len(shared):
        a = shared.set_index("run_hash")["repose_angle"]
        b = ref_by_hash.loc[a.index, "repose_angle"]
        differ = int((~np.isclose(a, b, rtol=0, atol=0, equal_nan=True)).sum())
        hosts = sorted(set(shared.get("host", pd.Series(dtype=object)).dropna())
                       | set(ref_by_hash.loc[a.index].get("host", pd.Series(dtype=object)).dropna()))
        out.append(f"{len(shared) - differ} of {len(shared)} shared heaps came out bit for bit as in the reference"
                   + (f"; {differ} did not (hosts: {', '.join(hosts)})" if differ else ""))
    return out


def _is_run(p: Path) -> bool:
    """A folder some command wrote as a run: its settings, or a stage's lock."""
    return (p / "settings.toml").is_file() or any(p.glob("*/*.lock.json")) or any(p.glob("*.lock.json"))


@checked
def diff_runs(run: Path, reference: Path, rtol: float = 1e-6) -> RunDiff:
    """The headline numbers of ``run`` against ``reference``'s and, where they differ, why."""
    run, reference = Path(run), Path(reference)
    if not (np.isfinite(rtol) and rtol >= 0):  # a negative one calls every number different, inf none
        raise CalibError(f"--rtol must be a finite number of at least 0, got {rtol:g}")
    for p in (run, reference):
        if not p.is_dir():
            raise CalibError(f"no run directory {p}")
        if not _is_run(p):
            raise CalibError(f"{p} is not a run directory (no settings.toml and no stage lock in it)")
    problems: list[str] = []
    table = pd.DataFrame(_headline_rows(run, reference, rtol, problems),
                         columns=["quantity", "this run", "reference", "same"])
    reasons = _heap_reasons(run, reference)
    heaps_equal = any("shared heaps came out" in r for r in reasons) and \
        not any("did not" in r or "other requests" in r for r in reasons)
    if len(table) and not (table["same"] == "yes").all() and heaps_equal:
        reasons.append("the heaps are the reference's, so the analysis differs: the analysis code or its "
                       "settings changed since the reference was made")
    return RunDiff(run, reference, table, problems + reasons)
