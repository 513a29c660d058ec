"""`calib calibrate`: the options of calib_cli.stages.calibrate, a progress bar per round, and the answer:
the posterior first, then how the rounds got there."""

from __future__ import annotations

from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from .common import (AtRevisionOpt, ColumnsOpt, ForceOpt, PresetOpt, ProfileOpt, RunOpt, ScatterOpt, ShearModulusOpt,
                     SideViewsOpt, console, df_table, posterior_table, say)


def calibrate(
    run: RunOpt,
    budget: Annotated[int, typer.Option("--budget", min=1, help="The most heaps this calibration simulates "
                                        "(heaps already in the run, from other commands or model revisions, are "
                                        "used and not counted).")] = 250,
    first: Annotated[Optional[int], typer.Option("--first", min=1, help="Heaps of round 0, the space-filling "
                                                 "design. Default: 12 per surrogate input (10 are needed; some fills "
                                                 "stand as columns).", show_default=False)] = None,
    batch: Annotated[Optional[int], typer.Option("--batch", min=1, help="Heaps of each later round. Default: 4 "
                                                 "per surrogate input.", show_default=False)] = None,
    repeats: Annotated[int, typer.Option("--repeats", min=1, help="Piles per design point: the scatter's model "
                                         "learns from the groups of repeated piles.")] = 2,
    rule: Annotated[str, typer.Option("--rule", help="Where later rounds simulate: variance (where the surrogates' "
                                      "variance summed over the posterior's draws falls most), max-sd (where it "
                                      "is largest) or draws (posterior draws at random).")] = "variance",
    engine: Annotated[Optional[str], typer.Option(help="builtin, gpu or lammps: the engine of the heaps. Default: "
                                                  "the run's heap.engine setting.", show_default=False)] = None,
    preset: PresetOpt = None,
    shear_modulus: ShearModulusOpt = None,
    workers: Annotated[int, typer.Option(min=1, help="Heaps at once on a local process pool.")] = 1,
    dask: Annotated[Optional[str], typer.Option(help="Run the heaps on a Dask cluster: a scheduler address or "
                                                "'local'.")] = None,
    scatter: ScatterOpt = None,
    profile: ProfileOpt = None,
    columns: ColumnsOpt = None,
    views: SideViewsOpt = False,
    walkers: Annotated[int, typer.Option("--walkers", min=2, help="emcee walkers.")] = 32,
    steps: Annotated[int, typer.Option("--steps", min=10, help="Steps per walker, each round; the answer (the "
                                       "last round's posterior) samples three to six times as many.")] = 2000,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the designs, the heaps and the sampler.")] = 0,
    at_revision: AtRevisionOpt = None,
    force: ForceOpt = False,
):
    """Calibrate the run's model in rounds: a space-filling design of heaps over its parameters and the
    measured conditions, then, round after round, the posterior given every condition (mean angle,
    piles' scatter, heap profile) and heaps where the surrogates are least sure about it, until every
    90 % interval and verdict is stable or --budget heaps are simulated (docs/method.md, 'Calibrating
    in rounds').

    Reads RUN/measure/ and RUN/model.toml; every heap of the model already in the run when the
    calibration begins is used (heaps compare or diagnose add later join only with --force, which
    calibrates again from every heap at hand). Writes RUN/calibrate/rev<N>/round-<k>/ (each round's
    design and posterior), RUN/calibrate/rounds.parquet, rounds.png, point.parquet (the most probable
    draw: what compare and diagnose simulate) and RUN/posterior/. A rerun goes on from the last
    finished round; Ctrl-C loses only the heaps in flight.
    """
    from ..posterior.evidence import widen_advice
    from ..stages.calibrate import calibrate as run_calibration

    # a bar on a terminal only: piped, the transient bar left an empty line before every message
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True, disable=not console.is_terminal) as prog:
        task = prog.add_task("heaps", total=None)

        def on_heap(req, row):
            prog.advance(task)

        r = run_calibration(run, budget, first, batch, repeats, rule, walkers, steps, seed, preset, shear_modulus,
                            engine, workers, dask, scatter, profile, columns, at_revision, force, views, say=say,
                            on_heap=on_heap)
    if r.skipped and r.rounds is None:
        return
    if r.skipped:
        console.print(f"[green]✓[/] calibrate rev{r.revision}: inputs and settings unchanged, nothing to do "
                      "(use --force to rerun)")
    show_calibration(r)
    widen = widen_advice(r.table)
    if widen:
        console.print(f"[yellow]![/] {widen} (`calib calibrate --run {run}` with the same options)")
    console.print(f"next: `calib compare --run {run}` simulates the most probable draw at every condition; "
                  f"`calib suggest-conditions --run {run} --rig RIG.toml` names the conditions to measure next")


def show_answer(r, out: Console = console) -> None:
    """The posterior as `calib calibrate` prints it: its table, then each parameter's verdict."""
    out.print(df_table(posterior_table(r.table), f"posterior of model revision {r.revision}: 90 % intervals",
                       width=out.width))
    for row in r.table.itertuples():
        out.print(f"[bold]{row.parameter}[/]: {row.verdict}")


def show_calibration(r, out: Console = console) -> None:
    """A :class:`~calib_cli.stages.calibrate.CalibrateResult` as `calib calibrate` prints it: the answer, the
    rounds that led to it and why they stopped."""
    show_answer(r, out)
    out.print(df_table(r.per_round(), "rounds: heaps and 90 % intervals", width=out.width))
    out.print(f"stopped: {r.stop}")
