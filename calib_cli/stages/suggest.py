"""Suggest the next conditions to measure: rank what the rig can make by the expected information about
the parameters (through the posterior and its surrogate) and by how much each would separate a missing
effect from what the current parameters absorb (through diagnose's sensitivities). Method:
:mod:`calib_cli.posterior.suggest`."""

from __future__ import annotations

import math
import shlex
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..heaps.index import RESULTS, load_results
from ..errors import CalibError
from ..parameters import check_rig
from ..model import EFFECTS, MODEL_FILE, Model, load_model
from ..posterior.gp import GPSurrogate, informative_conditions
from ..posterior.suggest import (Evidence, Rig, any_ranked, best_per_effect, explain, heaps_for, parse_rig,
                                 rank_conditions, region_design, simulate_command, unsettled_words,
                                 SEPARATES, unsettling)
from ..heaps.inputs import COND_VARS, heap_setup, modulus_settings, run_heap_settings
from .common import Result, Say, check_run_dir, plain, resolve_settings, shown, stage, writes_run
from ..conditions import outside_range
from ..measurements import measured_conditions
from ..posterior.evidence import RESPONSE, check_measured, check_rows, in_box, model_rows, model_surrogate, profile_rows
from ..posterior.profiles import FULLNESS, measured_fullness, profile_inputs, profiles_at_hand
from ..discrepancy.point import model_and_theta, simulate_points
from ..discrepancy.sensitivity import signatures
from ..heaps.inputs import Pairs

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
        raise CalibError(f"no posterior in {run}: run `calib calibrate --run {run}` (or calibrate-posterior) first")
    rev = art.read_provenance(path).get("model_revision")
    if rev is not None and int(rev) != model.revision:
        raise CalibError(f"{path} is the posterior of model revision {rev}, but the model is revision "
                         f"{model.revision}: run `calib calibrate --run {run}` (or calibrate-posterior) first")
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
    cand = _buildable(cand)
    same = [v for v in SUGGEST_VARS if v in measured]  # the variables a measured condition states
    # as numbers: a conditions table of whole numbers reads as integers, and "50" is not "50.0"
    key = lambda df: df[same].astype(float).round(6).astype(str).agg("|".join, axis=1)  # noqa: E731
    cand = cand[~key(cand).isin(set(key(measured)))].reset_index(drop=True)
    clash = sorted(set(cand["condition_id"].astype(str)) & set(measured["condition_id"].astype(str)))
    if clash:
        raise CalibError(f"the rig's condition {clash[0]} is not measured, but a measured condition has that name with "
                         "other values (the name leaves out what the rig holds at one value): rename the measured "
                         "condition in measure-angle's conditions table, or list that variable's values in the rig file")
    return cand


def _buildable(cand: pd.DataFrame) -> pd.DataFrame:
    """The rig's combinations a heap test can make (:func:`~calib_cli.parameters.check_rig`: a cylinder at least
    4, a fill at least 2 of the largest grains): a 20 mm cylinder is for the fine fractions only. The others are
    left out (``attrs["unbuildable"]`` names them); none left is the rig file's error."""
    ok = []
    for r in cand.itertuples(index=False):
        try:
            check_rig(r.particle_d_min_mm, r.particle_d_max_mm, getattr(r, "cylinder_diameter_mm", None),
                      getattr(r, "fill_height_mm", None))
            ok.append(True)
        except CalibError:
            ok.append(False)
    ok = np.asarray(ok, dtype=bool)
    if len(ok) and not ok.any():
        raise CalibError("no combination of the rig file's values makes a heap test (a cylinder at least 4 and a "
                         "fill at least 2 of the largest grains): list wider cylinders or finer grains")
    out = cand[ok].reset_index(drop=True)
    out.attrs["unbuildable"] = cand.loc[~ok, "condition_id"].astype(str).tolist()
    return out


def _complete(cand: pd.DataFrame, measured: pd.DataFrame, learnt: list[str]) -> pd.DataFrame:
    """The candidates with every condition variable the surrogate learnt that the rig does not set (a floor's
    friction) at the measured conditions' value; refused where they differ in it or lack it."""
    for v in (v for v in learnt if v not in cand):
        vals = measured[v].dropna().unique() if v in measured else []
        if len(vals) != 1:
            raise CalibError(f"the simulated heaps vary {v}, which a rig file does not set, and the measured "
                             f"conditions {'differ in it' if len(vals) else 'do not give it'}: rank the conditions "
                             "of one value at a time (a run whose measured conditions share it)")
        cand = cand.assign(**{v: float(vals[0])})
    return cand


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


def _scale(run: Path) -> Optional[dict]:
    """The posterior's prior box where it was the settings' (its surrogates scaled by it and learnt from the
    heaps inside it), else None (each effect's own ranges)."""
    prov = art.read_provenance(run / "posterior" / "summary.parquet")
    if prov.get("prior") != "settings" or not prov.get("bounds"):
        return None
    return {k: tuple(v) for k, v in prov["bounds"].items()}


def _scatter(sd, unknown: str) -> float:
    """The conditions' sds' rms, the scatter a new condition is measured with and a gain is measured in units
    of; refused (``unknown``: why, in words) where no sd is known or it is zero."""
    sd = np.asarray(sd, float)
    out = float(np.sqrt(np.nanmean(sd**2))) if np.isfinite(sd).any() else math.nan
    if not out > 0:
        raise CalibError(f"{unknown}: measure at least one condition with two or more piles")
    return out


def _surrogate_at(gp: GPSurrogate, draws: pd.DataFrame, cand: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The surrogate's angle at every posterior draw under each candidate (candidates, draws), and its
    own variance there (the mean over the draws); NaN where a candidate sets a condition variable
    every simulated heap shared at another value (the surrogate knows nothing of it there)."""
    S = len(draws)
    mu, var = np.zeros((len(cand), S)), np.zeros(len(cand))
    for i in range(len(cand)):
        m, sd = gp.predict(_inputs(gp, draws, cand.iloc[i]), return_std=True)
        mu[i], var[i] = m, float(np.mean(sd**2))
    unknown = np.zeros(len(cand), bool)
    for c, v in gp.constants_.items():
        if c in cand:
            unknown |= ~np.isclose(cand[c].to_numpy(float), v)
    mu[unknown], var[unknown] = np.nan, np.nan
    return mu, var


def _inputs(gp: GPSurrogate, draws: pd.DataFrame, cond: pd.Series) -> pd.DataFrame:
    """The surrogate's inputs at every draw under one condition (``cond``: a candidate's row)."""
    return draws.assign(**{c: float(cond[c]) for c in gp.inputs_ if c not in draws.columns})[gp.inputs_]


def _profile_at(run: Path, rows: pd.DataFrame, model: Model, ev: Evidence, measured: pd.DataFrame,
                cand: pd.DataFrame, mu: np.ndarray) -> tuple[np.ndarray, GPSurrogate]:
    """With a posterior that weighed the heap profile: the fullness's surrogate at every draw under each
    candidate stacked on the angle's ``mu`` (candidates, draws, 2), and that surrogate; ``ev`` is given the
    photographs' fullness scatter and its correlation with the angle, as a new condition would be measured."""
    table, rho = measured_fullness(run, measured)
    ev.profile_scatter = _scatter(table["sd"], "the photographs' heap profiles scatter by nothing measurable (every "
                                  "condition one photograph, or all of one fullness)")
    ev.profile_rho = rho
    gp = model_surrogate(rows, model, response=FULLNESS, scale=_scale(run))
    mu_f, _ = _surrogate_at(gp, ev.draws_frame(), cand)
    return np.stack([mu, mu_f], axis=2), gp


#: the surrogate's joint realisations a gain's spread is read from, and how many of the draws they are drawn at
#: (per candidate: the covariance is of every candidate's draws together, so that the chance of being the
#: best compares like with like)
REALISATIONS, SPREAD_DRAWS = 200, 100
#: at most this many points in one joint covariance (its Cholesky factor costs their cube): a larger rig draws
#: fewer draws a candidate
SPREAD_POINTS = 4000
#: the fewest draws a candidate's spread is read from: a rig of more candidates than SPREAD_POINTS / SPREAD_FEWEST
#: gets its gains without their spread
SPREAD_FEWEST = 10


def _realisations(gps: list[GPSurrogate], draws: pd.DataFrame, cand: pd.DataFrame, live: np.ndarray) -> np.ndarray:
    """REALISATIONS joint draws of each surrogate's latent response (the angle's, the fullness's) at
    SPREAD_DRAWS of the posterior's draws (evenly spaced; fewer where the live candidates would pass
    SPREAD_POINTS, SPREAD_FEWEST at the least, else none) under every ``live`` candidate: (K, candidates, draws,
    responses), NaN at a candidate not live (:func:`calib_cli.posterior.suggest.gain_spread`)."""
    idx = np.flatnonzero(live)
    per = min(len(draws), SPREAD_DRAWS, SPREAD_POINTS // max(1, len(idx)))
    if per < SPREAD_FEWEST:  # too many candidates for one joint covariance: no spread (a note says so)
        idx, per = idx[:0], min(len(draws), SPREAD_FEWEST)
    sub = draws.iloc[np.unique(np.linspace(0, len(draws) - 1, per).round().astype(int))]
    F = np.full((REALISATIONS, len(cand), len(sub), len(gps)), np.nan)
    for r, gp in enumerate(gps):
        if len(idx):
            X = np.vstack([_inputs(gp, sub, cand.iloc[i]).to_numpy(float) for i in idx])
            F[..., r][:, idx] = gp.sample_latent(X, REALISATIONS, seed=r)[1].reshape(REALISATIONS, len(idx), len(sub))
    return F


def _responses(run: Path, rows: pd.DataFrame, model: Model, ev: Evidence, measured: pd.DataFrame, cand: pd.DataFrame,
               gp: GPSurrogate, cond_vars=None, say: Optional[Say] = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The surrogates' means at every draw under each candidate (the angle's; with ``cond_vars``, a posterior
    that weighed the profile, the fullness's stacked on it), the angle's own variance there, and their joint
    realisations (:func:`_realisations`)."""
    draws = ev.draws_frame()
    mu, vp = _surrogate_at(gp, draws, cand)
    gps = [gp]
    if cond_vars is not None:
        mu, gp_f = _profile_at(run, profile_rows(run, rows, model, cond_vars, say), model, ev, measured, cand, mu)
        gps.append(gp_f)
    return mu, vp, _realisations(gps, draws, cand, np.isfinite(vp))


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
        cols = ["condition_id", "info_gain_nats", "best_effect", "best_separation", "sensitivities", "surrogate_sd"]
        t = self.table.head(self.top)
        if "info_gain_q05" in t:  # the gain with its 90 % range over the surrogate's uncertainty
            t = t.assign(info_gain_nats=[f"{g:.2f} ({a:.2f}-{b:.2f})" if np.isfinite(a) else f"{g:.3g}" for g, a, b
                                         in zip(t["info_gain_nats"], t["info_gain_q05"], t["info_gain_q95"])])
        if "simulated" in t and any(c.startswith("separation_") for c in t):  # where they come from
            t = t.assign(sensitivities=np.select([t["simulated"], ~t["known"], t["extrapolated"]],
                                                 ["simulated", "unknown", "extrapolated"], "interpolated"))
        t = t[[c for c in cols if c in t]]
        # the parenthesis says what it is: the gain's 90 % range over the surrogate's own uncertainty
        return t.rename(columns={"info_gain_nats": "info_gain_nats (90 %)"}) if "info_gain_q05" in self.table else t

    def title(self) -> str:
        """The table's heading: ranked best first, or (no candidate's gain or separation ranked, each the
        surrogate's extrapolation) in the rig's order."""
        if any_ranked(self.table):
            return "the next conditions to measure, best first"
        return "the conditions the rig offers, in its order: none is ranked (the surrogate extrapolates at each)"

    def conclusion(self, markup: bool = False) -> list[str]:
        """Why each of the top conditions ranks where it does, the condition that best tells each effect apart,
        and the notes (``markup``: with the command line's rich markup)."""
        return shown([f"[bold]{r.condition_id}[/]: {r.reason}" for r in self.table.head(self.top).itertuples()]
                     + self.per_effect(markup=True) + list(self.notes), markup)

    def per_effect(self, markup: bool = False) -> list[str]:
        """For each candidate effect, the condition that would best tell it apart (:func:`best_per_effect`):
        what to measure to settle that one effect."""
        return shown([f"{e.replace('_', ' ')}: best told apart at [bold]{cid}[/] ({sep:.2g} chi-square units, "
                f"sensitivities {how})" + unsettling(sep)
                for e, cid, sep, how in best_per_effect(self.table)], markup)


def _theta(run: Path, set_: Pairs) -> tuple[Model, dict[str, float]]:
    """The parameters diagnose's sensitivities were simulated at (their table's provenance), so that
    a candidate's are taken at the same point; ``--set`` or, for a table that does not say, the
    calibrated values (as diagnose takes them)."""
    path = run / "diagnose" / "sensitivities.parquet"
    said = art.read_provenance(path).get("theta") if not set_ and path.is_file() else None
    model = load_model(run)
    if said and all(p in said for p in model.parameters):
        return model, {k: float(v) for k, v in said.items()}
    return model_and_theta(run, set_)


#: the design label of the heaps ``--heaps`` spreads over the posterior at the candidates
REGION = "suggest-region"


def _made(run: Path, design: str) -> pd.DataFrame:
    """The rows a ``design``'s heaps hold in the run's results index (none where it has none)."""
    made = load_results(run)
    if not {"design", "run_id"} <= set(made.columns):
        return made.iloc[:0]
    return made[made["design"] == design]


def next_run_id(run: Path, design: str) -> int:
    """The run id after the largest a ``design``'s heaps hold in the run's results index (1 where none): a
    later design of the same label is numbered on, so that design and run id name one point."""
    return _next_id(_made(run, design))


def _next_id(made: pd.DataFrame) -> int:
    """The run id after the largest among a design's rows (1 where there are none)."""
    return 1 + int(made["run_id"].max()) if len(made) else 1


def _same_point(made: pd.DataFrame, params: list[str], x) -> np.ndarray:
    """Per row of ``made``, whether its parameters are the point ``x`` (a design's values, in ``params``'
    order; exact but for the round trip through Parquet); False throughout where a parameter is not a column."""
    if not set(params) <= set(made.columns):
        return np.zeros(len(made), bool)
    return np.isclose(made[params].to_numpy(float), np.asarray(x, float), rtol=1e-12, atol=0.0).all(axis=1)


def region_ids(run: Path, design: pd.DataFrame, params: list[str]) -> pd.DataFrame:
    """``design`` with each point's run id: that of the same parameters among the REGION heaps made
    before (a design run again, or grown, finds them cached and adds no row), else numbered on."""
    made = _made(run, REGION)
    ids, new = [], _next_id(made)
    for x in design[params].to_numpy(float):
        same = _same_point(made, params, x)
        if same.any():
            ids.append(int(made.loc[same, "run_id"].iloc[0]))
        else:
            ids.append(new)
            new += 1
    return design.assign(run_id=ids)


#: how far into the current posterior's design :func:`region_heaps` looks for points simulated before
REGION_SPAN = 256


def region_heaps(run: Path, cand: pd.DataFrame, summary: pd.DataFrame) -> np.ndarray:
    """How many of the current posterior's ``--heaps`` points (the first REGION_SPAN of its nested design over
    ``summary``'s intervals) each candidate has: what a larger --heaps keeps. Points of an earlier posterior
    do not count, since its design is no longer the current one's prefix."""
    made = _made(run, REGION)
    params = list(summary["parameter"])
    if not len(made) or "condition_id" not in made or not set(params) <= set(made.columns):
        return np.zeros(len(cand), int)
    span = max(REGION_SPAN, int(made["run_id"].nunique()))  # an earlier --heaps beyond the span still counts
    design = region_design(summary, span, nested=True)[params].to_numpy(float)
    where = made["condition_id"].astype(str)
    return np.array([sum(_same_point(made[where == cid], params, x).any() for x in design)
                     for cid in cand["condition_id"].astype(str)], int)


def _simulate_candidates(run: Path, cand: pd.DataFrame, ids, set_: Pairs, preset: Optional[str], repeats: int,
                         workers: int, shear_modulus: Optional[float], say: Say, heaps: int = 0) -> pd.DataFrame:
    """diagnose's sensitivities simulated at the candidates ``ids``: one row per candidate (NaN where not
    simulated), columns d_<parameter> and candidate_<effect> as in diagnose/sensitivities.parquet, and
    se_candidate_<effect>, the signature's standard error from the heaps' scatter. With ``heaps``, as many
    more at each candidate spread over the posterior's 90 % intervals (:func:`region_design`): diagnose's
    heaps teach the surrogate the candidate at one point, these where the posterior's draws lie."""
    known = cand["condition_id"].astype(str).tolist()
    wrong = [i for i in ids if i not in known]
    if wrong:
        raise CalibError(f"--simulate names {', '.join(wrong)}, which the rig cannot make or which is measured "
                         f"already; the candidates are {', '.join(known)}")
    if not (run / "diagnose" / "sensitivities.parquet").is_file():
        raise CalibError(f"--simulate needs diagnose's sensitivities at the measured conditions: run "
                         f"`calib diagnose --run {run}` first")
    preset, shear_modulus = heap_setup(resolve_settings(run, None, None), preset, shear_modulus)
    model, theta = _theta(run, set_)
    picks = cand[cand["condition_id"].astype(str).isin(ids)].reset_index()
    # the effects diagnose tested: only theirs can be set against the measured conditions' signatures
    tested = [c.removeprefix("candidate_") for c in art.read_table(run / "diagnose" / "sensitivities.parquet").columns
              if c.startswith("candidate_") and c.removeprefix("candidate_") in model.candidates]
    two_sided = sum(EFFECTS[e].two_sided for e in tested)
    n = (1 + len(model.parameters) + len(tested) + two_sided) * len(picks) * repeats
    say(f"simulating diagnose's sensitivities at {len(picks)} candidate condition(s): {n} heaps at most "
        "(cached ones are reused)" + (f", and {heaps * len(picks)} over the posterior's 90 % intervals" if heaps else ""))
    # seeded by each candidate's values, not its place among those named: naming another one later finds these cached
    _, J, G, G_se, _ = signatures(run, model, theta, picks, preset, repeats, workers, shear_modulus, tested,
                                  seeds="condition")
    if heaps:
        # nested: a larger --heaps keeps these points, and a design run again is found cached, adding no rows
        design = region_ids(run, region_design(art.read_table(run / "posterior" / "summary.parquet"), heaps,
                                               nested=True), model.parameters)
        points = [(int(r["run_id"]), {p: float(r[p]) for p in model.parameters}) for _, r in design.iterrows()]
        simulate_points(run, model, points, picks, preset, 1, workers, REGION, shear_modulus=shear_modulus,
                        seeds="content")
    out = pd.DataFrame(index=cand.index)
    for k, e in enumerate(model.effects):
        out.loc[picks["index"], f"d_{EFFECTS[e].parameter}"] = J[k]
    for e, g in G.items():
        out.loc[picks["index"], f"candidate_{e}"] = g
        out.loc[picks["index"], f"se_candidate_{e}"] = G_se[e]
    return out


def _residual_uncertainty(run: Path, measured: pd.DataFrame, u: np.ndarray) -> tuple[np.ndarray, float]:
    """The uncertainty of each measured condition's residual as diagnose's test weighs it (compare's:
    measured and simulated means together) and the simulated mean's share of its variance; the
    measured mean's alone (``u``) and no share where compare has not run on these conditions."""
    path = run / "compare" / "residuals.parquet"
    if not path.is_file():
        return u, 0.0
    res = art.read_table(path).set_index("condition_id")
    ids = measured["condition_id"].astype(str)
    if not ids.isin(res.index.astype(str)).all():
        return u, 0.0
    uc = res.set_axis(res.index.astype(str)).loc[ids, "uncertainty"].to_numpy(float)
    return uc, float(np.nanmean(np.clip(uc**2 - u**2, 0.0, None)))


def _evidence(run: Path, model: Model, measured: pd.DataFrame, samples: pd.DataFrame) -> tuple[Evidence, list[str]]:
    params = model.parameters
    J, G = _diagnosed(run, model, measured)
    notes = []
    if J is None:
        notes.append(f"no separation of missing effects: diagnose's sensitivities at the measured conditions of "
                     f"this model's parameters are missing (run `calib diagnose --run {run}`)")
        J, G = pd.DataFrame(index=range(len(measured))), pd.DataFrame(index=range(len(measured)))
    sd = measured["sd"].to_numpy(float)
    scatter = _scatter(sd, "the measured piles' scatter is unknown or zero (every condition one pile, or piles of "
                       "one angle)")
    u = np.where(np.isfinite(sd) & (sd > 0), sd, scatter) / np.sqrt(measured["n"].to_numpy(float))
    u, sim_var = _residual_uncertainty(run, measured, u)
    # a thinned subset of the draws: the preposterior reweights them once per simulated outcome
    sub = samples[params].iloc[:: max(1, len(samples) // DRAWS)].to_numpy(float)
    ev = Evidence(measured.reset_index(drop=True), J, G, u, scatter, params, sub,
                  {e: EFFECTS[e].step for e in G.columns}, sim_var)
    return ev, notes


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
            if row["extrapolated"]:
                why = (f"may separate, by a straight line carried beyond the measured conditions (not ranked; "
                       f"`--simulate {_named(table, row['condition_id'])}` simulates it): " + why)
        elif ranked:
            why = "narrows " + ", ".join(f"{p.replace('_', ' ')}'s interval by {shr[p]:.0%}" for p in ranked[:2])
            if row["best_effect"]:
                why += f"; separates no missing effect (at most {row['best_separation']:.2g} chi-square units)"
        else:
            why = "unknown: it sets a variable no simulated heap varied; simulate heaps there first"
        if row.get("beyond_heaps") and np.isfinite(row["info_gain_nats"]):
            why += f"; the surrogate extrapolates here ({row['beyond_heaps']}): the gain is not ranked"
        sd = row["surrogate_sd"]
        if np.isfinite(sd) and (sd > 1.25 * sd_measured or sd > mean_sd):
            why += (f"; the surrogate is unsure here (sd {sd:.1f} deg at the posterior's draws, against "
                    f"{mean_sd:.1f} for a mean of {piles} piles): simulate heaps there before trusting the gain "
                    f"({_advice(table, row['condition_id'])})")
        out.append(why)
    return out


def _advice(table: pd.DataFrame, cid: str) -> str:
    """The options that add REGION_HEAPS heaps at ``cid`` (:func:`heaps_for`), naming the candidates simulated
    before too; --heaps then tops those up as well, which it says."""
    named = _named(table, cid)
    return (f"`--simulate {named} --heaps {heaps_for(table, [cid])}`"
            + ("; --heaps tops up every candidate named" if "," in named else ""))


def _named(table: pd.DataFrame, cid: str) -> str:
    """``--simulate``'s list to simulate at ``cid``: the candidates simulated for this ranking too, whose
    sensitivities a ranking reads only where they are named."""
    done = table.loc[table["simulated"], "condition_id"].astype(str).tolist() if "simulated" in table else []
    return ",".join(dict.fromkeys([*done, str(cid)]))


def _beyond_heaps(gp: GPSurrogate, cand: pd.DataFrame) -> list[str]:
    """Per candidate, the condition variables it sets beyond the range of the heaps the surrogate learnt
    from ("fill height 150 beyond the heaps' 50-100"), or "": there its gain is the surrogate's guess."""
    ranges = gp.condition_ranges()
    out = []
    for _, row in cand.iterrows():
        far = [f"{WORDS.get(c, c)} {row[c]:g} beyond the heaps' {lo:g}-{hi:g}"
               for c, (lo, hi) in ranges.items() if c in row and outside_range(row[c], lo, hi)]
        out.append("; ".join(far))
    return out


def _conditions_csv(table: pd.DataFrame, top: int, piles: int) -> str:
    """The top candidates, one row per pile (image names to photograph), as measure-angle reads them."""
    lines = ["image,condition_id," + ",".join(SUGGEST_VARS)]
    for _, r in table.head(top).iterrows():
        vals = ",".join(f"{float(r[v]):g}" for v in SUGGEST_VARS)
        lines += [f"{r['condition_id']}_r{k}.png,{r['condition_id']},{vals}" for k in range(1, piles + 1)]
    return "\n".join(lines) + "\n"


def _ranking_notes(ev: Evidence, table: pd.DataFrame, sd_measured: float, mean_sd: float, piles: int,
                   command: str) -> list[str]:
    """What limits a ranking: a surrogate less sure than a measured mean even where there are heaps, gains or
    separations carried beyond the heaps or the measured range (shown, not ranked), the command that
    would simulate heaps at the best of those (this one's, else ``command``, when called from a library), the
    gains' ranges where a rig of too many candidates left them out (:func:`_realisations`), and the candidates
    in contention for the largest gain where the surrogate leaves it open."""
    notes = []
    if sd_measured > mean_sd:  # the bottleneck is the simulator's stand-in, not the lab
        notes.append(f"[yellow]note:[/] the surrogate's own sd at the posterior's draws is {sd_measured:.1f} deg even at "
                     f"the measured conditions, against {mean_sd:.1f} for a measured mean of {piles} piles: simulating "
                     "heaps where the posterior lies (a design over its 90 % intervals) will teach more than any new "
                     "condition until it falls")
    to_rank = simulate_command(art.command_line(), table, command)  # "" where no gain lies beyond the heaps
    if to_rank:
        notes.append("[yellow]note:[/] an information gain beyond the simulated heaps' range is the surrogate's own "
                     f"extrapolation and is not ranked: simulate heaps there first; at the two largest, `{to_rank}`")
    if np.isfinite(table["info_gain_nats"]).any() and not np.isfinite(table["info_gain_q05"]).any():
        notes.append(f"[yellow]note:[/] the gains' 90 % ranges are left out: over {SPREAD_POINTS // SPREAD_FEWEST} "
                     "candidates are too many for one joint covariance (list fewer values in the rig file)")
    open_ = unsettled_words(table)
    if open_:
        notes.append(f"[yellow]note:[/] {open_}")
    if len(ev.G.columns) and table["extrapolated"].any() and not table["simulated"].any():
        notes.append("[yellow]note:[/] a separation beyond the measured conditions' range is a straight line carried "
                     "out from them and is not ranked; `--simulate ID,...` simulates the sensitivities there")
    return notes


def _unnamed(run: Path, simulate: list[str]) -> list[str]:
    """A note where an earlier ``--simulate`` made sensitivities at candidates this ranking does not name: it
    reads them only where named, so they fall back to the measured conditions' (their heaps stay cached)."""
    path = run / "suggest" / "sensitivities.parquet"
    try:  # a note only: a file its lock does not vouch for (an interrupted ranking) is the commit's to replace
        before = art.read_table(path, ["condition_id"])["condition_id"].astype(str).tolist() if path.is_file() else []
    except CalibError:
        before = []
    left = [c for c in before if c not in simulate]
    if not left:
        return []
    return [f"[yellow]note:[/] diagnose's sensitivities were simulated before at {', '.join(left)}, which this ranking "
            f"does not name, so there they are carried from the measured conditions: add them to `--simulate` (their "
            "heaps are cached)"]


def _rank_inputs(run: Path, rig: Path, model: Model, rows: pd.DataFrame, cond_vars: list[str], profile: bool) -> dict:
    """What a ranking reads, for its lock: the posterior, the measured conditions, diagnose's sensitivities and
    compare's residuals where they exist, the model, the rig, the photographs' profiles where the posterior
    weighed them, and the heaps the surrogate learns from (more of them change the gains)."""
    sens, res = run / "diagnose" / "sensitivities.parquet", run / "compare" / "residuals.parquet"
    mfile = run / MODEL_FILE
    return {"posterior": run / "posterior" / "samples.parquet", "conditions": run / "measure" / "conditions.parquet",
            "sensitivities": sens if sens.is_file() else None, "residuals": res if res.is_file() else None,
            "results": art.Rows(run / RESULTS, rows[[*model.parameters, *cond_vars, RESPONSE]]),
            "model": mfile if mfile.is_file() else None, "rig": Path(rig), **(profile_inputs(run) if profile else {})}


def _check_options(piles: int, top: int, repeats: int, heaps: int, simulate: bool, heap_options: bool) -> None:
    """Refuses counts out of range, and options that choose heaps (``heap_options``: --set, --preset,
    --shear-modulus, a --repeats or --workers not the default; and --heaps) without --simulate, which alone
    makes them."""
    if piles < 1 or top < 1 or repeats < 1:
        raise CalibError("--piles, --top and --repeats must be at least 1")
    if simulate and repeats < 2:
        raise CalibError(f"--repeats must be at least 2 with --simulate (got {repeats}): a sensitivity's noise is "
                         "taken from its repeated heaps")
    if heaps < 0 or heaps == 1:
        raise CalibError(f"--heaps must be 0 or at least 2 (a design over the posterior's intervals), got {heaps}")
    if not simulate and (heap_options or heaps):
        raise CalibError("--set, --preset, --shear-modulus, --heaps, --repeats and --workers choose the heaps "
                         "--simulate makes: name the candidates to simulate (--simulate ID), or leave them out")


@writes_run
def suggest_conditions(run: Path, rig: Path, piles: Optional[int] = None, top: int = 5, force: bool = False,
                       say: Optional[Say] = None, simulate: tuple[str, ...] = (), set_: Pairs = None,
                       preset: Optional[str] = None, repeats: int = 3, workers: int = 1,
                       shear_modulus: Optional[float] = None, heaps: int = 0) -> SuggestResult:
    """Rank the conditions a rig can make (``rig``: a TOML file) by the expected information about the
    current model's parameters and the expected separation of each missing effect; writes
    RUN/suggest/ranking.parquet and conditions.csv (the ``top`` ones, ``piles`` rows each). The
    candidates named in ``simulate`` get diagnose's sensitivities simulated there (``repeats`` heaps a
    step, at the parameters diagnose used or ``set_``) instead of extrapolated, in
    RUN/suggest/sensitivities.parquet, and ``heaps`` more each over the posterior's 90 % intervals, which
    the surrogate learns the candidate from where the posterior lies."""
    say = say or plain
    run = check_run_dir(run)
    cfg = resolve_settings(run, None, None)  # read first: a broken settings.toml stops every command, this one too
    the_rig = load_rig(rig)
    piles = int(piles or the_rig.piles)
    simulate = [simulate] if isinstance(simulate, str) else list(simulate)  # one name, not its letters
    _check_options(piles, top, repeats, heaps, bool(simulate),
                   bool(set_ or preset or shear_modulus is not None or repeats != 3 or workers != 1))
    model = load_model(run)
    measured = measured_conditions(run)
    if measured.empty:
        raise CalibError(f"no measured condition in {run}: run `calib measure-angle` first")
    samples = _posterior(run, model)
    # the responses the posterior weighed: with the heap profile, a new condition's profile counts too
    profile = bool(art.read_provenance(run / "posterior" / "summary.parquet").get("profile", False))
    cand = _candidates(the_rig, measured)
    gone = cand.attrs.get("unbuildable", [])
    if gone:
        say(f"[yellow]note:[/] {len(gone)} of the rig's combinations make no heap test (a cylinder under 4 or a fill "
            f"under 2 of the largest grains) and are not ranked: {', '.join(gone[:4])}"
            + (", ..." if len(gone) > 4 else ""))
    if cand.empty:
        raise CalibError(f"every condition the rig file {rig} lists is measured already: list others")
    simulate = sorted(set(simulate))
    rows = model_rows(run, model)
    # a variable the heaps vary and a rig cannot set (a floor's friction): the candidates' heaps and gains need it
    cand = _complete(cand, measured, informative_conditions(rows, COND_VARS))
    # simulated first (a rerun finds them cached): the heaps join what the surrogate and the lock read
    sims = _simulate_candidates(run, cand, simulate, set_, preset, repeats, workers, shear_modulus, say, heaps) \
        if simulate else None
    rows = model_rows(run, model) if simulate else rows
    scale = _scale(run)
    rows = in_box(rows, scale) if scale else rows  # the heaps the posterior's surrogates learnt from
    cond_vars = check_rows(run, rows, model)
    st = stage(run, "suggest", "rank", inputs=_rank_inputs(run, rig, model, rows, cond_vars, profile),
               settings={"piles": piles, "top": top,
                         **({"profiles_at_hand": profiles_at_hand(run, rows)} if profile else {}),
                         **({"simulate": simulate, "repeats": repeats, "set": set_ or [],
                         **({"heaps": heaps} if heaps else {}), "preset": preset, **modulus_settings(shear_modulus),
                         **run_heap_settings(cfg)} if simulate else {})})
    if st.up_to_date() and not force:
        return SuggestResult(st, True, top=top)
    ev, notes = _evidence(run, model, measured, samples)
    gp = model_surrogate(rows, model, scale=scale)
    check_measured(measured, gp, run / "measure" / "conditions.parquet")  # as the posterior refused them
    say(f"ranking {len(cand)} condition(s) the rig can make: the posterior of model revision {model.revision}, "
        f"a Gaussian process on {len(rows)} heaps, {len(ev.G.columns)} candidate effect(s)"
        + ("; each condition's angle and profile, as the posterior weighed them" if profile else ""))
    draws = ev.draws_frame()
    mu, vp, F = _responses(run, rows, model, ev, measured, cand, gp, cond_vars if profile else None, say)
    # the surrogate's uncertainty where it has data: a candidate well above it is an extrapolation
    sd_measured = float(np.sqrt(np.nanmax(_surrogate_at(gp, draws, measured)[1])))
    had = region_heaps(run, cand, art.read_table(run / "posterior" / "summary.parquet"))
    table = rank_conditions(ev, cand.assign(beyond_heaps=_beyond_heaps(gp, cand), region_heaps=had),
                            mu, vp, piles, SUGGEST_VARS, sims, F)
    mean_sd = ev.scatter / math.sqrt(piles)  # the sd of a measured mean
    table["reason"] = _reasons(ev, table, sd_measured, mean_sd, piles)
    notes += _ranking_notes(ev, table, sd_measured, mean_sd, piles,
                            shlex.join(["calib", "suggest-conditions", "--run", str(run), "--rig", str(rig)]))
    notes += _unnamed(run, simulate)
    with st.commit() as out:
        out.text("conditions.csv", _conditions_csv(table, top, piles))
        out.table("ranking.parquet", table, model_revision=model.revision, piles=piles, scatter=ev.scatter,
                  profile=profile)
        if sims is not None:
            # the candidates simulated: a column a step could not give (NaN) keeps its row
            out.table("sensitivities.parquet", cand[["condition_id"]].join(sims).dropna(how="all", subset=list(sims.columns))
                      .reset_index(drop=True))
    return SuggestResult(st, False, table, top, tuple(notes))
