"""`calib fit-surrogate`, `calib predict`, `calib invert`, `calib calibrate-posterior`: the options of
calib_cli.stages.surrogate, .invert and .posterior, and their tables."""

from __future__ import annotations

from typing import Annotated, Optional

import typer
from rich.markup import escape

from ..errors import CalibError
from .common import (ColumnsOpt, ForceOpt, PresetOpt, ProfileOpt, ResponsesOpt, RunOpt, ScatterOpt, SettingOpt,
                     SettingsOpt, ShearModulusOpt, SideViewsOpt, check_run_dir, console, df_table, posterior_table, say,
                     skipped)


def fit_surrogate(run: RunOpt, responses: ResponsesOpt = None,
                  from_simulations: Annotated[Optional[str], typer.Option(
                      "--from-simulations", help="Train on the simulations of this design stage (e.g. bbd), "
                      "with the condition variables that vary as extra inputs (several conditions at once).")] = None,
                  settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Fit RSM, BP and PSO-BP surrogates; compare them in-sample, on a seeded 80/20 split and by
    leave-one-out (paper 3.5.1-3.5.2, Table 9).

    Reads RUN/bbd/data.parquet (from `bbd analyze`) or --responses FILE. Writes
    RUN/surrogate/metrics.parquet (model, split, r2, mse, aad), predictions.parquet,
    models/<model>.json, best.json and predicted_vs_actual.png.
    """
    from ..stages.surrogate import fit_surrogate as fit

    res = fit(run, responses, from_simulations, settings, setting, force, say=say)
    if res.skipped:
        return skipped(res.stage)
    metrics, best = res.metrics, res.best
    loo = metrics[metrics["split"] == "loo"].set_index("model")
    console.print(df_table(res.summary(),
                           "R2 by model and split (cf. paper Table 9, which reports in-sample fits)"))
    console.print(df_table(metrics[metrics["split"].isin(["train", "loo"])],
                           "In-sample and leave-one-out metrics (Eqs. 8-10)"))
    console.print(f"[bold]Best on held-out data (leave-one-out MSE): {best}[/] "
                  f"(R2 {loo.loc[best, 'r2']:.4f}, MSE {loo.loc[best, 'mse']:.4f}). With {res.n_samples} samples the "
                  f"held-out comparison is the honest one; in-sample fits reward flexibility.")


ModelOpt = Annotated[Optional[str], typer.Option("--model", help="rsm | bp | pso-bp (default: all for predict, "
                                                 "the best on held-out data for invert).")]


def predict(run: RunOpt, set_: Annotated[Optional[list[str]], typer.Option("--set", help="KEY=VALUE for every "
            "surrogate input (repeatable).")] = None, model: ModelOpt = None):
    """Evaluate the saved surrogate(s) at a point. Reads RUN/surrogate/models/*.json."""
    import numpy as np

    from ..heaps.inputs import parse_pairs, parse_params
    from ..surrogate.store import load_models

    run = check_run_dir(run)
    models, best = load_models(run, model)
    vals = parse_params(parse_pairs(set_, "--set")) if set_ else {}
    names = best["inputs"]
    missing = [n for n in names if n not in vals]
    if missing:
        raise CalibError(f"give a value for {', '.join(missing)} (--set NAME=VALUE)")
    x = np.array([[vals[n] for n in names]])
    for n, lo, hi in zip(names, best["lows"], best["highs"]):
        if not lo <= vals[n] <= hi:
            console.print(f"[yellow]warning:[/] {n} = {vals[n]:g} is outside the fitted range [{lo:g}, {hi:g}]: "
                          "extrapolating")
    for name, m in models.items():
        console.print(f"{name:7s} {float(m.predict(x)[0]):.2f} deg")


def invert(
    run: RunOpt,
    target: Annotated[Optional[float], typer.Option(help="Target angle (deg); default: the measured conditions "
                                                    "(conditions.parquet in RUN/measure/), else settings target.")] = None,
    model: ModelOpt = None,
    validate: Annotated[int, typer.Option(min=0, help="Simulations at the solution, each with its own seed "
                                          "(paper 3.6: five), on the measured rig: N per measured "
                                          "condition, or the preset's rig with --condition.")] = 0,
    preset: PresetOpt = None,
    shear_modulus: ShearModulusOpt = None,
    condition: Annotated[Optional[list[str]], typer.Option("--condition", help="Heap-test variable of the "
                         "validation runs, KEY=VALUE (repeatable); given, the validation runs on the preset's "
                         "rig with these changes instead of the measured conditions.")] = None,
    workers: Annotated[int, typer.Option(min=1, help="Parallel validation runs.")] = 1,
    refine: Annotated[Optional[int], typer.Option(min=0, help="With --validate: at most this many corrections "
                      "when the validation misses the targets by more than invert.refine_z combined sd (rms z): its error "
                      "there is added to the surrogate, which is inverted again nearest the last point (output space "
                      "mapping). Default: settings invert.refine.")] = None,
    settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False,
):
    """GA inversion of the surrogate to the target angle within the fitted ranges (paper Eq. 11, Fig. 9),
    the set of near-optimal parameters, and optional validation simulations (paper 3.6), optionally
    refined where the validation shows the surrogate wrong. Warns when the solution sits on the edge
    of the range the surrogate was fitted on.

    Reads RUN/surrogate/. Writes RUN/invert/solution.parquet, history.parquet, solution_set.parquet,
    ranges.parquet, fitness.png and, with --validate, validation.parquet (and with --refine, refinement.parquet).
    """
    from ..stages.invert import invert as solve

    r = solve(run, target, model, validate, preset, shear_modulus, condition, workers, refine, settings, setting, force,
              say=say)
    if r.skipped:
        return skipped(r.stage)
    chosen = r.validation.chosen if r.validation is not None else 0
    title = "GA optimum" if chosen == 0 else f"Solution of refinement round {chosen}"
    console.print(df_table(r.solution, f"{title} (targets from {r.target_source})"))
    if len(r.per_condition) > 1:
        console.print(df_table(r.per_condition, "per condition: measured target and predicted angle at the optimum"))
    console.print(df_table(r.ranges, f"Near-optimal set: {r.n_near} points within {r.tolerance:g} deg of the best "
                                     "fitness"))
    for line in r.warnings():
        console.print(f"[yellow]warning:[/] {escape(line)}")
    refinement = r.refinement()
    if refinement is not None:
        console.print(df_table(refinement, f"Refinement by simulation: {int(refinement['round'].max())} correction(s)"))
    for line in r.verdict:  # a line that warns is marked so (plain text in the result, for a notebook too)
        console.print(f"[yellow]warning:[/]{escape(line[8:])}" if line.startswith("warning:") else escape(line))


def calibrate_posterior(
    run: RunOpt,
    walkers: Annotated[int, typer.Option("--walkers", min=2, help="emcee walkers (at least twice the "
                                         "parameters).")] = 32,
    steps: Annotated[int, typer.Option("--steps", min=10, help="Steps per walker; the first quarter (or three "
                                       "autocorrelation times) is burn-in.")] = 5000,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the sampler and of the surrogates' held-out "
                                      "folds: the same seed gives the same draws.")] = 0,
    prior: Annotated[str, typer.Option("--prior", help="The uniform prior's ranges: settings (the run's factor "
                                       "table, settings.toml \\[factors]: the ranges you declare plausible), effects "
                                       "(each effect's physical bounds, `calib model show`) or heaps (what the "
                                       "model's simulated heaps cover).")] = "settings",
    design: Annotated[int, typer.Option("--design", min=0, help="Also write design.parquet in RUN/posterior/: this "
                                        "many points spread over the 90 % intervals (a Latin hypercube), to "
                                        "simulate at the measured conditions with simulate-heap --design, so "
                                        "the surrogate learns where the posterior lies; then run this again.")] = 0,
    scatter: ScatterOpt = None,
    profile: ProfileOpt = None,
    columns: ColumnsOpt = None,
    views: SideViewsOpt = False,
    force: ForceOpt = False,
):
    """The posterior over the current model's parameters given every measured condition: a
    Gaussian process of the angle over the parameters and the condition variables, trained on all
    the run's simulated heaps of the model, and the likelihood of each condition's mean angle
    (measured scatter over n, plus the surrogate's own uncertainty, shared by the conditions),
    sampled by emcee under a uniform prior (--prior); each condition's pile scatter and heap profile too,
    wherever the heaps and photographs allow. A parameter is identified when its 90 % interval spans at
    most a fifth of its prior range; an effect the model gained gets the Bayes factor of its being off
    (docs/method.md, 'The posterior'). No verdict is given while the surrogate's own uncertainty where
    the posterior lies outweighs the measurement's: `calib calibrate` simulates heaps there.

    Reads RUN/simulate/results.parquet, RUN/measure/conditions.parquet (for the profile, profiles.parquet
    and the heaps' side views) and RUN/model.toml. Writes RUN/posterior/summary.parquet,
    samples.parquet, surrogates.parquet (held-out RMSE of the GP, RSM and BP network) and corner.png
    (with --design, design.parquet). Skipped when its inputs and options are unchanged. Where
    posterior/ holds `calib calibrate`'s answer, it is replaced only with --force.
    """
    from ..stages.posterior import posterior as posterior_stage

    r = posterior_stage(run, walkers, steps, seed, prior, force, say=say, design=design, scatter=scatter,
                        profile=profile, columns=columns, views=views)
    if r.skipped:
        return skipped(r.stage)
    console.print(df_table(posterior_table(r.table), f"posterior of model revision {r.revision}: 90 % intervals"))
    cv = r.surrogates
    cols = [c for c in ("response", "surrogate", "rmse", "noise_sd", "piles") if c in cv.columns]
    console.print(df_table(cv[cols], "held-out RMSE per pile (the angle's in deg)"))
    console.print(f"each surrogate trained without a fifth of the {cv['design_points'].iloc[0]} design points, "
                  f"{cv['folds'].iloc[0]} times; noise_sd is the piles' own scatter, the floor")
    for line in r.conclusion(markup=True):
        console.print(line)
    if design:
        d = r.stage.dir / "design.parquet"
        # one pile per point and condition teaches the scatter nothing: with --scatter, repeats do
        reps = " --repeats 3" if scatter is not False else ""
        console.print(f"wrote {d}: {design} points over the 90 % intervals; simulate them at the measured conditions "
                      f"(calib simulate-heap --run {run} --design {d} --conditions {run}/measure/conditions.parquet"
                      f"{reps}), then run calibrate-posterior again")
