"""A Bayesian calibration: the posterior over the current model's parameters given every measured
condition, from Gaussian-process surrogates trained on all the run's simulated heaps of that model
(calib_cli.posterior.evidence)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import pandas as pd

from .. import artifacts as art
from ..heaps.index import RESULTS
from ..errors import CalibError
from ..measurements import measured_conditions
from ..model import MODEL_FILE, load_model
from ..posterior.evidence import (PRIORS, RESPONSE, check_rows, evidence_lock, extrapolation_note, fit_posterior,
                                  model_rows, prior_bounds, settings_ranges, summary_view, write_posterior)
from ..posterior.calibrate import check_sampler
from ..posterior.suggest import region_design
from .common import Result, Say, check_run_dir, plain, resolve_settings, shown, stage, writes_run


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
        return summary_view(self.table)

    def conclusion(self, markup: bool = False) -> list[str]:
        """Each parameter's verdict, the sampler's acceptance and whether its chains were long enough
        (``markup``: with the command line's rich markup)."""
        t = self.table
        out = [f"[bold]{r.parameter}[/]: {r.verdict}" for r in t.itertuples()]
        acc = t["acceptance"].iloc[0]
        out.append(f"acceptance fraction {acc:.2f}" + (" (below 0.1: walkers are stuck; look at corner.png)"
                                                       if acc < 0.1 else ""))
        if not t["chain_ok"].all():
            out.append(f"[yellow]warning:[/] the chains are shorter than 50 autocorrelation times "
                       f"(longest {t['autocorr_time'].max():.0f} steps): the intervals are rough; rerun with "
                       "more --steps")
        return shown(out, markup)


def _calibrate_answer(run: Path, revision: int) -> bool:
    """Whether RUN/posterior/ is the answer of model ``revision``'s calibration in rounds (its lock names the
    summary's hash): another sampling would replace it, and that calibration would then sample it again."""
    summary = run / "posterior" / "summary.parquet"
    lock = art.Stage(run, "calibrate", f"rev{revision}").read_lock()
    return bool(lock) and summary.is_file() and lock.get("inputs", {}).get("answer") == art.file_hash(summary)


@writes_run
def posterior(run: Path, walkers: int = 32, steps: int = 5000, seed: int = 0, prior: str = "settings",
              force: bool = False, say: Optional[Say] = None, design: int = 0,
              scatter: Optional[bool] = None, profile: Optional[bool] = None,
              columns: Optional[bool] = None, views: bool = False) -> PosteriorStageResult:
    """Sample the posterior of the current model's parameters given every measured condition, through
    Gaussian processes trained on the run's simulated heaps of the model
    (:func:`~calib_cli.posterior.evidence.fit_posterior`); the prior is uniform over the run's factor table
    (``prior="settings"``: settings.toml's [factors]), each effect's range (``"effects"``) or the range the
    heaps cover (``"heaps"``). Writes RUN/posterior/
    samples.parquet, summary.parquet, surrogates.parquet (held-out RMSE of the GP, RSM and BP network)
    and corner.png; with ``design`` N, also design.parquet: N points over the 90 % box
    (:func:`~calib_cli.posterior.suggest.region_design`) for ``simulate-heap --design``. ``scatter`` /
    ``profile`` / ``columns``: weigh each condition's pile scatter / mean heap profile / share of piles
    that stood as columns as well as its mean angle (None, the default: wherever the simulated heaps and
    the photographs allow). ``views``: the surrogates learn each heap from its side views' mean where every
    heap recorded them (docs/method.md)."""
    say = say or plain
    run = check_run_dir(run)
    if prior not in PRIORS:
        raise CalibError(f"--prior must be one of {', '.join(PRIORS)}, got {prior!r}")
    model = load_model(run)
    check_sampler(len(model.parameters), walkers, steps)
    conds = measured_conditions(run)
    if conds.empty:
        raise CalibError(f"no measured condition in {run / 'measure' / 'conditions.parquet'}: "
                         "run `calib measure-angle` first")
    rows = model_rows(run, model, views=views)
    cond_vars = check_rows(run, rows, model)
    used = rows[[*model.parameters, *cond_vars, RESPONSE]]
    ranges = settings_ranges(resolve_settings(run, None, None))
    bounds = prior_bounds(model, prior, rows, ranges)
    mfile = run / MODEL_FILE
    # a heap's fullness follows from its run hash (its side view) and the code's version: the rows and how many
    # of them have one stand for it
    prof_in, prof_set = evidence_lock(run, model, rows, profile, columns)
    st = stage(run, "posterior", "sample",
               inputs={"results": art.Rows(run / RESULTS, used), "conditions": run / "measure" / "conditions.parquet",
                       "model": mfile if mfile.is_file() else None, **prof_in},
               settings={"walkers": walkers, "steps": steps, "seed": seed, "model": model.hash, "prior": prior,
                         "bounds": bounds,
                         **({"design": design} if design else {}), "scatter": scatter, **prof_set,
                         **({"views": True} if views else {})})
    if st.up_to_date() and not force:
        return PosteriorStageResult(st, True)
    if not force and _calibrate_answer(run, model.revision):
        raise CalibError(f"{run / 'posterior'} holds the answer `calib calibrate` gave for model revision "
                         f"{model.revision}; give --force to replace it with this sampling (a later `calib "
                         "calibrate` would then sample its answer again)")
    note = extrapolation_note(rows, model, bounds) if prior != "heaps" else ""
    if note:
        say(note)
    say(f"posterior of model revision {model.revision} ({', '.join(model.parameters)}): a Gaussian process on "
        f"{len(rows)} simulated heaps, {len(conds)} measured condition(s), {walkers} walkers x {steps} steps")
    fit = fit_posterior(run, model, conds, walkers=walkers, steps=steps, seed=seed, prior=prior, ranges=ranges,
                        scatter=scatter,
                        profile=profile, columns=columns, rows=rows, average=True, say=say)
    with st.commit() as out:
        write_posterior(out, fit)
        if design:  # run ids after every id the run's heaps already use above 100 (earlier rounds, a design
            # made by hand): each round its own labels
            first = int(max(rows["run_id"].max() if "run_id" in rows.columns else 0, 100)) + 1
            out.table("design.parquet", region_design(fit.table, design, seed, first), model_revision=model.revision)
    return PosteriorStageResult(st, False, fit.table, fit.held, fit.samples, model.revision)
