"""Compare the calibrated model with the measurements, condition by condition (residuals in units of
the combined uncertainty, RMSE, chi2/dof), and keep the error of every model revision."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import pandas as pd

from .. import artifacts as art
from ..heaps.keys import CACHE_SOURCE
from ..discrepancy.point import (MEASURED_SEEDINGS, check_seeding, fitted_parameters, model_and_theta, run_seeding,
                                 seeding_settings, simulate_at)
from ..discrepancy.stats import residual_table, summary
from ..measurements import measured_conditions
from ..model import Model
from ..plots import history_figure, residuals_figure
from ..heaps.inputs import COND_VARS, Pairs, heap_setup, modulus_settings, run_heap_settings
from .common import (Result, Say, check_not_empty, check_run_dir, plain, resolve_settings, stage, warn_other_modulus,
                     writes_run)


def _history(hist: pd.DataFrame, model: Model, theta: dict, summ: dict) -> pd.DataFrame:
    """The error history with this revision's row (replacing an earlier row of the same revision)."""
    if len(hist):  # one row per revision: a rerun (more repeats, a recalibration) replaces its own
        hist = hist[hist["revision"] != model.revision]
    hist = pd.concat([hist, pd.DataFrame([{"revision": model.revision, "effects": ",".join(model.effects),
                                           "rmse": summ["rmse"], "chi2_dof": summ["chi2_dof"],
                                           "n_conditions": summ["n_conditions"], "n_fail": summ["n_fail"],
                                           **{f"param_{k}": v for k, v in theta.items()}}])], ignore_index=True)
    hist = hist.sort_values("revision", kind="stable").reset_index(drop=True)
    return hist


@dataclass
class CompareResult(Result):
    """RUN/compare/: ``residuals`` per condition, the ``history`` of every revision, and the fit's
    ``stats`` (rmse, chi2_dof, n_conditions, n_fail)."""

    residuals: Optional[pd.DataFrame] = None
    history: Optional[pd.DataFrame] = None
    stats: Optional[dict] = None
    revision: int = 0

    def __post_init__(self):
        if self.residuals is None and (self.dir / "residuals.parquet").is_file():
            self.residuals = art.read_table(self.dir / "residuals.parquet")
            self.history = art.read_table(self.dir / "history.parquet")
            self.revision = int(art.read_provenance(self.dir / "residuals.parquet").get("model_revision", 0))
            row = self.history[self.history["revision"] == self.revision]
            if len(row):
                self.stats = {"rmse": float(row["rmse"].iloc[-1]), "chi2_dof": float(row["chi2_dof"].iloc[-1]),
                              "n_fail": int(row["n_fail"].iloc[-1]), "n_conditions": int(row["n_conditions"].iloc[-1])}

    def summary(self) -> pd.DataFrame:
        """Measured against simulated angle per condition, the residual and its z."""
        return self.residuals[["condition_id", "measured", "measured_sd", "simulated", "simulated_sd", "residual",
                               "z", "fails"]]


@writes_run
def compare(run: Path, set_: Pairs = None, preset: Optional[str] = None, repeats: int = 3, workers: int = 1,
            shear_modulus: Optional[float] = None, force: bool = False, say: Optional[Say] = None,
            seeds: Optional[str] = None) -> CompareResult:
    """Simulate ``repeats`` heaps at every measured condition at the calibrated parameters (``set_``
    overrides them) and compare them with the measurements; each heap seeded by its condition's values, or
    by its row of the measured table (``seeds``, :data:`~calib_cli.discrepancy.point.MEASURED_SEEDINGS`;
    by default as the run's comparison before, :func:`~calib_cli.discrepancy.point.run_seeding`). Writes
    RUN/compare/residuals.parquet, residuals.png, and adds the model revision's row to history.parquet
    (history.png), all in one commit."""
    say = say or plain
    run = check_run_dir(run)
    check_not_empty(run)
    seeds = check_seeding(seeds or run_seeding(run))
    preset, shear_modulus = heap_setup(resolve_settings(run, None, None), preset, shear_modulus)
    model, theta = model_and_theta(run, set_)
    fitted = fitted_parameters(run, model, set_)
    conds = measured_conditions(run)
    warn_other_modulus(run, shear_modulus, "the comparison's", say)
    # the kernel's source too: the heaps would change with it, though nothing in the run dir does
    st = stage(run, "compare", f"rev{model.revision}",
                   inputs={"conditions": run / "measure" / "conditions.parquet"},
                   settings={"theta": theta, "model": model.hash, "preset": preset, "repeats": repeats,
                             "kernel": CACHE_SOURCE, **modulus_settings(shear_modulus),
                             **run_heap_settings(resolve_settings(run, None, None)), **seeding_settings(seeds),
                             # where some were held or set: locks from before this count stay up to date
                             **({"fitted": fitted} if len(fitted) != len(model.parameters) else {})})
    hist_path = run / "compare" / "history.parquet"
    hist = art.read_table(hist_path, columns=["revision"], what="compare history") if hist_path.is_file() \
        else pd.DataFrame()  # checked before any heap is simulated
    if st.up_to_date() and not force and len(hist) and (hist["revision"] == model.revision).any():
        return CompareResult(st, True)
    say(f"model revision {model.revision} ({', '.join(model.effects)}); {len(conds)} condition(s) x "
        f"{repeats} simulations")
    sim, _ = simulate_at(run, model, theta, conds, preset, repeats, workers, "compare", shear_modulus=shear_modulus,
                         seeds=MEASURED_SEEDINGS[seeds])
    res = residual_table(conds["mean"], conds["sd"], conds["n"], sim["mean"].to_numpy(), sim["sd"].to_numpy(),
                         sim["n"].to_numpy())
    table = pd.DataFrame({"condition_id": conds["condition_id"].astype(str), "measured": conds["mean"],
                          "measured_sd": conds["sd"], "measured_n": conds["n"], "simulated": sim["mean"].to_numpy(),
                          "simulated_sd": sim["sd"].to_numpy(), "simulated_n": sim["n"].to_numpy(),
                          **{k: res[k].to_numpy() for k in ("residual", "uncertainty", "z", "fails")}})
    for c in COND_VARS:
        if c in conds.columns:
            table[c] = conds[c].to_numpy()
    summ = summary(res, len(fitted))
    hist = _history(hist, model, theta, summ)
    fig1, fig2 = residuals_figure(table, model.revision, COND_VARS), history_figure(hist)
    # the history under the same lock as the residuals: one commit, so no reader sees one without the other
    with st.commit() as out:
        # the seeding with the residuals: diagnose simulates its base point alike, so it reuses these heaps
        out.table("residuals.parquet", table, model_revision=model.revision, model=list(model.effects),
                  theta=theta, **seeding_settings(seeds))
        out.figure("residuals.png", fig1)
        out.table("history.parquet", hist, model_revision=model.revision)
        out.figure("history.png", fig2)
    return CompareResult(st, False, table, hist, summ, model.revision)
