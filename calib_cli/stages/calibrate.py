"""`calib calibrate`: the whole calibration in rounds. Round 0 simulates a space-filling design over the
model's parameters and the measured conditions; each round then fits the posterior (every condition's
mean angle, its piles' scatter and its heap profile, as far as the heaps and photographs allow), and
the next round simulates where the surrogates are least sure about it, until the intervals and
verdicts stop moving or the heap budget is spent (calib_cli.posterior.adaptive, docs/method.md).

Every round is a locked stage under RUN/calibrate/rev<N>/round-<k>/: a rerun reads the finished ones,
and a kill loses only the heaps in flight (the campaign caches each finished heap). Every heap the
model's posterior can use counts, whichever command simulated it: revision 0's heaps, compare's and
diagnose's are reused after ``model add``.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..heaps.index import RESULTS, heap_setups
from ..heaps.keys import Request
from ..heaps.runner import check_dask, run_campaign
from ..errors import CalibError
from ..measurements import CONDITIONS, measured_conditions
from ..model import MODEL_FILE, Model, load_model
from ..posterior.adaptive import RULES, acquire, first_design, reference_round, stop_reason
from ..posterior.calibrate import check_sampler, response_variances
from ..posterior.evidence import (FULLNESS, RESPONSE, PosteriorFit, box_cuts, effect_verdict, evidence_lock,
                                  fit_posterior, heaps_needed, in_box, model_rows, model_surrogate, most_probable,
                                  prior_bounds, profile_rows, second_response, settings_ranges, summary_view,
                                  write_posterior)
from ..posterior.gp import informative_conditions
from ..heaps.inputs import (COND_VARS, check_engine, condition_from_row, content_seed, heap_engine, heap_precision,
                            heap_preset, heap_setup, modulus_settings, precision_note, run_heap_settings)
from .common import Result, Say, check_run_dir, plain, resolve_settings, stage, writes_run

#: the results rows' design label of every heap a calibration's rounds simulate
DESIGN = "calibrate"


@dataclass(frozen=True)
class Plan:
    """A calibration's settings: the heap budget, round 0's and each later round's heaps, piles per design
    pair, the acquisition rule, the sampler's walkers and steps, the seed, and the evidence weighed
    (None: wherever it can be)."""

    budget: int
    first: int
    batch: int
    repeats: int = 2
    rule: str = "variance"
    walkers: int = 32
    steps: int = 2000
    seed: int = 0
    scatter: Optional[bool] = None
    profile: Optional[bool] = None
    columns: Optional[bool] = None
    bounds: dict = field(default_factory=dict)  # the prior: the run's factor table
    views: bool = False  # the surrogates learn each heap from its side views' mean
    span: int = 0  # heaps the stop rule looks back over: a default batch's round (0: this plan's batch)
    beside: bool = False  # the held-out scores in a second process beside the chains (more than one worker)

    def round_settings(self, model: Model) -> dict:
        """What a round's design and posterior depend on (not the budget: a larger budget goes on from
        the rounds a smaller one finished)."""
        return {"first": self.first, "batch": self.batch, "repeats": self.repeats, "rule": self.rule,
                "walkers": self.walkers, "steps": self.steps, "seed": self.seed, "scatter": self.scatter,
                "profile": self.profile, "columns": self.columns, "model": model.hash,
                "bounds": {k: list(v) for k, v in self.bounds.items()},
                # only where asked: the rounds locked before views were an option stay up to date
                **({"views": True} if self.views else {})}


@dataclass
class Round:
    """One round: its ``design`` (pairs, each simulated ``repeats`` times), the posterior after it
    (``table``, ``samples``, the surrogates' held-out errors ``held`` and variance ratios ``ratios``), the
    heaps that posterior learnt from, and ``fit`` where it was computed in this process."""

    index: int
    rule: str
    design: pd.DataFrame
    table: pd.DataFrame
    samples: pd.DataFrame
    held: pd.DataFrame
    ratios: dict
    heaps: int
    evidence: dict = field(default_factory=dict)
    fit: Optional[PosteriorFit] = None
    spent: int = 0  # the heaps this calibration simulated up to this round, top-up rounds included


@dataclass
class CalibrateResult(Result):
    """RUN/calibrate/: ``rounds`` (one row per round and parameter), the final posterior ``table``, why
    the rounds stopped, the model's revision, and the heaps: the posterior's and this calibration's."""

    rounds: Optional[pd.DataFrame] = None
    table: Optional[pd.DataFrame] = None
    stop: str = ""
    revision: int = 0
    elsewhere: bool = False  # a step for another model revision: nothing to show
    answer: str = "posterior/summary.parquet"  # the file ``table`` was read from, in the run directory

    def __post_init__(self):
        if self.rounds is None and not self.elsewhere and (self.dir / "rounds.parquet").is_file():
            rounds = art.read_table(self.dir / "rounds.parquet")
            self.revision = int(art.read_provenance(self.dir / "rounds.parquet").get("model_revision", 0))
            self.rounds = rounds[rounds["revision"] == self.revision].reset_index(drop=True)
            self.table = art.read_table(self.run_posterior / "summary.parquet")
            self.stop = str(self.rounds["stop"].iloc[-1]) if len(self.rounds) else ""

    def at_revision(self, revision: int) -> "CalibrateResult":
        """The run's calibration of model ``revision`` as its rounds left it: its rounds and, for an earlier
        revision, its last round's posterior (posterior/ holds the current revision's answer)."""
        if revision == self.revision:
            return self
        every = art.read_table(self.dir / "rounds.parquet")
        rounds = every[every["revision"] == revision].reset_index(drop=True)
        if rounds.empty:
            raise CalibError(f"{self.dir} holds no calibration of model revision {revision}")
        last = _round_dir(self.stage.run_dir, revision, int(rounds["round"].max())) / "summary.parquet"
        answer = last.relative_to(self.stage.run_dir).as_posix()
        return CalibrateResult(self.stage, rounds=rounds, table=art.read_table(self.stage.run_dir / answer),
                               stop=str(rounds["stop"].iloc[-1]), revision=revision, answer=answer)

    @property
    def run_posterior(self) -> Path:
        return self.stage.run_dir / "posterior"

    def summary(self) -> pd.DataFrame | str:
        """The answer: per parameter its median, 90 % interval, verdicts and the chains' length (the columns of
        posterior/summary.parquet that ``calibrate-posterior``'s result shows too); for a step of another model
        revision, what it did."""
        return summary_view(self.table) if self.table is not None else super().summary()

    def per_round(self) -> pd.DataFrame:
        """A row per round: heaps, the interval of each parameter and the effects' Bayes factors."""
        r = self.rounds
        wide = r.assign(interval=[f"{a:.3g}-{b:.3g}" for a, b in zip(r["q05"], r["q95"])]).pivot_table(
            index="round", columns="parameter", values="interval", aggfunc="first", sort=False)
        head = r.groupby("round", sort=True)[["new_heaps", "heaps", "surrogate_ratio"]].first()
        return head.join(wide).reset_index()


# ------------------------------------------------------------------ the heaps of a round
def _requests(design: pd.DataFrame, model: Model, conds: pd.DataFrame, setup: dict, plan: Plan) -> list[Request]:
    """Each design pair's ``repeats`` heaps, seeded by what they simulate (:func:`content_seed`)."""
    pre = setup["pre"]
    rows = {str(r["condition_id"]): r for _, r in conds.iterrows()}
    out = []
    for _, d in design.iterrows():
        params = model.pin({p: float(d[p]) for p in model.parameters})
        cond = condition_from_row(pre.condition, rows[str(d["condition_id"])])
        out += [Request(params, cond, pre.numerics, content_seed(plan.seed, params, cond, r), setup["preset"], DESIGN,
                        int(d["run_id"]), r, model.hash, str(d["condition_id"]), setup["engine"])
                for r in range(plan.repeats)]
    return out


#: the most points a round designs: its run ids are 1000 (k + 1) onwards, one thousand a round
MAX_POINTS = 999


def _round_design(run: Path, model: Model, k: int, pairs: int, prev: Optional[Round], conds: pd.DataFrame,
                  plan: Plan, say: Say) -> pd.DataFrame:
    """Round k's pairs (locked): space-filling until a posterior exists (round 0, and a top-up where too few
    of its heaps formed one), then where the surrogates are least sure about the previous posterior."""
    prev_dir = _dir(run, model, prev.index) if prev is not None else None
    st = stage(run, "calibrate", _stage_name(model, k, "-design"),
               inputs={"conditions": run / CONDITIONS, "posterior": prev_dir / "samples.parquet" if prev_dir else None},
               settings={**plan.round_settings(model), "pairs": pairs})
    path = _dir(run, model, k) / "design.parquet"
    if st.up_to_date() and (k or _reused(run, model) is not None):
        return art.read_table(path)
    if prev is None:
        design = first_design(plan.bounds, conds["condition_id"].astype(str).tolist(), pairs, plan.seed + k)
    else:
        design = acquire(_surrogates(run, model, prev, conds, plan), prev.samples, conds, pairs, plan.repeats,
                         plan.rule, plan.seed + k)
    design.insert(0, "run_id", np.arange(pairs) + (MAX_POINTS + 1) * (k + 1))
    with st.commit() as out:
        out.table(path.relative_to(st.dir).as_posix(), design, model_revision=model.revision, round=k)
        if k == 0:  # kept where a changed setting redesigns round 0: heaps added since stay out
            at_hand = _reused(run, model)
            out.table((path.parent / "reused.parquet").relative_to(st.dir).as_posix(),
                      _at_hand(run, model) if at_hand is None else at_hand, model_revision=model.revision)
    return design


def _drop_after(run: Path, model: Model, k: int) -> None:
    """The rounds after k on disk, with their locks, once this calibration's last round k stands: they are another
    calibration's (another --seed or budget), whose designs the whole calibration's heaps would count
    (:func:`_designed`). Kept until then, so a calibration stopped on the way leaves the one before it
    whole but for the rounds it redesigned, and that one's options, given again, find its later rounds."""
    j = k + 1
    while (d := _dir(run, model, j)).is_dir():
        shutil.rmtree(d)
        for name in (_stage_name(model, j, "-design"), _stage_name(model, j)):
            (run / "calibrate" / f"{name}{art.LOCK_SUFFIX}").unlink(missing_ok=True)
        j += 1


def _surrogates(run: Path, model: Model, prev: Round, conds: pd.DataFrame, plan: Plan) -> list:
    """The previous round's surrogates with their measured means' variances: the angle's, and the
    profile's where the posterior weighed it (refitted when the round was read back from disk)."""
    if prev.fit is not None:
        gp, second = prev.fit.gp, prev.fit.second
    else:
        rows = in_box(_until_round(run, model_rows(run, model, views=plan.views), model, prev.index),
                      plan.bounds)
        gp = model_surrogate(rows, model, plan.seed, scale=plan.bounds)
        second = None
        if prev.evidence.get("profile"):
            cond_vars = informative_conditions(rows, COND_VARS)
            second = second_response(run, profile_rows(run, rows, model, cond_vars), model, conds, plan.seed,
                                     scale=plan.bounds)
    return response_variances(gp, conds, second)


def _stage_name(model: Model, k: int, part: str = "") -> str:
    """The lock's name of round k's stage: its posterior's, or (``part`` "-design") its design's."""
    return f"rev{model.revision}-round-{k:02d}{part}"


def _dir(run: Path, model: Model, k: int) -> Path:
    return _round_dir(run, model.revision, k)


def _round_dir(run: Path, revision: int, k: int) -> Path:
    """Round ``k`` of model ``revision``'s calibration: its design, heaps' posterior and summary."""
    return run / "calibrate" / f"rev{revision}" / f"round-{k:02d}"


def _simulate(run: Path, design: pd.DataFrame, model: Model, conds: pd.DataFrame, setup: dict, plan: Plan,
              workers: int, dask: Optional[str], on_heap: Optional[Callable]) -> pd.DataFrame:
    """Run a round's heaps (cached ones are read); a kill loses only the heaps in flight."""
    return run_campaign(_requests(design, model, conds, setup, plan), run, workers, on_done=on_heap, dask=dask,
                        rows_suffice=True)


# ------------------------------------------------------------------ the posterior of a round
def _round_posterior(run: Path, model: Model, k: int, rule: str, design: pd.DataFrame, conds: pd.DataFrame,
                     plan: Plan, force: bool, say: Say, first: bool = False) -> Round:
    """The posterior after round k (locked): every heap of the model so far, the surrogates' held-out
    error scored for the Gaussian processes alone (the last round's is scored for every surrogate)."""
    rows = _until_round(run, model_rows(run, model, views=plan.views), model, k)
    judged = _until_round(run, model_rows(run, model, judged=True), model, k)
    cond_vars = informative_conditions(rows, COND_VARS)
    prof_in, prof_set = evidence_lock(run, model, rows, plan.profile, plan.columns, judged)
    mfile = run / MODEL_FILE
    st = stage(run, "calibrate", _stage_name(model, k),
               inputs={"results": art.Rows(run / RESULTS, rows[[*model.parameters, *cond_vars, RESPONSE]]),
                       "conditions": run / CONDITIONS, "model": mfile if mfile.is_file() else None, **prof_in},
               settings={**plan.round_settings(model), **prof_set})
    d = _dir(run, model, k)
    if st.up_to_date() and not force:
        meta = art.read_provenance(d / "summary.parquet")
        return Round(k, rule, design, art.read_table(d / "summary.parquet"), art.read_table(d / "samples.parquet"),
                     art.read_table(d / "surrogates.parquet"), meta["surrogate_ratios"], int(meta["heaps"]),
                     {"scatter": meta["scatter"], "profile": meta["profile"]})
    fit = fit_posterior(run, model, conds, walkers=plan.walkers, steps=plan.steps, seed=plan.seed,
                        ranges=plan.bounds, scatter=plan.scatter, profile=plan.profile, columns=plan.columns, rows=rows,
                        judged=judged, held_out_by=("gp",), beside=plan.beside, say=say if first else _quiet)
    with st.commit() as out:
        write_posterior(out, fit, prefix=d.relative_to(st.dir).as_posix() + "/")
    return Round(k, rule, design, fit.table, fit.samples, fit.held, fit.ratios, fit.heaps, fit.evidence, fit)


def _quiet(message: str, err: bool = False) -> None:
    pass


HEAP_KEYS = ["run_hash", "design", "run_id", "repeat", "condition_id"]  # a heap's row, as the index keys it


def _own(rows: pd.DataFrame, model: Model) -> np.ndarray:
    if not {"design", "model", "run_id"} <= set(rows.columns):
        return np.zeros(len(rows), bool)
    return ((rows["design"] == DESIGN) & (rows["model"] == model.hash)).to_numpy()


def _until_round(run: Path, rows: pd.DataFrame, model: Model, k: Optional[int]) -> pd.DataFrame:
    """The heaps a round's posterior learns from (``k`` None: the whole calibration's): those at hand when the
    calibration began (recorded by round 0; before it, every heap not a calibration's own) and the points of
    this calibration's designs up to round k (:func:`_designed`). Heaps that compare, diagnose or a later
    command add do not join, nor another calibration's of the same model (another --seed, a round designed
    again at a smaller --budget after a kill), so a calibration resumed or run again goes as it went
    (``--force``, or a new model revision, begins from every heap at hand)."""
    reused = _reused(run, model)
    own = _own(rows, model)
    keep = own & _in_designs(rows, _designed(run, model, k), model.parameters)
    if reused is None:
        keep = keep | ~own
    elif len(rows):
        keys = [c for c in HEAP_KEYS if c in rows.columns]
        at_hand = rows[keys].merge(reused[keys].drop_duplicates(), how="left", on=keys, indicator=True)
        keep = keep | ((at_hand["_merge"] == "both").to_numpy() & ~own)
    return rows[keep].reset_index(drop=True)


def _designed(run: Path, model: Model, k: Optional[int]) -> pd.DataFrame:
    """The points of this calibration's rounds 0 to ``k`` as their locked designs hold them (None: every
    round on disk): run_id, condition_id and the parameters."""
    cols = ["run_id", "condition_id", *model.parameters]
    frames, j = [], 0
    while (k is None or j <= k) and (path := _dir(run, model, j) / "design.parquet").is_file():
        frames.append(art.read_table(path, cols)[cols])
        j += 1
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=cols)


def _in_designs(rows: pd.DataFrame, designed: pd.DataFrame, params: list[str]) -> np.ndarray:
    """Per row, whether it is a point of ``designed``: its run id and condition, and its parameters exactly
    (but for the round trip through Parquet)."""
    if not len(rows) or not len(designed) or not {"run_id", "condition_id", *params} <= set(rows.columns):
        return np.zeros(len(rows), bool)
    left = pd.DataFrame({"run_id": pd.to_numeric(rows["run_id"], errors="coerce").to_numpy(float),
                         "condition_id": rows["condition_id"].astype(str).to_numpy()})
    right = designed.assign(run_id=designed["run_id"].astype(float), condition_id=designed["condition_id"].astype(str))
    m = left.merge(right.drop_duplicates(["run_id", "condition_id"]), how="left", on=["run_id", "condition_id"])
    got, want = rows[params].to_numpy(float), m[params].to_numpy(float)
    with np.errstate(invalid="ignore"):
        return np.isclose(got, want, rtol=1e-12, atol=0.0).all(axis=1)


def _reused(run: Path, model: Model) -> Optional[pd.DataFrame]:
    """The heaps at hand when this model's calibration began (round 0's record), None before it."""
    path = _dir(run, model, 0) / "reused.parquet"
    return art.read_table(path) if path.is_file() else None


def _at_hand(run: Path, model: Model) -> pd.DataFrame:
    """The keys of every heap of the model (judged ones too) that is not this calibration's own."""
    try:
        rows = model_rows(run, model, judged=True)
    except CalibError:
        return pd.DataFrame(columns=HEAP_KEYS)
    keys = [c for c in HEAP_KEYS if c in rows.columns]
    return rows.loc[~_own(rows, model), keys].reset_index(drop=True)


def _effect_words(table: pd.DataFrame) -> list[str]:
    """Each switchable effect's verdict in a word (on, off, open, undecided, cut), in the table's order."""
    ok = table["bf_off"].notna()
    return [effect_verdict(b, u, d, c) for b, u, d, c in
            zip(table["bf_off"][ok], table["bf_upper"][ok], table["decided"][ok], box_cuts(table)[ok])]


def _record(rnd: Round, new: int, revision: int) -> pd.DataFrame:
    """Round ``rnd``'s rows of rounds.parquet: one per parameter, with the heaps so far, its interval, its
    effect's Bayes factor, the surrogates' variance ratios and held-out errors."""
    held = rnd.held[rnd.held["surrogate"] == "gp"].set_index("response") if len(rnd.held) else pd.DataFrame()
    rmse = {r: float(held.loc[r, "rmse"]) if r in held.index else math.nan for r in (RESPONSE, FULLNESS)}
    t = rnd.table
    return pd.DataFrame({
        "revision": revision, "round": rnd.index, "rule": rnd.rule, "new_heaps": new,
        "calibration_heaps": rnd.spent, "heaps": rnd.heaps, "parameter": t["parameter"], "median": t["median"],
        "q05": t["q05"], "q95": t["q95"], "low": t["low"], "high": t["high"], "rel_width": t["rel_width"],
        "identified": t["identified"], "bf_off": t["bf_off"], "bf_upper": t["bf_upper"],
        "effect": [effect_verdict(b, u, d, c) for b, u, d, c in zip(t["bf_off"], t["bf_upper"], t["decided"],
                                                                     box_cuts(t))],
        "box_cut": box_cuts(t),
        "surrogate_ratio": rnd.ratios["combined"], "ratio_angle": rnd.ratios.get(RESPONSE, math.nan),
        "ratio_profile": rnd.ratios.get(FULLNESS, math.nan), "rmse_angle": rmse[RESPONSE],
        "rmse_profile": rmse[FULLNESS], "scatter": bool(rnd.evidence.get("scatter")),
        "profile": bool(rnd.evidence.get("profile")), "stop": ""})


def _say_round(rnd: Round, spent: int, say: Say) -> None:
    t = rnd.table
    parts = [f"{r.parameter} {r.q05:.3g}-{r.q95:.3g}" for r in t.itertuples()]
    bf = [f"{r.parameter} Bayes factor off {'<' if r.bf_upper else ''}{r.bf_off:.2g}" for r in t.itertuples()
          if np.isfinite(r.bf_off)]
    say(f"round {rnd.index}: posterior on {rnd.heaps} heaps ({spent} simulated by this calibration): "
        + "; ".join(parts + bf) + f"; surrogate/measurement variance {rnd.ratios['combined']:.3g}")


# ------------------------------------------------------------------ the calibration
def _plan(model: Model, conds: pd.DataFrame, budget: int, first: Optional[int], batch: Optional[int],
          **kw) -> Plan:
    """The settings, checked; round 0 defaults to a fifth more heaps than a surrogate needs (PILES_PER_INPUT
    per input: some fills stand as columns or blow up), a later round to 4 per input."""
    inputs = len(model.parameters) + len(informative_conditions(conds, COND_VARS))
    need = heaps_needed(model, informative_conditions(conds, COND_VARS))
    reps = max(int(kw.get("repeats", 2)), 1)
    # what a round of the default batch simulates: whole design points of ``repeats`` piles
    span = max(reps, 4 * inputs // reps * reps)
    plan = Plan(int(budget), int(first or math.ceil(1.2 * need)), int(batch or max(4 * inputs, 2 * reps)), span=span,
                **kw)
    if plan.rule not in RULES:
        raise CalibError(f"--rule must be one of {', '.join(RULES)}, got {plan.rule!r}")
    if plan.repeats < 1 or plan.first < 1 or plan.batch < 1:
        raise CalibError("--repeats, --first and --batch must be at least 1")
    if plan.batch // plan.repeats < 2:
        raise CalibError(f"--batch {plan.batch} with --repeats {plan.repeats} gives a later round fewer than 2 points: "
                         f"give a --batch of at least {2 * plan.repeats}")
    if max(plan.first, plan.batch) // plan.repeats > MAX_POINTS:
        raise CalibError(f"--first and --batch make at most {MAX_POINTS} points of --repeats {plan.repeats} piles a "
                         f"round, got {max(plan.first, plan.batch) // plan.repeats}: run more rounds instead")
    if first and plan.first > plan.budget:
        raise CalibError(f"--first {plan.first} is more than --budget {plan.budget}: round 0 spends the budget's "
                         "heaps, so give a --budget of at least --first")
    check_sampler(len(model.parameters), plan.walkers, plan.steps)
    if min(plan.first, plan.budget) // plan.repeats < 2:
        which = f"--first {plan.first}" if plan.first < plan.budget else f"--budget {plan.budget}"
        raise CalibError(f"{which} leaves round 0 fewer than 2 points of {plan.repeats} heaps: give at least "
                         f"{2 * plan.repeats} (a surrogate of {inputs} inputs wants {need} or more)")
    return plan


def _final_stage(run: Path, model: Model, plan: Plan, setup: dict, rows: Optional[pd.DataFrame]):
    """The lock of the whole calibration of this model revision: its heaps and settings."""
    mfile = run / MODEL_FILE
    used = None
    if rows is not None and len(rows):
        cond_vars = informative_conditions(rows, COND_VARS)
        used = art.Rows(run / RESULTS, rows[[*model.parameters, *cond_vars, RESPONSE]])
    prof_in, prof_set = (evidence_lock(run, model, rows, plan.profile, plan.columns, _judged_rows(run, model))
                         if rows is not None else ({}, {}))
    answer = run / "posterior" / "summary.parquet"  # another command's posterior there: the answer is redone
    return stage(run, "calibrate", f"rev{model.revision}", version="calibrate-answer",
                 inputs={"results": used, "conditions": run / CONDITIONS, "model": mfile if mfile.is_file() else None,
                         "answer": answer if answer.is_file() else None, **prof_in},
                 settings={**plan.round_settings(model), "budget": plan.budget, "preset": setup["preset"],
                           **modulus_settings(setup["modulus"]), **setup["engine_settings"], **prof_set})


def _judged_rows(run: Path, model: Model) -> pd.DataFrame:
    """Every heap the calibration judges (those that stood as columns too): :func:`_until_round`'s."""
    return _until_round(run, model_rows(run, model, judged=True), model, None)


def _current_rows(run: Path, model: Model) -> Optional[pd.DataFrame]:
    try:
        return _until_round(run, model_rows(run, model), model, None)
    except CalibError:  # no heaps yet
        return None


@writes_run
def calibrate(run: Path, budget: int = 250, first: Optional[int] = None, batch: Optional[int] = None,
              repeats: int = 2, rule: str = "variance", walkers: int = 32, steps: int = 2000, seed: int = 0,
              preset: Optional[str] = None, shear_modulus: Optional[float] = None, engine: Optional[str] = None,
              workers: int = 1, dask: Optional[str] = None, scatter: Optional[bool] = None,
              profile: Optional[bool] = None, columns: Optional[bool] = None, at_revision: Optional[int] = None,
              force: bool = False, views: bool = False,
              say: Optional[Say] = None, on_heap: Optional[Callable] = None) -> CalibrateResult:
    """Calibrate the run's current model in rounds until the posterior is stable or ``budget`` heaps are
    simulated (see the module's docstring). Writes RUN/calibrate/rev<N>/round-<k>/ per round (design,
    posterior), RUN/calibrate/rounds.parquet, rounds.png and point.parquet (the posterior's most probable
    draw, which compare and diagnose simulate), and RUN/posterior/ (the last round's posterior, every
    surrogate's held-out error). ``at_revision``: do nothing unless the model is at that revision (a
    pipeline's step for one revision). ``views``: the surrogates learn each heap from its side views' mean
    (heaps simulated since they are recorded; docs/method.md). ``on_heap(request, row)`` after each heap."""
    say = say or plain
    run = check_run_dir(run)
    model = load_model(run)
    if at_revision is not None and model.revision != at_revision:
        say(f"the model is at revision {model.revision}, this step calibrates revision {at_revision}: nothing to do")
        return CalibrateResult(stage(run, "calibrate", f"rev{model.revision}", version="calibrate-answer"), True,
                               elsewhere=True)
    cfg = resolve_settings(run, None, None)
    preset, g = heap_setup(cfg, preset, shear_modulus)
    name = heap_engine(cfg, engine)
    precision = heap_precision(cfg, name)
    setup = {"pre": heap_preset(preset, g, precision), "preset": preset, "modulus": g, "engine": name,
             "engine_settings": run_heap_settings(cfg, engine)}
    check_engine(setup["engine"])
    check_dask(dask)
    conds = measured_conditions(run)
    if conds.empty:
        raise CalibError(f"no measured condition in {run / CONDITIONS}: run `calib measure-angle` first")
    plan = _plan(model, conds, budget, first, batch, repeats=repeats, rule=rule, walkers=walkers, steps=steps,
                 seed=seed, scatter=scatter, profile=profile, columns=columns, views=bool(views),
                 beside=workers > 1 and not dask, bounds=prior_bounds(model, "settings", ranges=settings_ranges(cfg)))
    final = _final_stage(run, model, plan, setup, _current_rows(run, model))
    if final.up_to_date() and not force:
        return CalibrateResult(final, True)
    _check_setup(run, model, setup)
    say(f"calibrating model revision {model.revision} ({', '.join(model.parameters)}) on {len(conds)} measured "
        f"condition(s): round 0 {plan.first} heaps, then rounds of {plan.batch} ({plan.rule} rule, {plan.repeats} "
        f"piles a point) until stable or {plan.budget} heaps; preset {preset}, engine {setup['engine']}"
        + precision_note(precision))
    odd = [f"{opt} {n} makes {n // plan.repeats * plan.repeats}" for opt, n in (("--first", plan.first),
                                                                              ("--batch", plan.batch))
           if n % plan.repeats]
    if odd:  # a round simulates whole points of --repeats piles
        say(f"note: {' and '.join(odd)} heaps, whole points of {plan.repeats} piles (--repeats)")
    if force:  # begin again from every heap at hand now: compare's and diagnose's join
        (_dir(run, model, 0) / "reused.parquet").unlink(missing_ok=True)
    rounds, spent, stop, designed = _rounds(run, model, conds, plan, setup, workers, dask, force, say, on_heap)
    return _finish(run, model, conds, plan, setup, rounds, spent, stop, designed, say)


def _check_setup(run: Path, model: Model, setup: dict) -> None:
    """Refuse, before a heap runs, heaps of another preset or shear modulus than the model's heaps at hand:
    one surrogate would mix them (its fit refuses them, but only after a round of heaps)."""
    if not (run / RESULTS).is_file():
        return
    rows = model_rows(run, model, judged=True)
    if rows.empty:
        return
    have = heap_setups(rows)
    mine = heap_setups(rows.head(1).assign(preset=setup["preset"], shear_modulus=setup["pre"].numerics.shear_modulus))
    if have != mine:
        raise CalibError(f"the heaps of model revision {model.revision} in {run} were simulated at {'; '.join(have)}, "
                         f"and this calibration would simulate at {mine[0]}, which one surrogate would mix: give "
                         "--preset and --shear-modulus as those heaps had them, or calibrate in another run directory")


def _next_pairs(plan: Plan, k: int, spent: int, short: int = 0) -> int:
    """The pairs of round k: round 0's, a top-up of half as many again as the heaps missing, or a batch;
    never beyond the budget, and no later round of less than half a batch (a few heaps move nothing)."""
    if k and not short and plan.budget - spent < plan.batch / 2:
        return 0
    want = plan.first if k == 0 else max(math.ceil(1.5 * short), 2 * plan.repeats) if short else plan.batch
    return min(want, plan.budget - spent) // plan.repeats


def _rounds(run, model, conds, plan, setup, workers, dask, force, say, on_heap) -> tuple[list[Round], int, str, int]:
    """Round after round until the stop rule or the budget; returns the rounds that fitted a posterior,
    the heaps they simulated, why they stopped and the last round designed."""
    rounds: list[Round] = []
    spent, k, short = 0, 0, 0
    need = heaps_needed(model, informative_conditions(conds, COND_VARS))
    while True:
        pairs = _next_pairs(plan, k, spent, short)
        if pairs < 2:
            if not rounds:
                raise CalibError(f"only {need - short} heaps of the model formed a heap ({spent} simulated by this "
                                 f"calibration); the surrogate needs {need}: raise --budget")
            return rounds, spent, (f"budget: {spent} of the {plan.budget} heaps simulated, too few left for "
                                   f"another round"), k - 1
        prev = rounds[-1] if rounds else None
        rule = "space-filling" if prev is None else plan.rule
        design = _round_design(run, model, k, pairs, prev, conds, plan, say)
        spent += len(design) * plan.repeats
        say(f"round {k}: {len(design)} points x {plan.repeats} piles ({rule})")
        _simulate(run, design, model, conds, setup, plan, workers, dask, on_heap)
        have = len(in_box(_until_round(run, model_rows(run, model), model, k), plan.bounds))
        short = max(need - have, 0)
        if short:
            say(f"round {k}: {have} heaps of the model formed a heap, the surrogate needs {need}: another "
                "space-filling round")
            k += 1
            continue
        rnd = _round_posterior(run, model, k, rule, design, conds, plan, force, say, first=prev is None)
        rnd.spent = spent
        rounds.append(rnd)
        _say_round(rnd, spent, say)
        stop = _stop(rounds, plan, rnd)
        if stop:
            return rounds, spent, stop, k
        k += 1


def _stop(rounds: list[Round], plan: Plan, rnd: Round) -> str:
    """The stop rule on the last of ``rounds`` (``rnd``) against the round a default batch before it."""
    ref = reference_round([r.spent for r in rounds[:-1]], rnd.spent, plan.span or plan.batch)
    if ref is None:
        return ""
    prev = rounds[ref]
    since = ("the previous round" if ref == len(rounds) - 2
             else f"round {prev.index}, {rnd.spent - prev.spent} heaps before")
    return stop_reason(prev.table, rnd.table, _effect_words(prev.table), _effect_words(rnd.table),
                       bool(rnd.table["decided"].iloc[0]), since)


#: the final posterior (the answer) samples FINAL_LONGER times a round's steps, longer still where an effect's
#: Bayes factor is only bounded above BF_RESOLUTION (no draw near its neutral value, and too few draws to say
#: the bound is below BF_RESOLUTION, half Jeffreys' 0.1, where a bound's verdict is safe), at most MAX_LONGER times: on the hidden-cohesion lab a round's 3000 steps
#: moved an interval's end by up to 0.03 against 18000 steps
FINAL_LONGER, BF_RESOLUTION, MAX_LONGER = 3, 0.05, 6


def _final_steps(last: Round, plan: Plan) -> int:
    t = last.table
    bound = t["bf_upper"].astype(bool) & (t["bf_off"] > BF_RESOLUTION)
    need = math.ceil(float(t.loc[bound, "bf_off"].max()) / BF_RESOLUTION) if bound.any() else 1
    return plan.steps * min(MAX_LONGER, max(FINAL_LONGER, need))


def _write_final_posterior(run: Path, model: Model, conds: pd.DataFrame, plan: Plan, last: Round,
                           say: Say) -> pd.DataFrame:
    """RUN/posterior/: the last round's heaps and evidence, sampled longer (:func:`_final_steps`), with every
    surrogate's held-out error; returns its draws."""
    rows = _until_round(run, model_rows(run, model, views=plan.views), model, last.index)
    judged = _until_round(run, model_rows(run, model, judged=True), model, last.index)
    cond_vars = informative_conditions(in_box(rows, plan.bounds), COND_VARS)
    steps = _final_steps(last, plan)
    say(f"the answer: the last round's posterior sampled {steps} steps (a round's {plan.steps}), with every "
        "surrogate's held-out error")
    prof_in, prof_set = evidence_lock(run, model, rows, plan.profile, plan.columns, judged)
    mfile = run / MODEL_FILE
    pst = stage(run, "posterior", "sample",
                inputs={"results": art.Rows(run / RESULTS, rows[[*model.parameters, *cond_vars, RESPONSE]]),
                        "conditions": run / CONDITIONS, "model": mfile if mfile.is_file() else None, **prof_in},
                settings={"calibrate": plan.round_settings(model), "round": last.index, "steps": steps, **prof_set})
    fit = fit_posterior(run, model, conds, walkers=plan.walkers, steps=steps, seed=plan.seed, ranges=plan.bounds,
                        scatter=plan.scatter, profile=plan.profile, columns=plan.columns, rows=rows, judged=judged,
                        average=True, beside=plan.beside, say=say)
    with pst.commit() as out:
        write_posterior(out, fit)
    return fit.samples


def _finish(run: Path, model: Model, conds: pd.DataFrame, plan: Plan, setup: dict, rounds: list[Round],
            spent: int, stop: str, designed: int, say: Say) -> CalibrateResult:
    """RUN/posterior/ from the last round, then RUN/calibrate/'s rounds, figure and point (the final
    posterior's most probable draw) under the calibration's lock; the rounds on disk after the last one
    ``designed`` go (:func:`_drop_after`)."""
    from ..plots import rounds_figure

    last = rounds[-1]
    samples = _write_final_posterior(run, model, conds, plan, last, say)
    table = pd.concat([_record(r, r.spent - (rounds[i - 1].spent if i else 0), model.revision)
                       for i, r in enumerate(rounds)], ignore_index=True)
    table.loc[table["round"] == last.index, "stop"] = stop
    old = run / "calibrate" / "rounds.parquet"
    if old.is_file():
        prev = art.read_table(old)
        table = pd.concat([prev[prev["revision"] != model.revision], table], ignore_index=True)
    best = most_probable(samples, model.parameters)
    _drop_after(run, model, designed)
    final = _final_stage(run, model, plan, setup, _current_rows(run, model))
    with final.commit() as out:
        out.table("rounds.parquet", table, model_revision=model.revision, stop=stop)
        out.figure("rounds.png", rounds_figure(table[table["revision"] == model.revision],
                                               art.read_table(run / "posterior" / "summary.parquet")))
        out.table("point.parquet", best, model_revision=model.revision, model=list(model.effects),
                  how="the posterior's most probable draw")
    say(f"stopped after round {last.index}: {stop}")
    return CalibrateResult(final, False, table[table["revision"] == model.revision].reset_index(drop=True),
                           art.read_table(run / "posterior" / "summary.parquet"), stop, model.revision)
