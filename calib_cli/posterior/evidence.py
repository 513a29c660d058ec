"""What a posterior weighs and how its answer is worded: the model's simulated heaps, the responses'
surrogates (the angle's, and the heap profile's fullness where the photographs and side views give
one), the measured conditions, and the verdicts (identified, an effect called for or favoured off,
or undecided because the surrogate is unsure where the posterior lies).

``fit_posterior`` is what ``calibrate-posterior`` and each round of ``calibrate`` compute; it reads
the run directory and writes nothing (docs/method.md, "The posterior").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pandas as pd

from .. import artifacts as art, pool
from ..conditions import outside_range
from ..heaps.index import RESULTS, current_results, heap_setups
from ..errors import CalibError
from ..measurements import photo_piles
from ..model import DEFAULT_EFFECTS, EFFECTS, Model
from ..heaps.inputs import COND_VARS
from .calibrate import (ColumnShare, PosteriorResult, SecondResponse, _inputs, averaged_draws, bayes_factor_equal,
                        bayes_factor_off, calibrate_posterior, response_variances, summarise)
from .gp import VIEWS_OF, ColumnModel, GPSurrogate, holdout_rmse, informative_conditions, views_of
from .profiles import FULLNESS, asked_for, measured_fullness, profile_inputs, profiles_at_hand, simulated_fullness

RESPONSE = "repose_angle"
#: simulated piles per surrogate input (parameter or condition variable) the posterior needs at least:
#: Loeppky, Sacks & Welch (Technometrics 51, 2009) recommend 10 runs per input for a GP
PILES_PER_INPUT = 10
#: Jeffreys' scale for the Bayes factor of an effect off: above 3 substantial evidence it is off, below
#: 1/10 strong evidence it is on
BF_OFF, BF_NEEDED = 3.0, 0.1
#: the prior ranges: the run's factor table (settings.toml [factors]: the ranges the user declares
#: plausible for the material), each effect's own physical bounds (`calib model show`), or what the
#: model's heaps cover
PRIORS = ("settings", "effects", "heaps")
#: with the settings' prior, heaps this far (a share of each range) beyond it still train the surrogates
BOX_MARGIN = 0.05
#: no verdict while the surrogate's variance at the posterior's draws exceeds the measured means' (its
#: ratio r above this): the posterior's width is then the surrogate's ignorance, not the lab's evidence
SURROGATE_RATIO_MAX = 1.0
#: the posterior draws the surrogate's variance is averaged over: with 256 the ratio of the hidden-effect answer
#: moved by +-0.024 with the draws' seed (0.95 to 1.03, across the bar), with 4,096 by +-0.006 (0.6 s a call)
RATIO_DRAWS = 4096
#: a posterior "presses against" a bound of its prior box when more than EDGE_SHARE of its draws lie in
#: the outer EDGE_BAND of the range there (a flat posterior puts EDGE_BAND there: 4x less)
EDGE_BAND, EDGE_SHARE = 0.025, 0.10

Say = Callable[..., None]


def _quiet(message: str, err: bool = False) -> None:
    pass


# ------------------------------------------------------------------ the heaps and their surrogates
#: the heaps' statuses the column share learns from: those that stood, and those that formed a heap
JUDGED = ("ok", "column")
#: a results row's side views' columns (:mod:`calib_cli.heaps.runner`)
VIEW_COLUMNS = (*VIEWS_OF.values(), "side_views")


def model_rows(run: Path, model: Model, judged: bool = False, views: bool = False) -> pd.DataFrame:
    """The simulated piles of the current model (every heap that gave an angle, or with ``judged`` every
    heap that stood as a column too, with each absent effect's parameter at its neutral value, or
    unset), with the model's parameters filled in where a heap left one unset: a wall's value at the
    grains' own, another at its neutral value. ``views``: keep each heap's side views' means, from which
    the surrogates then learn (:func:`~calib_cli.posterior.gp.views_of`); else one view a heap."""
    if not (run / RESULTS).is_file():
        raise CalibError(f"no simulated heaps in {run}: run `calib calibrate --run {run}` (or simulate-heap) first")
    rows = current_results(run)
    if not views:
        rows = rows.drop(columns=[c for c in VIEW_COLUMNS if c in rows.columns])
    if judged:
        keep = rows["status"].isin(JUDGED).to_numpy().copy() if "status" in rows.columns else np.zeros(len(rows), bool)
    else:
        keep = rows[RESPONSE].notna().to_numpy().copy() if RESPONSE in rows.columns else np.zeros(len(rows), bool)
    for name, eff in EFFECTS.items():
        if name not in model.effects and eff.parameter in rows.columns:
            v = rows[eff.parameter]
            keep = keep & (v.isna() | (v == eff.neutral)).to_numpy()
    # one simulation once: a heap that two designs name (the same run hash) is one pile, not two
    rows = rows[keep]
    if "run_hash" in rows.columns:
        rows = rows[~(rows["run_hash"].notna() & rows["run_hash"].duplicated())]
    rows = rows.copy()
    for name in model.effects:
        eff = EFFECTS[name]
        tied = eff.tied
        col = rows[eff.parameter] if eff.parameter in rows.columns else pd.Series(np.nan, index=rows.index)
        rows[eff.parameter] = col.fillna(rows[tied] if tied in rows.columns else eff.neutral)
    setups = heap_setups(rows)
    if len(setups) > 1:
        raise CalibError(f"the heaps of model revision {model.revision} in {run} were simulated with {len(setups)} "
                         f"setups ({'; '.join(setups)}), which one surrogate would mix: keep one preset and shear "
                         "modulus per run directory")
    return rows.reset_index(drop=True)


def heaps_needed(model: Model, cond_vars: list[str]) -> int:
    """The fewest heaps a surrogate of the model learns from: PILES_PER_INPUT per input."""
    return PILES_PER_INPUT * (len(model.parameters) + len(cond_vars))


def check_rows(run: Path, rows: pd.DataFrame, model: Model) -> list[str]:
    """The condition variables the surrogate learns; refuses a parameter the heaps never varied and
    fewer piles than PILES_PER_INPUT per input."""
    flat = [p for p in model.parameters if rows[p].nunique() < 2]
    if flat:
        vals = ", ".join(f"{p} = {rows[p].iloc[0]:g}" for p in flat) if len(rows) else "no heaps"
        raise CalibError(f"every simulated heap of model revision {model.revision} in {run} has the same "
                         f"{', '.join(flat)} ({vals}): the surrogate cannot learn its effect; run `calib calibrate`, "
                         "which designs heaps that vary it")
    conds = informative_conditions(rows, COND_VARS)
    need = heaps_needed(model, conds)
    if len(rows) < need:
        raise CalibError(f"{run} has {len(rows)} simulated heaps of model revision {model.revision}; the posterior's "
                         f"surrogate needs at least {need} ({PILES_PER_INPUT} per input: {len(model.parameters)} "
                         f"parameters + {len(conds)} condition variables): simulate more heaps (`calib calibrate`)")
    return conds


def check_measured(conds: pd.DataFrame, gp: GPSurrogate, path: Path) -> None:
    """Refuse a measured condition the surrogate would extrapolate to: outside the simulated range of
    a condition variable it learnt, or off the value every simulated heap shared."""
    ids = conds["condition_id"].astype(str)
    for c, off, why in beyond_heaps(conds, gp):
        if why is None:
            raise CalibError(f"{path} has no {c} column, which the simulated heaps vary: measure-angle's "
                             "conditions table must give it")
        if off.any():
            raise CalibError(f"condition(s) {', '.join(ids[off])} have {c} {why}: simulate heaps under them first")


def beyond_heaps(conds: pd.DataFrame, gp: GPSurrogate):
    """Per condition variable the surrogate knows, (variable, which of ``conds`` lie beyond its heaps, why):
    outside a learnt variable's simulated range, or off the value every simulated heap shared; a learnt
    variable ``conds`` lack puts every one beyond (why None)."""
    for c, (lo, hi) in gp.condition_ranges().items():
        if c not in conds.columns:
            yield c, np.ones(len(conds), bool), None
        else:
            yield c, outside_range(conds[c], lo, hi), f"outside the simulated heaps' {lo:g} to {hi:g}"
    for c, val in gp.constants_.items():
        if c in conds.columns:
            yield c, (conds[c].notna() & ~np.isclose(conds[c], val)).to_numpy(), \
                f"other than the {val:g} of every simulated heap"


def effect_ranges(model: Model) -> dict[str, tuple[float, float]]:
    """Each of the model's parameters' range (its effect's bounds): the prior and the surrogate's scale."""
    return {EFFECTS[e].parameter: (EFFECTS[e].low, EFFECTS[e].high) for e in model.effects}


def model_surrogate(rows: pd.DataFrame, model: Model, seed: int = 0, response: str = RESPONSE,
                    scale: Optional[dict] = None) -> GPSurrogate:
    """The Gaussian process of the model's heaps (of their ``response``), fitted on every condition column
    the heaps have: it learns the ones that vary and records the ones they all shared (``constants_``),
    at which a measured or suggested condition elsewhere is beyond what it knows. Each parameter is
    scaled by ``scale`` (the prior's ranges; default each effect's own)."""
    cols = [*model.parameters, *(c for c in COND_VARS if c in rows.columns)]
    gp = GPSurrogate(model.parameters, COND_VARS, scale or effect_ranges(model), seed=seed)
    return gp.fit(rows[cols], rows[response], views_of(rows, response))


def settings_ranges(cfg: dict) -> dict[str, tuple[float, float]]:
    """The factor table's ranges of a run's settings (``[factors]``): the prior the user declares."""
    return {k: (float(v["low"]), float(v["high"])) for k, v in cfg.get("factors", {}).items()}


def in_box(rows: pd.DataFrame, bounds: dict[str, tuple[float, float]], margin: float = BOX_MARGIN) -> pd.DataFrame:
    """The heaps within the prior's box (widened by ``margin`` of each range): a surrogate of a narrow
    prior learns nothing from heaps in other regimes of the heap (fills that stand, grains that bounce
    off), only their misfit."""
    keep = np.ones(len(rows), bool)
    for p, (lo, hi) in bounds.items():
        pad = margin * (hi - lo)
        keep &= rows[p].between(lo - pad, hi + pad).to_numpy()
    return rows[keep].reset_index(drop=True)


# ------------------------------------------------------------------ the heap profile
def profile_rows(run: Path, rows: pd.DataFrame, model: Model, cond_vars: list[str], say: Say = _quiet,
                 need: Optional[int] = None) -> pd.DataFrame:
    """The model's heaps with each one's fullness (:func:`~calib_cli.posterior.profiles.simulated_fullness`);
    refuses fewer heaps with one than the surrogate needs (PILES_PER_INPUT per input)."""
    rows = rows.assign(**{FULLNESS: simulated_fullness(run, rows)})
    have = int(np.isfinite(rows[FULLNESS]).sum())
    need = heaps_needed(model, cond_vars) if need is None else need
    if have < need:
        raise CalibError(f"only {have} of the {len(rows)} simulated heaps have a profile (a side view whose heap "
                         f"could be measured; a committed sample run keeps its rows, not its heaps' folders); the "
                         f"profile's surrogate needs at least {need}: simulate more heaps")
    if have < len(rows):
        say(f"the profile's surrogate learns from the {have} of {len(rows)} heaps whose side view is at hand")
    return rows


def profile_available(run: Path, rows: pd.DataFrame, model: Model, cond_vars: list[str]) -> str:
    """Why the heap profile cannot be evidence here ("" where it can): no photographs' profiles, or
    too few heaps with a fullness."""
    try:
        profile_inputs(run)
        prof = pd.read_parquet(run / "measure" / "profiles.parquet", columns=["image"])
    except (CalibError, OSError, ValueError):
        return "the angles were not measured on photographs here (no measure/profiles.parquet)"
    if prof.empty:
        return "the angles were given as a table, not measured on photographs"
    have = int(np.isfinite(simulated_fullness(run, rows)).sum())
    need = heaps_needed(model, cond_vars)
    return "" if have >= need else f"only {have} of {len(rows)} simulated heaps have a side view's profile ({need} needed)"


def second_response(run: Path, rows: pd.DataFrame, model: Model, conds: pd.DataFrame, seed: int,
                    say: Say = _quiet, scale: Optional[dict] = None) -> SecondResponse:
    """The heap profile's fullness as a second response: its surrogate and each condition's measured mean."""
    table, rho = measured_fullness(run, conds)
    gp = model_surrogate(rows, model, seed, FULLNESS, scale)
    check_measured(conds, gp, run / "measure" / "conditions.parquet")  # its heaps may cover less than the angle's
    say(f"profile: each condition's photographs' mean fullness is evidence beside its angle (a photograph's two "
        f"correlate at {rho:+.2f} within a condition; a simulated pile's fullness scatters by {gp.noise_sd_:.3f}"
        + (f"; its surrogate learns each heap's mean over its side views, which keeps {gp.view_share_:.2f} of that"
           if gp.view_share_ < 1 else "") + ")")
    return SecondResponse(gp, table["mean"].to_numpy(float), table["sd"].to_numpy(float),
                          table["n"].to_numpy(float), rho)


def held_out(used: pd.DataFrame, params: list[str], scale, seed: int, profile: bool,
             which: tuple[str, ...] = ("gp", "rsm", "bp")) -> pd.DataFrame:
    """The surrogates' held-out RMSE per pile (:func:`holdout_rmse`), of the angle and, with ``profile``,
    of the fullness (on the heaps that have one); ``which`` surrogates (none: an empty table)."""
    if not which:
        return pd.DataFrame()
    held = holdout_rmse(used, params, COND_VARS, scale, RESPONSE, seed=seed, which=which).assign(response=RESPONSE)
    if not profile:
        return held
    full = holdout_rmse(used, params, COND_VARS, scale, FULLNESS, seed=seed, which=which).assign(response=FULLNESS)
    return pd.concat([held, full], ignore_index=True)


# ------------------------------------------------------------------ the share of piles that stood as columns
def measured_columns(run: Path, conds: pd.DataFrame) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """Per measured condition (``conds``' order) the piles that stood as columns and the piles judged
    (formed a heap or stood), from the photographs' statuses (RUN/measure/angles.parquet; a pile is its
    ``pile`` where the conditions table gave one, else a photograph); None where the angles were given
    as numbers, not measured on photographs."""
    path = run / "measure" / "angles.parquet"
    if not path.is_file():
        return None
    a = art.read_table(path, columns=["image", "condition_id", "status"], what="measured angles")
    if a.empty or (a.get("message", pd.Series(dtype=str)) == "given").all():
        return None
    a = a.assign(pile=photo_piles(a))[a["status"].isin(JUDGED)]
    piles = a.groupby(["condition_id", "pile"])["status"].agg(lambda s: bool((s == "column").any()))
    per = piles.groupby(level=0).agg(["sum", "count"])
    ids = conds["condition_id"].astype(str)
    per = per.reindex(ids).fillna(0)
    return per["sum"].to_numpy(float), per["count"].to_numpy(float)


def column_share(run: Path, model: Model, gp: GPSurrogate, conds: pd.DataFrame, seed: int = 0,
                 box: Optional[dict] = None, judged: Optional[pd.DataFrame] = None) -> tuple[Optional[ColumnShare], str]:
    """The share of piles that stood as columns as evidence (:class:`ColumnShare`), or None and why not:
    no photographs' statuses, or no simulated heap of the model (within ``box``) stood, or every one did.
    ``judged``: the heaps to learn from (else every judged heap of the model)."""
    lab = measured_columns(run, conds)
    if lab is None:
        return None, "the angles were not measured on photographs"
    if not lab[1].sum():
        return None, "no photographed pile of the measured conditions formed a heap or stood"
    rows = model_rows(run, model, judged=True) if judged is None else judged
    rows = in_box(rows, box) if box is not None and len(rows) else rows
    stands = (rows["status"] == "column").to_numpy() if "status" in rows.columns else np.zeros(0, bool)
    if not stands.any():
        return None, f"none of the model's {len(rows)} simulated fills stood as a column"
    if stands.all():
        return None, "every simulated fill stood as a column"
    if not set(gp.inputs_) <= set(rows.columns):
        return None, "the heaps that stood lack the surrogate's inputs"
    stood, why = _stood_inputs(run, gp)
    return ColumnShare(ColumnModel(gp, seed).fit(rows, stands), *lab, *stood), why


def _stood_inputs(run: Path, gp: GPSurrogate) -> tuple[tuple[dict, np.ndarray], str]:
    """The measured conditions where every pile stood (:func:`~calib_cli.measurements.standing_conditions`) as
    the column share weighs them: their condition inputs and piles; those the simulated heaps do not cover
    (beyond a learnt variable's range, off a shared value) are left out, and the second value says so."""
    from ..measurements import CONDITIONS, standing_conditions

    stood = standing_conditions(run)
    if stood.empty:
        return ({}, np.zeros(0)), ""
    conds = [c for c in gp.inputs_ if c not in gp.parameters]
    full = art.read_table(run / CONDITIONS, what="measured conditions").set_index("condition_id")
    full = full.loc[stood["condition_id"].astype(str)]
    inside = np.ones(len(full), bool)
    for _, off, _ in beyond_heaps(full, gp):
        inside &= ~off
    out = ({c: full.loc[inside, c].to_numpy(float) for c in conds}, stood["piles"].to_numpy(float)[inside])
    left = ", ".join(full.index[~inside].astype(str))
    return out, (f"condition(s) {left}, where every pile stood, lie beyond the simulated heaps and are left out"
                 if left else "")


# ------------------------------------------------------------------ how sure the surrogate is
def surrogate_ratios(gp: GPSurrogate, second: Optional[SecondResponse], measured: pd.DataFrame,
                     samples: pd.DataFrame, draws: int = RATIO_DRAWS, seed: int = 0) -> dict[str, float]:
    """Per response, r = mean over the posterior's draws and the conditions of s_gp^2(theta, c) / v_c:
    the surrogate's own variance of a condition's mean against the measured mean's (v_c, as the
    likelihood takes it); and ``combined``, the r whose measured share 1 / (1 + r) is the responses'
    mean share. r > 1: the surrogate's uncertainty outweighs the measurement's where the posterior lies.
    Averaged over ``draws`` of the posterior's draws (:data:`RATIO_DRAWS`)."""
    names = list(samples.columns.intersection(gp.parameters))
    pick = np.random.default_rng(seed).choice(len(samples), min(draws, len(samples)), replace=False)
    t = samples[names].to_numpy(float)[pick]
    C = len(measured)
    conds = {c: measured[c].to_numpy(float) for c in measured.columns if c in COND_VARS}
    out = {}
    for name, (g, v) in zip((RESPONSE, FULLNESS), response_variances(gp, measured, second)):
        X = _inputs(g, t, names, {}, conds, C).reshape(-1, len(g.inputs_))
        _, sd = g.predict(X, return_std=True)
        out[name] = float(np.mean(sd.reshape(len(t), C) ** 2 / np.maximum(v, 1e-12)[None, :]))
    out["combined"] = float(1.0 / np.mean([1.0 / (1.0 + r) for r in out.values()]) - 1.0)
    return out


# ------------------------------------------------------------------ the verdicts
def verdicts(table: pd.DataFrame, samples: pd.DataFrame, ratio: float = 0.0, prior: str = "settings",
             off: Optional[dict] = None) -> pd.DataFrame:
    """Each parameter's verdict in words, and for an effect the model gained (not a default one) the
    Bayes factor of "off" against the posterior (``bf_off``; ``bf_upper`` where no draw fell near
    the neutral value and it is an upper bound from the effective draws; a wall's off is the grains' own
    value, :func:`_bf_off`). Where the surrogate is
    unsure (``ratio`` above SURROGATE_RATIO_MAX) nothing is called identified, for or against; a
    posterior pressed against a bound of its box that could be wider (``edge``: low/high, see
    :func:`pressed_edge`) is not called identified: its width is the box's, not the data's, and the verdict
    says how to widen the box of this ``prior`` (:data:`PRIORS`). Nor is any other parameter, nor does an
    effect's Bayes factor give a verdict (``box_cut`` names the pressed ones): the likelihood's peak may lie
    beyond the box, and the parameters that trade off with the pressed one sit where they compensate for the
    bound (on the cohesive LAMMPS lab surface energy's interval, 0.22-0.51 J/m2 with static friction and
    restitution at their boxes' tops, missed the truth 0.6; docs/method.md, "A box that cuts the
    posterior"). ``off``: of a posterior averaged over an effect on and off (:func:`averaged`), its parameter,
    name, neutral value, P(off), its interval with the effect on and whether the data favour it off; then
    the averaged interval is the neutral value's: the verdict says so rather than "90 % between 0 and 0",
    and the parameter is not called identified."""
    owner = {e.parameter: e for e in EFFECTS.values()}
    added = [owner[p] if owner[p].name not in DEFAULT_EFFECTS else None for p in table["parameter"]]
    table = table.assign(neutral=[e.neutral if e else math.nan for e in added])
    rows = table.set_index("parameter")
    bfs = [_bf_off(r, e, samples, rows) for r, e in zip(table.itertuples(), added)]
    unsure = bool(ratio > SURROGATE_RATIO_MAX)
    table["bf_off"], table["bf_upper"] = [b for b, _ in bfs], [u for _, u in bfs]
    table["surrogate_ratio"], table["decided"] = float(ratio), not unsure
    table["edge"] = [pressed_edge(samples[r.parameter].to_numpy(float), r.low, r.high, owner.get(r.parameter),
                                  r.neutral) for r in table.itertuples()]
    pressed = table["edge"] != ""
    table["box_cut"] = ", ".join(f"{p} {e}" for p, e in zip(table.loc[pressed, "parameter"],
                                                             table.loc[pressed, "edge"]))
    table["identified"] = table["identified"] & (not unsure) & (not pressed.any())
    if off and off["favoured"]:  # its narrow interval is the off model's neutral value, not an identification
        table.loc[table["parameter"] == off["parameter"], "identified"] = False
    table["verdict"] = [_words(r, owner, unsure, prior, _off_words(r, off, unsure)) for r in table.itertuples()]
    return table


def _bf_off(r, eff, samples: pd.DataFrame, rows: pd.DataFrame) -> tuple[float, bool]:
    """The Bayes factor of the added effect ``eff`` off and whether it is a bound: its parameter at its neutral
    value, or a wall's at the grains' own value calibrated beside it (:func:`bayes_factor_equal`); NaN where
    off lies outside the box, or the grains' value is not calibrated."""
    if eff is None:
        return math.nan, False
    if not eff.two_sided:
        return (bayes_factor_off(samples[r.parameter], r.neutral, r.low, r.high, r.n_eff)
                if r.low <= r.neutral <= r.high else (math.nan, False))
    if eff.tied not in rows.index:
        return math.nan, False
    t = rows.loc[eff.tied]
    n_eff = [n for n in (r.n_eff, t.n_eff) if np.isfinite(n)]
    return bayes_factor_equal(samples[r.parameter], samples[eff.tied], (r.low, r.high), (t.low, t.high),
                              min(n_eff) if n_eff else math.nan)


def _off_words(r, off: Optional[dict], unsure: bool) -> str:
    """For the parameter of an effect the data favour off (``off["favoured"]``: a Bayes factor of off above
    BF_OFF) in a posterior averaged over it (``off``), what its interval is: P(off) of the draws at the
    neutral value, and the interval with the effect on ("off" only where the surrogate is sure); "" for
    any other row."""
    if not (off and off["favoured"] and r.parameter == off["parameter"]):
        return ""
    share = (f"{100 * off['p_off']:.0f} % of the averaged draws sit at {off['neutral']:g} (with {off['effect']} on, "
             f"90 % between {off['q05_on']:.3g} and {off['q95_on']:.3g})")
    return (f"averaged over {off['effect']} on and off, {share}" if unsure
            else f"off with probability {off['p_off']:.2g}, so {share}")


#: the answer's columns a result's ``summary()`` shows (posterior/summary.parquet holds more: ranges, draws'
#: effective size, the surrogate's ratio, each pressed edge)
SUMMARY_COLUMNS = ("parameter", "median", "q05", "q95", "rel_width", "identified", "box_cut", "bf_off",
                   "bf_upper", "autocorr_time", "chain_ok", "verdict")


def summary_view(table: pd.DataFrame) -> pd.DataFrame:
    """A posterior's summary table as a result's ``summary()`` shows it: per parameter its median, 90 %
    interval, width over its range, verdicts, the chains' autocorrelation time and whether they are long
    enough for it (the columns of :data:`SUMMARY_COLUMNS` the table has)."""
    return table[[c for c in SUMMARY_COLUMNS if c in table.columns]]


def edges(table: pd.DataFrame) -> pd.Series:
    """Each parameter's ``edge`` of a summary ("low", "high" or ""; "" throughout in one written before the
    column existed)."""
    if "edge" not in table.columns:
        return pd.Series("", index=table.index, dtype=object)
    return table["edge"].fillna("").astype(str)


def pressed_edge(s: np.ndarray, lo: float, hi: float, effect=None, neutral: float = math.nan) -> str:
    """"low" or "high" where the draws ``s`` crowd a bound of the prior box [lo, hi] (over EDGE_SHARE of
    them in its outer EDGE_BAND) that is neither the ``effect``'s own physical bound nor the ``neutral``
    value of an added effect (its Bayes factor speaks for that one); "" otherwise. Such a posterior is cut by the box: the data may lie
    beyond it, or the model lacks an effect (or its engine differs from the lab's)."""
    band = EDGE_BAND * (hi - lo)
    if len(s) == 0 or not band > 0:
        return ""
    phys_lo, phys_hi = (effect.low, effect.high) if effect is not None else (-math.inf, math.inf)
    for side, bound, near, wider in (("low", lo, s <= lo + band, lo > phys_lo + 1e-12),
                                     ("high", hi, s >= hi - band, hi < phys_hi - 1e-12)):
        if wider and bound != neutral and float(np.mean(near)) > EDGE_SHARE:
            return side
    return ""


def bf_text(bf: float, upper: bool) -> str:
    """A Bayes factor as it can be read: "< 0.037" where no draw fell in the window (its resolution)."""
    return f"< {bf:.2g}" if upper else f"{bf:.2g}"


def _widen(r, prior: str) -> str:
    """How to give a posterior pressed against its box's ``r.edge`` more room, by the prior's kind."""
    if prior == "heaps":  # the box is the heaps' span: only heaps beyond it widen it
        return (f"simulate heaps beyond it (the prior is the span of the heaps at hand; widen factors.{r.parameter}."
                f"{r.edge} in settings.toml and run `calib calibrate`)")
    return f"widen factors.{r.parameter}.{r.edge} in settings.toml and calibrate again"


def _words(r, owner, unsure: bool, prior: str = "settings", off: str = "") -> str:
    if unsure:
        w = (f"undecided: the surrogate is unsure here (its variance at the posterior's draws is {r.surrogate_ratio:.3g}x "
             f"the measured means'); {off or f'90 % between {r.q05:.3g} and {r.q95:.3g}'}: simulate heaps where "
             "the posterior lies (`calib calibrate`)")
    elif r.edge:
        bound = r.low if r.edge == "low" else r.high
        w = (f"at its range's {'lower' if r.edge == 'low' else 'upper'} edge: 90 % between {r.q05:.3g} and "
             f"{r.q95:.3g}, crowding {bound:.3g}; the data may lie beyond it ({_widen(r, prior)}) or the model "
             "lacks an effect")
    elif r.box_cut:
        several = len(cut_pairs(r.box_cut)) > 1
        more = ("simulate heaps beyond " + ("them" if several else "it") if prior == "heaps"
                else f"widen {'those ranges' if several else 'that range'} and calibrate again")
        w = (f"inside this box only: 90 % between {r.q05:.3g} and {r.q95:.3g} ({100 * r.rel_width:.0f} % of its "
             f"range), while the box cuts the posterior at {cut_words(r.box_cut)} ({more})")
    elif off:  # averaged over the effect, which the data favour off (the averaging needs no edge, no cut)
        w = off
    elif r.identified:
        w = f"identified: 90 % between {r.q05:.3g} and {r.q95:.3g} ({100 * r.rel_width:.0f} % of its range)"
    else:
        w = (f"not identified: its 90 % interval {r.q05:.3g} to {r.q95:.3g} spans {100 * r.rel_width:.0f} % "
             "of its range")
    if not math.isnan(r.bf_off):
        name = owner[r.parameter].name
        say = ("undecided" if unsure else "the data call for it" if r.bf_off < BF_NEEDED
               else "the data favour it off" if r.bf_off > BF_OFF and not r.bf_upper
               else "the data do not decide")  # a bound above BF_OFF: no draw near off, nothing favours it
        if r.box_cut and not unsure:
            say = f"no verdict while the box cuts the posterior (inside it: {say})"
        at = owner[r.parameter].tied or f"{r.neutral:g}"
        w += (f"; {name} off ({r.parameter} = {at}) against on: Bayes factor "
              f"{bf_text(r.bf_off, r.bf_upper)}, {say}")
    return w


def cut_pairs(box_cut: str) -> list[tuple[str, str]]:
    """:func:`verdicts`' ``box_cut`` ("static_friction high, restitution low") as (parameter, edge) pairs."""
    return [tuple(q.rsplit(" ", 1)) for q in box_cut.split(", ")] if box_cut else []


def cut_words(box_cut: str) -> str:
    """"static_friction's upper edge" from :func:`verdicts`' ``box_cut`` ("static_friction high"), joined by "and"."""
    said = [f"{p}'s {'lower' if e == 'low' else 'upper'} edge" for p, e in cut_pairs(box_cut)]
    return ", ".join(said[:-1]) + " and " + said[-1] if len(said) > 1 else said[0]


def widen_advice(table: pd.DataFrame) -> str:
    """Where the box cuts a posterior (:func:`verdicts`' ``box_cut``), which ranges to widen; "" where it does not."""
    cut = str(box_cuts(table).iloc[0]) if len(table) else ""
    if not cut:
        return ""
    ranges = ", ".join(f"factors.{p}.{e}" for p, e in cut_pairs(cut))
    return (f"the box cuts the posterior at {cut_words(cut)}: widen {ranges} in settings.toml (within the effect's "
            "bounds, `calib model show`) and calibrate again; the heaps at hand inside the new box are used")


def effect_verdict(bf: float, upper: bool, decided: bool, cut: str = "") -> str:
    """A switchable effect's verdict in one word: on, off, undecided, open (the data do not decide) or cut
    (the box cuts the posterior: ``cut`` is :func:`verdicts`' ``box_cut``); "" without a Bayes factor (no
    effect the model gained)."""
    if not np.isfinite(bf):
        return ""
    if not decided:
        return "undecided"
    if cut:
        return "cut"
    return "on" if bf < BF_NEEDED else "off" if bf > BF_OFF and not upper else "open"


def box_cuts(table: pd.DataFrame) -> pd.Series:
    """Each row's ``box_cut`` of a summary or rounds table ("" in one written before the column existed)."""
    if "box_cut" not in table.columns:
        return pd.Series("", index=table.index, dtype=object)
    return table["box_cut"].fillna("").astype(str)


# ------------------------------------------------------------------ the fit
@dataclass
class PosteriorFit:
    """A posterior of the model's parameters: the per-parameter ``table`` (with verdicts), the ``samples``
    (with their log_prob), the surrogates' held-out errors ``held``, the angle's surrogate ``gp`` and the
    profile's (``second``, or None), the surrogate ratios, and what the likelihood weighed (``evidence``)."""

    model: Model
    table: pd.DataFrame
    samples: pd.DataFrame
    held: pd.DataFrame
    gp: GPSurrogate
    second: Optional[SecondResponse]
    rows: pd.DataFrame
    ratios: dict[str, float]
    evidence: dict = field(default_factory=dict)
    result: Optional[PosteriorResult] = None
    averaged: dict = field(default_factory=dict)

    @property
    def heaps(self) -> int:
        return len(self.rows)

    def provenance(self) -> dict:
        """What summary.parquet's metadata keeps of the fit."""
        s = self.second
        return {"model_revision": self.model.revision, "model": list(self.model.effects),
                "noise_sd": self.gp.noise_sd_, "length_scales": self.gp.length_scales_.to_dict(), "heaps": self.heaps,
                "scatter": bool(self.evidence.get("scatter")), "profile": bool(self.evidence.get("profile")),
                "columns": bool(self.evidence.get("columns")), "prior": self.evidence.get("prior"),
                "bounds": self.evidence.get("bounds"),
                "surrogate_ratios": self.ratios, **({"averaged": self.averaged} if self.averaged else {}),
                **({"profile_rho": s.rho, "profile_noise_sd": s.gp.noise_sd_} if s is not None else {}),
                # only where the surrogates learnt from the heaps' side views' means: older answers keep their metadata
                **({"view_share": self.gp.view_share_} if self.gp.view_share_ < 1 else {}),
                **({"profile_view_share": s.gp.view_share_} if s is not None and s.gp.view_share_ < 1 else {})}


def prior_bounds(model: Model, prior: str, rows: Optional[pd.DataFrame] = None,
                 ranges: Optional[dict] = None) -> dict[str, tuple[float, float]]:
    """The uniform prior's ranges (:data:`PRIORS`): the run's factor table (``ranges``, from
    :func:`settings_ranges`; an effect it lacks takes its own bounds), each effect's own, or what the
    heaps (``rows``) cover."""
    if prior not in PRIORS:
        raise CalibError(f"--prior must be one of {', '.join(PRIORS)}, got {prior!r}")
    own = effect_ranges(model)
    if prior == "effects":
        return own
    if prior == "heaps":
        return {p: (float(rows[p].min()), float(rows[p].max())) for p in model.parameters}
    out = {p: tuple(map(float, (ranges or {}).get(p, own[p]))) for p in model.parameters}
    bad = [p for p, (lo, hi) in out.items() if not (own[p][0] <= lo < hi <= own[p][1])]
    if bad:
        raise CalibError(f"the settings' factor range of {', '.join(bad)} ({'; '.join(f'{out[p][0]:g} to {out[p][1]:g}' for p in bad)}) "
                         f"must lie within the effect's bounds ({'; '.join(f'{own[p][0]:g} to {own[p][1]:g}' for p in bad)}) "
                         "and be increasing")
    return out


def _evidence(run, rows, model, cond_vars, conds, gp, scatter, profile, columns, seed, say, scale, box, judged=None):
    """Which of the scatter, the profile and the column share the likelihood weighs (None: wherever they
    can be), the profile's second response and the column share; says why one is left out."""
    asked = profile
    if profile is None:
        why = profile_available(run, rows, model, cond_vars)
        profile = not why
        if why:
            say(f"[yellow]note:[/] the heap profile is not evidence here: {why}")
    second = None
    if profile:
        try:
            with_profile = profile_rows(run, rows, model, cond_vars, say)
            second = second_response(run, with_profile, model, conds, seed, say, scale)
            rows = with_profile
        except CalibError as e:  # asked for: refused; by default: left out, saying why
            if asked:
                raise asked_for(e) from None
            profile = False
            say(f"[yellow]note:[/] the heap profile is not evidence here: {e}")
    use_scatter = gp.scatter_ is not None and scatter is not False
    if scatter and gp.scatter_ is None:
        say("[yellow]note:[/] the simulated piles scatter alike over every parameter, so the lab's scatter tells "
            "nothing about them: only the measured means are used")
    elif scatter is None and gp.scatter_ is not None:
        say("likelihood: each condition's piles' scatter too (the simulated piles' scatter changes with the "
            "parameters; it assumes the lab's piles scatter as the simulated ones do)")
    share = None
    if columns is not False:
        share, why = column_share(run, model, gp, conds, seed, box, judged)
        if share is None and columns:
            raise CalibError(f"the share of piles that stood as columns cannot be evidence: {why}")
        if share is None:
            say(f"[yellow]note:[/] the share of piles that stood as columns is not evidence here: {why}")
        else:
            wholly = (f", and the {int(share.stood_n.sum())} piles, all standing, of {len(share.stood_n)} condition(s) "
                      "with no angle for it" if len(share.stood_n) else "")
            say(f"likelihood: each condition's share of piles that stood as columns too ({int(share.k.sum())} of "
                f"{int(share.n.sum())} photographed piles{wholly}; {share.model.n_columns_} of {share.model.n_train_} "
                "simulated fills)" + (f"; [yellow]note:[/] {why}" if why else ""))
    return rows, second, share, {"scatter": use_scatter, "profile": bool(profile), "columns": share is not None}


def fit_posterior(run: Path, model: Model, conds: pd.DataFrame, *, walkers: int = 32, steps: int = 5000, seed: int = 0,
                  prior: str = "settings", ranges: Optional[dict] = None, scatter: Optional[bool] = None,
                  profile: Optional[bool] = None, columns: Optional[bool] = None,
                  rows: Optional[pd.DataFrame] = None, held_out_by: tuple[str, ...] = ("gp", "rsm", "bp"),
                  judged: Optional[pd.DataFrame] = None, average: bool = False, views: bool = False,
                  beside: bool = False, say: Say = _quiet) -> PosteriorFit:
    """The posterior of the model's parameters given the measured ``conds``, through Gaussian processes
    on the run's heaps of the model (``rows``: else :func:`model_rows`) under a uniform ``prior``
    (:func:`prior_bounds`; ``ranges`` the run's factor table). With the settings' prior the surrogates
    learn from the heaps in its box and scale each parameter by it. ``scatter`` / ``profile`` /
    ``columns``: weigh each condition's pile scatter / heap profile / share of piles that stood as
    columns too (None: wherever the heaps and photographs allow). ``held_out_by``: the surrogates
    whose held-out error is scored (none: empty). ``judged``: the heaps the column share learns from (those
    that stood too; else every such heap of the model). ``average``: over the effect the model gained, on and
    off (:func:`averaged`). ``views``: the surrogates learn each heap from its side views' mean, where every
    heap recorded them (:func:`model_rows`; ``rows`` given: learnt from whatever view columns they hold).
    ``beside``: score the held-out errors in a second process while the chains run in this one (the same
    numbers, on a second core; docs/performance.md, "The posterior's fits")."""
    rows = model_rows(run, model, views=views) if rows is None else rows
    bounds = prior_bounds(model, prior, rows, ranges)
    scale = bounds if prior == "settings" else effect_ranges(model)
    if prior == "settings":
        inside = in_box(rows, bounds)
        need = heaps_needed(model, informative_conditions(inside, COND_VARS))
        if len(inside) < min(need, len(rows)):
            box = "; ".join(f"{p} {lo:g} to {hi:g}" for p, (lo, hi) in bounds.items())
            raise CalibError(f"only {len(inside)} of the {len(rows)} simulated heaps lie within the prior's ranges "
                             f"(settings.toml [factors]: {box}); the surrogate needs {need}: simulate heaps there "
                             "(`calib calibrate`), or give --prior effects")
        if len(inside) < len(rows):
            say(f"the surrogates learn from the {len(inside)} of {len(rows)} heaps within the prior's ranges")
        rows = inside
    cond_vars = check_rows(run, rows, model)
    params = model.parameters
    gp = model_surrogate(rows, model, seed, scale=scale)
    if gp.view_share_ < 1:
        say(f"the angle's surrogate learns each heap's mean over its side views, which keeps {gp.view_share_:.2f} "
            "of one view's pile-to-pile variance (a photograph's, which the lab's piles are)")
    check_measured(conds, gp, run / "measure" / "conditions.parquet")
    rows, second, share, evidence = _evidence(run, rows, model, cond_vars, conds, gp, scatter, profile, columns,
                                              seed, say, scale, bounds if prior == "settings" else None, judged)
    cols = [*params, *cond_vars, RESPONSE, *([FULLNESS] if second is not None else []),
            *(c for c in VIEW_COLUMNS if c in rows.columns)]
    scored = (rows[cols], params, scale, seed, second is not None, held_out_by)
    with pool.beside(held_out, *scored, spawn=beside and bool(held_out_by)) as pending:
        post = calibrate_posterior(gp, conds, bounds, n_walkers=walkers, n_steps=steps, seed=seed,
                                   scatter=evidence["scatter"], second=second, columns=share)
        held = pending.result()
    ratios = surrogate_ratios(gp, second, conds, post.samples_, seed=seed)
    table = verdicts(post.summary(), post.samples_, ratios["combined"], prior)
    evidence.update(prior=prior, bounds=bounds)
    fit = PosteriorFit(model, table, post.samples_.assign(log_prob=post.log_prob_), held, gp, second, rows, ratios,
                       evidence, post)
    if average:
        fit = averaged(fit, conds, bounds, share, walkers=walkers, steps=steps, seed=seed, say=say)
    return fit


def averaged(fit: PosteriorFit, conds: pd.DataFrame, bounds: dict, share: Optional[ColumnShare], *,
             walkers: int, steps: int, seed: int, say: Say = _quiet) -> PosteriorFit:
    """The posterior averaged over the one effect with a neutral value the model gained (a wall effect stays
    free in both), on and off (Bayesian model averaging,
    even prior odds): P(off | data) = B / (1 + B) with B the Savage-Dickey Bayes factor of "off", and that
    share of the draws from the posterior with the effect's parameter held at its neutral value. Without it,
    a free effect's boundary (surface energy >= 0) pulls the other parameters (rolling friction trades for a
    little cohesion) even where the data favour it off. The Bayes factor and the verdicts stay those of the
    model with the effect free; a bound (no draw near neutral) averages nothing: P(off) < B / (1 + B), nor does
    a Bayes factor the box cuts (:func:`verdicts`: it gives no verdict, so it weighs nothing either)."""
    t = fit.table
    # a wall's "off" is its grains' value, a line in the box, not a value to hold it at: it stays free in both
    eff = t[np.isfinite(t["bf_off"].to_numpy(float)) & np.isfinite(t["neutral"].to_numpy(float))]
    if len(eff) != 1 or bool(eff["bf_upper"].iloc[0]) or str(box_cuts(t).iloc[0]):
        return fit
    r = eff.iloc[0]
    p_off = float(r.bf_off / (1.0 + r.bf_off))
    res = fit.result
    off = calibrate_posterior(fit.gp, conds, {p: b for p, b in bounds.items() if p != r.parameter},
                              fixed={r.parameter: r.neutral}, n_walkers=walkers, n_steps=steps, seed=seed + 1,
                              scatter=fit.evidence["scatter"], second=fit.second, columns=share)
    draws = averaged_draws(fit.samples, off.samples_.assign(**{r.parameter: r.neutral}, log_prob=off.log_prob_),
                           p_off, seed)
    name = next(e.name for e in EFFECTS.values() if e.parameter == r.parameter)
    said = {"parameter": r.parameter, "effect": name, "neutral": float(r.neutral), "p_off": p_off,
            "q05_on": float(r.q05), "q95_on": float(r.q95), "favoured": bool(r.bf_off > BF_OFF)}
    table = verdicts(summarise(draws, bounds, t), res.samples_, fit.ratios["combined"],
                     fit.evidence.get("prior", "settings"), off=said)
    table["p_off"] = np.where(table["parameter"] == r.parameter, p_off, np.nan)
    own = not said["favoured"]  # else its verdict says so already
    table["verdict"] = [w + (f"; the intervals average {name} on and off (probability off {p_off:.2g})"
                             if p == r.parameter and own else "") for p, w in zip(table["parameter"], table["verdict"])]
    say(f"the answer averages {name} on and off: the data give it off a probability of {p_off:.2g}")
    info = {"effect": name, "parameter": r.parameter, "p_off": p_off, "neutral": float(r.neutral)}
    return replace(fit, table=table, samples=draws, averaged=info)


def most_probable(samples: pd.DataFrame, params: list[str]) -> pd.DataFrame:
    """The most probable draw (one row of ``params``); of an averaged posterior, the more probable model's
    (log densities of the model with and without the effect are not comparable)."""
    if "off" in samples.columns and samples["off"].any():
        keep = samples["off"] == (samples["off"].mean() > 0.5)
        samples = samples[keep] if keep.any() else samples
    return samples.loc[[samples["log_prob"].idxmax()], params].reset_index(drop=True)


def extrapolation_note(rows: pd.DataFrame, model: Model, bounds: dict[str, tuple[float, float]]) -> str:
    """Names the parameters whose prior range the heaps cover less than 80 % of ("" if none)."""
    short = [f"{p} {rows[p].min():.3g} to {rows[p].max():.3g} of {lo:g} to {hi:g}" for p, (lo, hi) in bounds.items()
             if np.ptp(np.clip(rows[p].to_numpy(float), lo, hi)) < 0.8 * (hi - lo)]
    return (f"[yellow]note:[/] the heaps cover {'; '.join(short)}: beyond them the surrogate knows nothing, and the "
            "posterior there stays as wide as the prior (`calib calibrate` simulates heaps over the whole prior)"
            if short else "")


def write_posterior(out, fit: PosteriorFit, prefix: str = "") -> None:
    """The posterior's artefacts through a stage's staging writer (:meth:`~calib_cli.artifacts.Stage.commit`):
    samples.parquet, surrogates.parquet, corner.png and summary.parquet (each name after ``prefix``)."""
    from ..plots import corner

    res = fit.result
    out.table(f"{prefix}samples.parquet", fit.samples, discard=res.discard_, thin=res.thin_)
    out.table(f"{prefix}surrogates.parquet", fit.held)
    out.figure(f"{prefix}corner.png", corner(fit.samples.drop(columns=["log_prob", "off"], errors="ignore"), fit.table))
    out.table(f"{prefix}summary.parquet", fit.table, **fit.provenance())


def evidence_lock(run: Path, model: Model, rows: pd.DataFrame, profile: Optional[bool],
                  columns: Optional[bool] = None, judged: Optional[pd.DataFrame] = None) -> tuple[dict, dict]:
    """The lock inputs and settings of a stage that may weigh the heap profile and the column share: the
    measured files they read, how many heaps have a profile (heaps whose side views arrive later rerun
    the stage) and how many stood as columns (of ``judged``, else of every heap of the model). With
    ``profile`` / ``columns`` None, wherever they can be. A model with a wall effect names the version of its
    Bayes factor (:func:`_bf_off`): its locks from before walls had one are stale, every other lock stays."""
    inputs, settings = {}, {"profile": profile, "columns": columns}
    if any(EFFECTS[e].two_sided for e in model.effects):
        settings["wall_bayes_factor"] = 1
    angles = run / "measure" / "angles.parquet"
    if profile is not False:
        try:
            inputs.update(profile_inputs(run))
            settings["profiles_at_hand"] = profiles_at_hand(run, rows)
        except CalibError as e:
            if profile:
                raise asked_for(e) from None
    if columns is not False and angles.is_file():
        inputs["angles"] = angles
        judged = model_rows(run, model, judged=True) if judged is None else judged
        settings["columns_at_hand"] = int((judged["status"] == "column").sum()) if "status" in judged.columns else 0
    return inputs, settings
