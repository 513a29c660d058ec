"""A Bayesian calibration: the posterior over the current model's parameters given every measured
condition, from a Gaussian-process surrogate trained on all the run's simulated heaps of that model
(calib_cli.posterior)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from .. import artifacts as art  # noqa: E402
from ..campaign import RESULTS, current_results, heap_setups  # noqa: E402
from ..errors import CalibError  # noqa: E402
from ..model import DEFAULT_EFFECTS, EFFECTS, MODEL_FILE, Model, load_model  # noqa: E402
from ..posterior.calibrate import PosteriorResult, SecondResponse, calibrate_posterior, savage_dickey  # noqa: E402
from ..posterior.gp import GPSurrogate, holdout_rmse, informative_conditions  # noqa: E402
from ..posterior.suggest import region_design  # noqa: E402
from ..requests import COND_VARS  # noqa: E402
from .common import Result, Say, check_run_dir, plain, stage, writes_run  # noqa: E402
from .compare import measured_conditions  # noqa: E402
from .profiles import FULLNESS, measured_fullness, profile_inputs, profiles_at_hand, simulated_fullness  # noqa: E402

RESPONSE = "repose_angle"
#: simulated piles per surrogate input (parameter or condition variable) the posterior needs at least:
#: Loeppky, Sacks & Welch (Technometrics 51, 2009) recommend 10 runs per input for a GP
PILES_PER_INPUT = 10
#: Jeffreys' scale for the Bayes factor of an effect off: above 3 substantial evidence it is off, below
#: 1/10 strong evidence it is on
BF_OFF, BF_NEEDED = 3.0, 0.1
#: the prior ranges: each effect's own (`calib model show`), or what the model's heaps cover
PRIORS = ("effects", "heaps")


def model_rows(run: Path, model: Model) -> pd.DataFrame:
    """The simulated piles of the current model (every heap that gave an angle with each absent
    effect's parameter at its neutral value, or unset), with the model's parameters filled in where
    a heap left one unset: a wall's value at the grains' own, another at its neutral value."""
    if not (run / RESULTS).is_file():
        raise CalibError(f"no simulated heaps in {run}: run `calib simulate-heap --run {run}` first")
    rows = current_results(run)
    keep = rows[RESPONSE].notna().to_numpy().copy() if RESPONSE in rows.columns else np.zeros(len(rows), bool)
    for name, eff in EFFECTS.items():
        if name not in model.effects and eff.parameter in rows.columns:
            v = rows[eff.parameter]
            keep = keep & (v.isna() | (v == eff.neutral)).to_numpy()
    rows = rows[keep].copy()
    for name in model.effects:
        eff = EFFECTS[name]
        tied = eff.parameter.replace("wall_", "") if eff.two_sided else None
        col = rows[eff.parameter] if eff.parameter in rows.columns else pd.Series(np.nan, index=rows.index)
        rows[eff.parameter] = col.fillna(rows[tied] if tied in rows.columns else eff.neutral)
    setups = heap_setups(rows)
    if len(setups) > 1:
        raise CalibError(f"the heaps of model revision {model.revision} in {run} were simulated with {len(setups)} "
                         f"setups ({'; '.join(setups)}), which one surrogate would mix: keep one preset and shear "
                         "modulus per run directory")
    return rows.reset_index(drop=True)


def _check_rows(run: Path, rows: pd.DataFrame, model: Model) -> list[str]:
    """The condition variables the surrogate learns; refuses a parameter the heaps never varied and
    fewer piles than PILES_PER_INPUT per input."""
    flat = [p for p in model.parameters if rows[p].nunique() < 2]
    if flat:
        vals = ", ".join(f"{p} = {rows[p].iloc[0]:g}" for p in flat) if len(rows) else "no heaps"
        raise CalibError(f"every simulated heap of model revision {model.revision} in {run} has the same "
                         f"{', '.join(flat)} ({vals}): the surrogate cannot learn its effect; simulate a design "
                         "that varies it (`calib bbd design`, `calib simulate-heap --design`)")
    conds = informative_conditions(rows, COND_VARS)
    need = PILES_PER_INPUT * (len(model.parameters) + len(conds))
    if len(rows) < need:
        raise CalibError(f"{run} has {len(rows)} simulated heaps of model revision {model.revision}; the posterior's "
                         f"surrogate needs at least {need} ({PILES_PER_INPUT} per input: {len(model.parameters)} "
                         f"parameters + {len(conds)} condition variables): simulate more heaps")
    return conds


def _check_measured(conds: pd.DataFrame, gp: GPSurrogate, path: Path) -> None:
    """Refuse a measured condition the surrogate would extrapolate to: outside the simulated range of
    a condition variable it learnt, or off the value every simulated heap shared."""
    ids = conds["condition_id"].astype(str)
    for c, (lo, hi) in gp.condition_ranges().items():
        if c not in conds.columns:
            raise CalibError(f"{path} has no {c} column, which the simulated heaps vary: measure-angle's "
                             "conditions table must give it")
        out = ~conds[c].between(lo, hi)
        if out.any():
            raise CalibError(f"condition(s) {', '.join(ids[out])} have {c} outside the simulated heaps' "
                             f"{lo:g} to {hi:g}: simulate heaps under them first")
    for c, val in gp.constants_.items():
        off = conds[c].notna() & ~np.isclose(conds[c], val) if c in conds.columns else pd.Series(False)
        if off.any():
            raise CalibError(f"condition(s) {', '.join(ids[off])} have {c} other than the {val:g} of every "
                             "simulated heap: simulate heaps under them first")


def _corner(samples: pd.DataFrame, table: pd.DataFrame):
    """Every pair of parameters' draws (2-D histograms), each one's own on the diagonal with its 90 %
    interval, each axis over the parameter's whole prior range."""
    names = list(table["parameter"])
    d = len(names)
    fig, axes = plt.subplots(d, d, figsize=(2.3 * d + 0.5, 2.3 * d + 0.5), squeeze=False)
    lim = {r.parameter: (r.low, r.high) for r in table.itertuples()}
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples[a], bins=40, range=lim[a], color="0.4")
                for q in ("q05", "q95"):
                    ax.axvline(table.loc[i, q], color="tab:red", ls="--", lw=1)
                ax.set_yticks([])
            else:
                ax.hist2d(samples[b], samples[a], bins=40, range=[lim[b], lim[a]], cmap="Greys")
                ax.set_ylim(lim[a])
            ax.set_xlim(lim[b])
            ax.set_xlabel(b if i == d - 1 else "")
            ax.set_ylabel(a if j == 0 and i > 0 else "")
    fig.suptitle("posterior draws over the prior ranges (dashed: 90 % interval)")
    fig.tight_layout()
    return fig


def _verdicts(table: pd.DataFrame, samples: pd.DataFrame) -> pd.DataFrame:
    """Each parameter's verdict in words, and for an effect the model gained (not a default one) its
    neutral value, where it is off, with the Bayes factor of "off" against the posterior (``bf_off``)."""
    owner = {e.parameter: e for e in EFFECTS.values()}
    added = [owner[p] if owner[p].name not in DEFAULT_EFFECTS and not owner[p].two_sided else None
             for p in table["parameter"]]
    table = table.assign(neutral=[e.neutral if e else math.nan for e in added])
    table["bf_off"] = [savage_dickey(samples[r.parameter], r.neutral, r.low, r.high)
                       if e and r.low <= r.neutral <= r.high else math.nan for r, e in zip(table.itertuples(), added)]
    words = []
    for r in table.itertuples():
        w = (f"identified: 90 % between {r.q05:.3g} and {r.q95:.3g} ({100 * r.rel_width:.0f} % of its range)"
             if r.identified else f"not identified: its 90 % interval {r.q05:.3g} to {r.q95:.3g} spans "
             f"{100 * r.rel_width:.0f} % of its range")
        if not math.isnan(r.bf_off):
            name = owner[r.parameter].name
            say = ("the data call for it" if r.bf_off < BF_NEEDED else "the data favour it off"
                   if r.bf_off > BF_OFF else "the data do not decide")
            w += f"; {name} off ({r.parameter} = {r.neutral:g}) against on: Bayes factor {r.bf_off:.2g}, {say}"
        words.append(w)
    table["verdict"] = words
    return table


@dataclass
class PosteriorStageResult(Result):
    """RUN/posterior/: the per-parameter ``table`` (summary.parquet), the held-out RMSE of the
    surrogates (``surrogates``), the posterior draws (``samples``) and the model's revision."""

    table: Optional[pd.DataFrame] = None
    surrogates: Optional[pd.DataFrame] = None
    samples: Optional[pd.DataFrame] = None
    revision: int = 0

    def __post_init__(self):
        if self.table is None and (self.dir / "summary.parquet").is_file():
            self.table = art.read_table(self.dir / "summary.parquet")
            self.surrogates = art.read_table(self.dir / "surrogates.parquet")
            self.samples = art.read_table(self.dir / "samples.parquet")
            self.revision = int(art.read_provenance(self.dir / "summary.parquet").get("model_revision", 0))

    def summary(self) -> pd.DataFrame:
        """Per parameter: median, 90 % interval, its width over the prior range, the verdicts, and
        the chains' autocorrelation time and whether they are long enough for it."""
        return self.table[["parameter", "median", "q05", "q95", "rel_width", "identified", "bf_off",
                           "autocorr_time", "chain_ok"]]

    def conclusion(self) -> list[str]:
        t = self.table
        out = [f"[bold]{r.parameter}[/]: {r.verdict}" for r in t.itertuples()]
        acc = t["acceptance"].iloc[0]
        out.append(f"acceptance fraction {acc:.2f}" + (" (below 0.1: walkers are stuck; look at corner.png)"
                                                       if acc < 0.1 else ""))
        if not t["chain_ok"].all():
            out.append(f"[yellow]warning:[/] the chains are shorter than 50 autocorrelation times "
                       f"(longest {t['autocorr_time'].max():.0f} steps): the intervals are rough; rerun with "
                       "more --steps")
        return out


def _note_extrapolation(rows: pd.DataFrame, model: Model, say: Say) -> None:
    """Name the parameters whose prior range the heaps cover less than 80 % of."""
    short = [f"{e.parameter} {rows[e.parameter].min():.3g} to {rows[e.parameter].max():.3g} of {e.low:g} to {e.high:g}"
             for e in (EFFECTS[n] for n in model.effects)
             if np.ptp(rows[e.parameter].to_numpy(float)) < 0.8 * (e.high - e.low)]
    if short:
        say(f"[yellow]note:[/] the heaps cover {'; '.join(short)}: beyond them the surrogate knows nothing, and "
            "the posterior there stays as wide as the prior (--prior heaps keeps it to what the heaps cover)")


def _note_scatter(gp: GPSurrogate, scatter: bool, say: Say) -> None:
    """Say whether the piles' scatter is evidence: only where the simulated piles' scatter changes with
    the parameters (the surrogate's scatter model), and only when asked, since it assumes the lab's
    piles scatter as the simulated ones do."""
    if scatter and gp.scatter_ is None:
        say("[yellow]note:[/] the simulated piles scatter alike over every parameter, so the lab's scatter tells "
            "nothing about them: only the measured means are used")
    elif scatter:
        say("likelihood: each condition's mean angle and its piles' scatter (the simulated piles' scatter "
            "changes with the parameters)")
    elif gp.scatter_ is not None:
        say("[yellow]note:[/] the simulated piles' scatter changes with the parameters: --scatter makes each "
            "condition's measured scatter evidence too, where the lab's piles scatter as the simulated ones do")


def effect_ranges(model: Model) -> dict[str, tuple[float, float]]:
    """Each of the model's parameters' range (its effect's bounds): the scale of the surrogate's inputs."""
    return {EFFECTS[e].parameter: (EFFECTS[e].low, EFFECTS[e].high) for e in model.effects}


def model_surrogate(rows: pd.DataFrame, model: Model, seed: int = 0, response: str = RESPONSE) -> GPSurrogate:
    """The Gaussian process of the model's heaps (of their ``response``), fitted on every condition column
    the heaps have: it learns the ones that vary and records the ones they all shared (``constants_``),
    at which a measured or suggested condition elsewhere is beyond what it knows."""
    cols = [*model.parameters, *(c for c in COND_VARS if c in rows.columns), response]
    return GPSurrogate(model.parameters, COND_VARS, effect_ranges(model), response, seed=seed).fit(rows[cols])


def _profile_rows(run: Path, rows: pd.DataFrame, model: Model, cond_vars: list[str], say: Say) -> pd.DataFrame:
    """The model's heaps with each one's fullness (:func:`~calib_cli.stages.profiles.simulated_fullness`);
    refuses fewer heaps with one than the surrogate needs (PILES_PER_INPUT per input)."""
    rows = rows.assign(**{FULLNESS: simulated_fullness(run, rows)})
    have = int(np.isfinite(rows[FULLNESS]).sum())
    need = PILES_PER_INPUT * (len(model.parameters) + len(cond_vars))
    if have < need:
        raise CalibError(f"only {have} of the {len(rows)} simulated heaps have a profile (a side view whose heap "
                         f"could be measured; a committed sample run keeps its rows, not its heaps' folders); the "
                         f"profile's surrogate needs at least {need}: simulate more heaps, or drop --profile")
    if have < len(rows):
        say(f"the profile's surrogate learns from the {have} of {len(rows)} heaps whose side view is at hand")
    return rows


def _second_response(run: Path, rows: pd.DataFrame, model: Model, conds: pd.DataFrame, seed: int,
                     say: Say) -> SecondResponse:
    """The heap profile's fullness as a second response: its surrogate and each condition's measured mean."""
    table, rho = measured_fullness(run, conds)
    gp = model_surrogate(rows, model, seed, FULLNESS)
    _check_measured(conds, gp, run / "measure" / "conditions.parquet")  # its heaps may cover less than the angle's
    say(f"profile: each condition's photographs' mean fullness is evidence beside its angle (a photograph's two "
        f"correlate at {rho:+.2f} within a condition; a simulated pile's fullness scatters by {gp.noise_sd_:.3f})")
    return SecondResponse(gp, table["mean"].to_numpy(float), table["sd"].to_numpy(float),
                          table["n"].to_numpy(float), rho)


def _held_out(used: pd.DataFrame, params: list[str], scale, seed: int, profile: bool) -> pd.DataFrame:
    """The surrogates' held-out RMSE per pile (:func:`holdout_rmse`), of the angle and, with ``profile``,
    of the fullness (on the heaps that have one)."""
    held = holdout_rmse(used, params, COND_VARS, scale, RESPONSE, seed=seed).assign(response=RESPONSE)
    if not profile:
        return held
    full = holdout_rmse(used, params, COND_VARS, scale, FULLNESS, seed=seed).assign(response=FULLNESS)
    return pd.concat([held, full], ignore_index=True)


@writes_run
def posterior(run: Path, walkers: int = 32, steps: int = 5000, seed: int = 0, prior: str = "effects",
              force: bool = False, say: Optional[Say] = None, design: int = 0,
              scatter: bool = False, profile: bool = False) -> PosteriorStageResult:
    """Sample the posterior of the current model's parameters given every measured condition, through a
    Gaussian process trained on the run's simulated heaps of the model; the prior is uniform over each
    effect's range (``prior="effects"``) or over the range the heaps cover (``"heaps"``). Writes
    RUN/posterior/samples.parquet, summary.parquet, surrogates.parquet (held-out RMSE of the GP,
    RSM and BP network) and corner.png; with ``design`` N, also design.parquet: N points over the 90 % box
    (:func:`~calib_cli.posterior.suggest.region_design`) for ``simulate-heap --design``. With
    ``scatter``, each condition's measured pile scatter is evidence as well as its mean; with
    ``profile``, each condition's mean profile fullness (:mod:`~calib_cli.stages.profiles`)."""
    say = say or plain
    run = check_run_dir(run)
    if prior not in PRIORS:
        raise CalibError(f"--prior must be one of {', '.join(PRIORS)}, got {prior!r}")
    model = load_model(run)
    conds = measured_conditions(run)
    if conds.empty:
        raise CalibError(f"no measured condition in {run / 'measure' / 'conditions.parquet'}: "
                         "run `calib measure-angle` first")
    rows = model_rows(run, model)
    cond_vars = _check_rows(run, rows, model)
    params = model.parameters
    scale = effect_ranges(model)
    bounds = scale if prior == "effects" else {p: (float(rows[p].min()), float(rows[p].max())) for p in params}
    used = rows[[*params, *cond_vars, RESPONSE]]
    mfile = run / MODEL_FILE
    # a heap's fullness follows from its run hash (its side view) and the code's version: the rows and how many
    # of them have one stand for it
    st = stage(run, "posterior", "sample",
               inputs={"results": art.Rows(run / RESULTS, used), "conditions": run / "measure" / "conditions.parquet",
                       "model": mfile if mfile.is_file() else None, **(profile_inputs(run) if profile else {})},
               settings={"walkers": walkers, "steps": steps, "seed": seed, "model": model.hash, "bounds": bounds,
                         **({"design": design} if design else {}), **({"scatter": True} if scatter else {}),
                         **({"profile": True, "profiles_at_hand": profiles_at_hand(run, rows)} if profile else {})})
    if st.up_to_date() and not force:
        return PosteriorStageResult(st, True)
    if profile:
        rows = _profile_rows(run, rows, model, cond_vars, say)
        used = rows[[*params, *cond_vars, RESPONSE, FULLNESS]]
    if prior == "effects":
        _note_extrapolation(rows, model, say)
    say(f"posterior of model revision {model.revision} ({', '.join(params)}): a Gaussian process on {len(rows)} "
        f"simulated heaps, {len(conds)} measured condition(s), {walkers} walkers x {steps} steps")
    gp = model_surrogate(rows, model, seed)
    _check_measured(conds, gp, run / "measure" / "conditions.parquet")
    _note_scatter(gp, scatter, say)
    second = _second_response(run, rows, model, conds, seed, say) if profile else None
    held = _held_out(used, params, scale, seed, profile)
    post: PosteriorResult = calibrate_posterior(gp, conds, bounds, n_walkers=walkers, n_steps=steps, seed=seed,
                                                scatter=scatter, second=second)
    table = _verdicts(post.summary(), post.samples_)
    samples = post.samples_.assign(log_prob=post.log_prob_)
    with st.commit() as out:
        out.table("samples.parquet", samples, discard=post.discard_, thin=post.thin_)
        out.table("surrogates.parquet", held)
        out.figure("corner.png", _corner(post.samples_, table))
        out.table("summary.parquet", table, model_revision=model.revision, model=list(model.effects),
                  noise_sd=gp.noise_sd_, length_scales=gp.length_scales_.to_dict(), heaps=len(rows),
                  scatter=bool(scatter and gp.scatter_ is not None), profile=bool(profile),
                  **({"profile_rho": second.rho, "profile_noise_sd": second.gp.noise_sd_} if second else {}))
        if design:  # run ids after every id the run's heaps already use above 100 (earlier rounds, a design
            # made by hand): each round its own labels
            first = int(max(rows["run_id"].max() if "run_id" in rows.columns else 0, 100)) + 1
            out.table("design.parquet", region_design(table, design, seed, first), model_revision=model.revision)
    return PosteriorStageResult(st, False, table, held, samples, model.revision)
