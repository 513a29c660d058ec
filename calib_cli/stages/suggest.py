"""Suggest the next conditions to measure: rank what the rig can make by the expected information about
the parameters (through the posterior and its surrogate) and by how much each would separate a missing
effect from what the current parameters absorb (through diagnose's sensitivities). Method:
:mod:`calib_cli.posterior.suggest`."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..campaign import RESULTS
from ..errors import CalibError
from ..model import EFFECTS, MODEL_FILE, Model, load_model
from ..posterior.gp import GPSurrogate
from ..posterior.suggest import Evidence, Rig, explain, parse_rig, rank_conditions
from .common import Result, Say, check_run_dir, plain, stage, writes_run
from .compare import measured_conditions
from .posterior import RESPONSE, _check_rows, model_rows, model_surrogate

#: posterior draws the preposterior uses (evenly thinned)
DRAWS = 2000
#: the condition variables a suggestion sets
SUGGEST_VARS = ["particle_d_min_mm", "particle_d_max_mm", "cylinder_diameter_mm", "fill_height_mm", "lift_speed_mm_s"]


def load_rig(path: Path) -> Rig:
    """A rig file (TOML, docs/cli.md), or a one-line error."""
    path = Path(path)
    if not path.is_file():
        raise CalibError(f"rig file {path} not found")
    try:
        return parse_rig(tomllib.loads(path.read_text()), str(path))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CalibError(f"{path} is not a valid TOML file ({e})") from None


def _posterior(run: Path, model: Model) -> pd.DataFrame:
    """The posterior draws of the current model, or an error saying to sample them first."""
    path = run / "posterior" / "summary.parquet"
    if not path.is_file():
        raise CalibError(f"no posterior in {run}: run `calib calibrate-posterior --run {run}` first")
    rev = art.read_provenance(path).get("model_revision")
    if rev is not None and int(rev) != model.revision:
        raise CalibError(f"{path} is the posterior of model revision {rev}, but the model is revision "
                         f"{model.revision}: run `calib calibrate-posterior --run {run}` first")
    return art.read_table(run / "posterior" / "samples.parquet")


def _candidates(rig: Rig, measured: pd.DataFrame) -> pd.DataFrame:
    """The rig's conditions not yet measured; a variable the rig does not list takes the measured
    conditions' value (refused where they differ: the rig must say which)."""
    cand = rig.conditions()
    for v in SUGGEST_VARS:
        if v not in cand:
            vals = measured[v].dropna().unique() if v in measured else []
            if len(vals) != 1:
                raise CalibError(f"the rig file lists no {v}, and the measured conditions "
                                 f"{'differ in it' if len(vals) else 'do not say it'}: list its values in the rig file")
            cand[v] = float(vals[0])
    same = [v for v in SUGGEST_VARS if v in measured]  # the variables a measured condition states
    key = lambda df: df[same].round(6).astype(str).agg("|".join, axis=1)  # noqa: E731
    return cand[~key(cand).isin(set(key(measured)))].reset_index(drop=True)


def _diagnosed(run: Path, model: Model, measured: pd.DataFrame):
    """diagnose's sensitivities at the measured conditions, split for the current model: J (its
    parameters: an effect added since diagnose ran is a column of J now) and G (the candidates)."""
    path = run / "diagnose" / "sensitivities.parquet"
    if not path.is_file():
        return None, None
    s = art.read_table(path).set_index("condition_id").reindex(measured["condition_id"].astype(str))
    col = {**{c.removeprefix("d_"): c for c in s if c.startswith("d_")},
           **{EFFECTS[c.removeprefix("candidate_")].parameter: c for c in s if c.startswith("candidate_")}}
    missing = [p for p in model.parameters if p not in col]
    if missing or s.isna().any().any():
        return None, None
    J = pd.DataFrame({p: s[col[p]].to_numpy(float) for p in model.parameters})
    G = pd.DataFrame({e: s[f"candidate_{e}"].to_numpy(float) for e in model.candidates if f"candidate_{e}" in s})
    return J, G


def _surrogate_at(gp: GPSurrogate, draws: pd.DataFrame, cand: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The surrogate's angle at every posterior draw under each candidate (candidates, draws), and its
    own variance there (the mean over the draws); NaN where a candidate sets a condition variable
    every simulated heap shared at another value (the surrogate knows nothing of it there)."""
    S = len(draws)
    mu, var = np.zeros((len(cand), S)), np.zeros(len(cand))
    for i in range(len(cand)):
        X = draws.assign(**{c: float(cand[c].iloc[i]) for c in gp.inputs_ if c not in draws.columns})
        m, sd = gp.predict(X, return_std=True)
        mu[i], var[i] = m, float(np.mean(sd**2))
    unknown = np.zeros(len(cand), bool)
    for c, v in gp.constants_.items():
        if c in cand:
            unknown |= ~np.isclose(cand[c].to_numpy(float), v)
    mu[unknown], var[unknown] = np.nan, np.nan
    return mu, var


@dataclass
class SuggestResult(Result):
    """RUN/suggest/: the ranked candidates (``table``: ranking.parquet) and conditions.csv (the top
    ones, one row per pile, in measure-angle's --conditions format)."""

    table: Optional[pd.DataFrame] = None
    top: int = 5
    notes: tuple[str, ...] = ()

    def __post_init__(self):
        if self.table is None and (self.dir / "ranking.parquet").is_file():
            self.table = art.read_table(self.dir / "ranking.parquet")

    def summary(self) -> pd.DataFrame:
        cols = ["condition_id", "info_gain_nats", "best_effect", "best_separation", "surrogate_sd"]
        return self.table[[c for c in cols if c in self.table]].head(self.top)

    def conclusion(self) -> list[str]:
        return [f"[bold]{r.condition_id}[/]: {r.reason}" for r in self.table.head(self.top).itertuples()] + list(
            self.notes)


def _evidence(run: Path, model: Model, measured: pd.DataFrame, samples: pd.DataFrame) -> tuple[Evidence, list[str]]:
    params = model.parameters
    J, G = _diagnosed(run, model, measured)
    notes = []
    if J is None:
        notes.append(f"no separation of missing effects: diagnose's sensitivities at the measured conditions of "
                     f"this model's parameters are missing (run `calib diagnose --run {run}`)")
        J, G = pd.DataFrame(index=range(len(measured))), pd.DataFrame(index=range(len(measured)))
    sd = measured["sd"].to_numpy(float)
    scatter = float(np.sqrt(np.nanmean(sd**2)))
    u = np.where(np.isfinite(sd), sd, scatter) / np.sqrt(measured["n"].to_numpy(float))
    # a thinned subset of the draws: the preposterior reweights them once per simulated outcome
    sub = samples[params].iloc[:: max(1, len(samples) // DRAWS)].to_numpy(float)
    ev = Evidence(measured.reset_index(drop=True), J, G, u, scatter, params, sub,
                  {e: EFFECTS[e].step for e in G.columns})
    return ev, notes


#: the expected rise of the score test's statistic below which a condition does not separate an effect
#: (one unit of chi-square: the test's own scale)
SEPARATES = 1.0
#: how the reasons name the condition variables
WORDS = {"particle_d_min_mm": "grain size", "particle_d_max_mm": "grain size", "cylinder_diameter_mm":
         "cylinder diameter", "fill_height_mm": "fill height", "lift_speed_mm_s": "lift speed"}


def _reasons(ev: Evidence, table: pd.DataFrame, sd_measured: float, mean_sd: float, piles: int) -> list[str]:
    """Why each candidate: the effect it separates (its confound and the variable that breaks it)
    when it does, else the parameters whose intervals it narrows; a warning where the surrogate is
    unsure (its sd above the measured mean's, or well above its own at the measured conditions)
    or knows nothing."""
    out = []
    for _, row in table.iterrows():
        shr = {p: row[f"shrink_{p}"] for p in ev.params}
        ranked = sorted((p for p in shr if np.isfinite(shr[p])), key=lambda k: -shr[k])
        if row["best_effect"] and row["best_separation"] >= SEPARATES:
            why = explain(ev, row, row["best_effect"], SUGGEST_VARS, WORDS)
        elif ranked:
            why = "narrows " + ", ".join(f"{p.replace('_', ' ')}'s interval by {shr[p]:.0%}" for p in ranked[:2])
            if row["best_effect"]:
                why += f"; separates no missing effect (at most {row['best_separation']:.2g} chi-square units)"
        else:
            why = "unknown: it sets a variable no simulated heap varied; simulate heaps there first"
        sd = row["surrogate_sd"]
        if np.isfinite(sd) and (sd > 1.25 * sd_measured or sd > mean_sd):
            why += (f"; the surrogate is unsure here (sd {sd:.1f} deg at the posterior's draws, against "
                    f"{mean_sd:.1f} for a mean of {piles} piles): simulate heaps there before trusting the gain")
        out.append(why)
    return out


def _conditions_csv(table: pd.DataFrame, top: int, piles: int) -> str:
    """The top candidates, one row per pile (image names to photograph), as measure-angle reads them."""
    lines = ["image,condition_id," + ",".join(SUGGEST_VARS)]
    for _, r in table.head(top).iterrows():
        vals = ",".join(f"{float(r[v]):g}" for v in SUGGEST_VARS)
        lines += [f"{r['condition_id']}_r{k}.png,{r['condition_id']},{vals}" for k in range(1, piles + 1)]
    return "\n".join(lines) + "\n"


@writes_run
def suggest_conditions(run: Path, rig: Path, piles: Optional[int] = None, top: int = 5, force: bool = False,
                       say: Optional[Say] = None) -> SuggestResult:
    """Rank the conditions a rig can make (``rig``: a TOML file) by the expected information about the
    current model's parameters and the expected separation of each missing effect; writes
    RUN/suggest/ranking.parquet and conditions.csv (the ``top`` ones, ``piles`` rows each)."""
    say = say or plain
    run = check_run_dir(run)
    the_rig = load_rig(rig)
    piles = int(piles or the_rig.piles)
    if piles < 1 or top < 1:
        raise CalibError("--piles and --top must be at least 1")
    model = load_model(run)
    measured = measured_conditions(run)
    if measured.empty:
        raise CalibError(f"no measured condition in {run}: run `calib measure-angle` first")
    samples = _posterior(run, model)
    rows = model_rows(run, model)
    cond_vars = _check_rows(run, rows, model)
    sens = run / "diagnose" / "sensitivities.parquet"
    mfile = run / MODEL_FILE
    # the heaps the surrogate learns from are an input too: more of them change the gains
    st = stage(run, "suggest", "rank",
               inputs={"posterior": run / "posterior" / "samples.parquet", "conditions": run / "measure" /
                       "conditions.parquet", "sensitivities": sens if sens.is_file() else None,
                       "results": art.Rows(run / RESULTS, rows[[*model.parameters, *cond_vars, RESPONSE]]),
                       "model": mfile if mfile.is_file() else None, "rig": Path(rig)},
               settings={"piles": piles, "top": top})
    if st.up_to_date() and not force:
        return SuggestResult(st, True, top=top)
    cand = _candidates(the_rig, measured)
    if cand.empty:
        raise CalibError(f"every condition the rig file {rig} lists is measured already: list others")
    ev, notes = _evidence(run, model, measured, samples)
    gp = model_surrogate(rows, model)
    say(f"ranking {len(cand)} condition(s) the rig can make: the posterior of model revision {model.revision}, "
        f"a Gaussian process on {len(rows)} heaps, {len(ev.G.columns)} candidate effect(s)")
    draws = ev.draws_frame()
    mu, vp = _surrogate_at(gp, draws, cand)
    # the surrogate's uncertainty where it has data: a candidate well above it is an extrapolation
    sd_measured = float(np.sqrt(np.nanmax(_surrogate_at(gp, draws, measured)[1])))
    table = rank_conditions(ev, cand, mu, vp, piles, SUGGEST_VARS)
    mean_sd = ev.scatter / math.sqrt(piles)  # the sd of a measured mean
    table["reason"] = _reasons(ev, table, sd_measured, mean_sd, piles)
    if sd_measured > mean_sd:  # the bottleneck is the simulator's stand-in, not the lab
        notes.append(f"[yellow]note:[/] the surrogate's own sd at the posterior's draws is {sd_measured:.1f} deg even at "
                     f"the measured conditions, against {mean_sd:.1f} for a measured mean of {piles} piles: simulating "
                     "heaps where the posterior lies (a design over its 90 % intervals) will teach more than any new "
                     "condition until it falls")
    with st.commit() as out:
        out.text("conditions.csv", _conditions_csv(table, top, piles))
        out.table("ranking.parquet", table, model_revision=model.revision, piles=piles, scatter=ev.scatter)
    return SuggestResult(st, False, table, top, tuple(notes))
