"""Simulate heaps into a run directory: a design's rows (or one point), crossed with a conditions
table and repeats, on the built-in kernel or LAMMPS, cached by each heap's hash (calib_cli.heaps.keys)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..heaps.index import RESULTS
from ..heaps.keys import RUNS, Request
from ..heaps.runner import REUSE_ENV, check_dask, reusable, run_campaign
from ..conditions import check_conditions, read_conditions_csv
from ..dem.heap import CONDITION_VARIABLES, PARAMETERS, Preset, interactions
from ..errors import CalibError
from ..measurements import CONDITIONS
from ..heaps.inputs import (Pairs, build_requests, check_engine, checked_condition, given_pairs, heap_engine,
                            heap_precision, heap_preset, heap_setup, make_condition, modulus_note, parse_params,
                            precision_note, table_conditions)
from .common import Say, check_run_dir, checked, plain, resolve_settings, shown, writes_run

#: deg/s: measured heaps whose angle still changes faster than this are pointed out
DRIFT_WARN = 2.0


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


@dataclass
class Plan:
    """The heaps a simulation will run: their requests, on which preset, and how many are cached."""

    run: Path
    requests: list[Request]
    preset: Preset
    force: bool = False


@dataclass
class SimulateResult:
    """The rows of RUN/simulate/results.parquet this simulation made or found cached."""

    run: Path
    rows: pd.DataFrame

    @property
    def path(self) -> Path:
        return self.run / RESULTS

    def summary(self) -> pd.DataFrame:
        rows = self.rows
        return rows[["run_id", "repeat", *[c for c in PARAMETERS if c in rows.columns], "status", "repose_angle",
                     "angle_drift_deg_s", "n_particles", "wall_s"]]

    def check(self) -> "SimulateResult":
        """Raise when no heap formed (the notes say why)."""
        if (self.rows["status"] != "ok").all():
            raise CalibError("no run formed a heap; see the messages above")
        return self

    def notes(self, markup: bool = False) -> list[str]:
        """Creeping heaps and heaps that failed (``markup``: with the command line's rich markup)."""
        rows, out = self.rows, []
        creeping = rows[(rows["status"] == "ok") & (rows["angle_drift_deg_s"].abs() > DRIFT_WARN)]
        if len(creeping):
            out.append(f"[yellow]note:[/] {len(creeping)} of {len(rows)} heap(s) were still creeping by more than "
                       f"{DRIFT_WARN:g} deg/s when measured (up to {creeping['angle_drift_deg_s'].abs().max():.1f}): "
                       "the rolling law cannot hold a static heap, so every angle is taken at the same stage "
                       "(docs/physics.md, 'Creep')")
        for _, r in rows[rows["status"] != "ok"].iterrows():
            out.append(f"[yellow]run {r['run_id']} repeat {r['repeat']}: {r['status']}[/] - {r['message']}")
        return shown(out, markup)


def _points(run: Path, design: Optional[Path], fixed: dict) -> tuple[list[tuple[int, dict]], str, str]:
    """(run id, parameters) of every design row (the fixed values for what it lacks), or of one point;
    with absent effects pinned at their neutral values once the run has a model file."""
    points: list[tuple[int, dict]] = []
    dname = ""
    if design is not None:
        df = art.read_table(design, what="design")
        cols = [c for c in df.columns if c in PARAMETERS]
        # a factor the settings declare that no heap takes would be left at its default in every heap, unseen
        declared = resolve_settings(run, None, None)["factors"]
        foreign = [c for c in df.columns if c in declared and c not in PARAMETERS]
        if foreign:
            raise CalibError(f"design {design}: factor(s) {', '.join(foreign)} are not parameters a simulated heap "
                             f"takes ({', '.join(PARAMETERS)}); a design over them needs responses measured "
                             "elsewhere (--responses)")
        if not cols:
            raise CalibError(f"design {design} has no parameter columns ({', '.join(PARAMETERS)})")
        rig = [c for c in df.columns if c in CONDITION_VARIABLES or str(c).startswith("floor")]
        if rig:  # a design row sets parameters only: these values would be dropped and every heap take the rig's
            raise CalibError(f"design {design}: column(s) {', '.join(map(str, rig))} are condition variables, which "
                             "a design does not set: give them as a conditions table (--conditions FILE), crossed "
                             "with the design")
        twice = sorted(set(fixed) & set(cols))
        if twice:  # --set is for what the design lacks; the design's value would win in silence
            it = "it" if len(twice) == 1 else "them"
            raise CalibError(f"--set {', '.join(twice)}: the design {design} gives {it} per run; --set only what "
                             "the design lacks")
        _misspelt(df, design)
        dname = Path(design).parent.name
        ids = _run_ids(df, design) if "run_id" in df.columns else np.arange(1, len(df) + 1)
        for rid, (_, row) in zip(ids, df.iterrows()):
            given = {c: row[c].item() if isinstance(row[c], np.generic) else row[c] for c in cols}
            points.append((int(rid), {**fixed, **parse_params(given, f"design {design}, run_id {int(rid)}")}))
    else:
        points.append((0, fixed))
    from ..model import load_model

    model = load_model(run)
    if model.revision >= 1:  # a model file exists: absent effects are pinned at their neutral values
        for _, p in points:
            model.check(p)
        return [(rid, model.pin(p)) for rid, p in points], dname, model.hash
    return points, dname, ""


def _misspelt(df: pd.DataFrame, design: Path) -> None:
    """Refuses a design column that is not a parameter but reads like one ("rolling_fricton"): a design may
    carry other columns (run_id, step, responses, notes), but this one's values would be ignored and every
    heap would take that parameter's default, unseen."""
    import difflib

    for c in (c for c in df.columns if c not in PARAMETERS):
        close = difflib.get_close_matches(str(c), list(PARAMETERS), n=1, cutoff=0.8)
        if close and close[0] not in df.columns:
            raise CalibError(f"design {design}: column {c!r} is not a parameter: did you mean {close[0]}? (its "
                             f"values would be ignored and every heap would take {close[0]}'s default)")


#: ``--conditions preset``: the preset's rig even where the run has measured its own
PRESET_RIG = "preset"


def _measured_rigs(run: Path, quiet: bool = False) -> Optional[pd.DataFrame]:
    """The run's measured conditions where they give a rig (a condition variable's column), else None
    (none measured or none with a rig: then the preset's rig). A table that does not read is an error: heaps
    of the preset's rig in its place would answer another question in silence. Unless ``quiet``: where the
    preset's rig is asked for, or changed by --condition, the table is read for a note only."""
    path = Path(run) / CONDITIONS
    if not path.is_file():
        return None
    try:
        table = art.read_table(path, what="measured conditions")
    except CalibError:
        if quiet:
            return None
        raise
    return table if any(c in table.columns for c in CONDITION_VARIABLES) else None


def _which_conditions(run: Path, conditions: Optional[Path], changed: bool, measured: Optional[pd.DataFrame]):
    """The conditions table to simulate: the one given; else, unless ``--condition`` changed the preset's
    rig, the run's measured conditions where they give a rig (heaps of the rigs photographed, not the
    preset's); None for the preset's rig (``--conditions preset``, or no measured rig)."""
    if conditions is not None:
        return None if str(conditions) == PRESET_RIG else Path(conditions)
    return Path(run) / CONDITIONS if measured is not None and not changed else None


def _note_measured_rigs(run: Path, cond, measured: Optional[pd.DataFrame], say: Say) -> None:
    """Say so where the run's photographs were of rigs these heaps do not simulate (the preset's rig, or
    one changed by --condition, while RUN/measure/conditions.parquet gives the measured ones)."""
    if measured is None:
        return
    rig = [c for c in CONDITION_VARIABLES if c in measured.columns]
    if not all((measured[c] == getattr(cond, c)).all() for c in rig):
        say(f"[yellow]note:[/] {Path(run) / CONDITIONS} holds {len(measured)} measured rig(s) ({', '.join(rig[:3])}, "
            f"...) that these heaps do not simulate (theirs: {cond.particle_d_min_mm:g}-{cond.particle_d_max_mm:g} mm "
            f"grains, {cond.cylinder_diameter_mm:g} mm cylinder filled {cond.fill_height_mm:g} mm); without "
            f"--condition and --conditions preset, simulate-heap simulates the photographed rigs")


def read_conditions_table(path: Path) -> pd.DataFrame:
    """A conditions table (CSV or Parquet with a condition_id column); a missing or unreadable file
    is the user's error, not a traceback."""
    if not path.is_file():
        raise CalibError(f"conditions table not found: {path}")
    if path.suffix.lower() == ".parquet":
        ctab = check_conditions(art.read_table(path, columns=["condition_id"], what="conditions table"), path)
    else:
        ctab = read_conditions_csv(path, what="conditions table")
    if ctab.empty:  # no condition: no heap, and an empty campaign's summary failed (exit 70)
        raise CalibError(f"conditions table {path} has no rows")
    return ctab


def _run_ids(df: pd.DataFrame, design) -> np.ndarray:
    """A design's run ids: whole, non-negative and each once (a heap's seed derives from its run id: 1.7 would
    share run 1's and merge the two heaps, -1 or text stopped the seeding with a traceback)."""
    ids = pd.to_numeric(df["run_id"], errors="coerce").to_numpy(float)
    bad = ~np.isfinite(ids) | (ids < 0) | (ids != np.round(ids))
    if bad.any():
        raise CalibError(f"design {design}: run_id {df['run_id'].iloc[int(np.flatnonzero(bad)[0])]!r} is not a whole "
                         "number >= 0 (each design point's own)")
    twice = pd.Series(ids).duplicated()
    if twice.any():
        raise CalibError(f"design {design}: run_id {int(ids[twice.to_numpy()][0])} is given twice (each design point "
                         "its own)")
    return ids.astype(int)


@checked
def plan_simulation(run: Path, params: Pairs = None, design: Optional[Path] = None, repeats: int = 1, seed: int = 0,
                    preset: Optional[str] = None, shear_modulus: Optional[float] = None, condition: Pairs = None,
                    conditions: Optional[Path] = None, engine: Optional[str] = None, mpi: int = 1,
                    shape: str = "sphere",
                    force: bool = False, say: Optional[Say] = None) -> Plan:
    """Check everything and build the requests (nothing runs yet): every row of ``design`` (else one
    point) with ``params`` for what it lacks, under every condition of the ``conditions`` table (by
    default the run's measured ones where they give a rig; ``"preset"``: none) or the preset's rig
    changed by ``condition``, ``repeats`` seeds each. Says how many are cached, and notes
    a floor that follows the grains and cohesive grains at a reduced modulus. ``force``: recompute the
    cached heaps (each replaced only when its new result is complete). ``engine``: else the run's."""
    say = say or plain
    run = check_run_dir(run)
    if repeats < 1:  # the command line's option refuses it; a call from Python gets the same line
        raise CalibError(f"repeats must be at least 1 (got {repeats})")
    cfg = resolve_settings(run, None, None)
    engine = heap_engine(cfg, engine)
    precision = heap_precision(cfg, engine)  # before the engine's check: a mixed run refuses LAMMPS installed or not
    shapes = check_engine(engine, mpi, shape)
    preset, shear_modulus = heap_setup(cfg, preset, shear_modulus)
    pre = heap_preset(preset, shear_modulus, precision)
    changes = checked_condition(condition)
    cond = make_condition(pre.condition, changes)
    points, dname, mhash = _points(run, design, parse_params(given_pairs(params, "--set")))
    crossed = [("", cond)]
    # read for the note only where the heaps take the preset's rig, as asked (--conditions preset) or as
    # --condition changes it: a table that does not read is then no matter
    measured = (_measured_rigs(run, quiet=bool(condition)) if conditions is None else
                _measured_rigs(run, quiet=True) if str(conditions) == PRESET_RIG else None)
    conditions = _which_conditions(run, conditions, bool(condition), measured)
    if conditions is not None:
        conditions = Path(conditions)
        ctab = read_conditions_table(conditions)
        both = sorted(set(changes) & set(ctab.columns))
        if both:  # the table's value would win in silence
            raise CalibError(f"{', '.join(both)} given by --condition and by the conditions table {conditions}: "
                             "give each variable once (the table's column, or --condition for every row)")
        crossed = table_conditions(cond, ctab)
    requests = build_requests(points, crossed, pre.numerics, seed=seed, repeats=repeats, from_table=conditions is not None,
                              preset=preset, design=dname, model=mhash, engine=engine, mpi=mpi, shapes=shapes)
    if not requests:  # an empty design: nothing to run, and an empty campaign's summary failed (exit 70)
        raise CalibError(f"design {design} has no rows: nothing to simulate")
    walls = [interactions(req.params, req.condition) for req in requests]  # validate everything before anything runs
    have = [(run / RUNS / r.hash / "result.json").is_file() for r in requests]
    copied = 0 if force else sum(not h and reusable(r.hash) is not None for h, r in zip(have, requests))
    where = (f"its numerics, the rig of {len(crossed)} condition(s) from {conditions}" if conditions is not None
             else pre.note if cond == pre.condition
             else f"its numerics on the rig --condition makes: {cond.particle_d_min_mm:g}-{cond.particle_d_max_mm:g} mm "
                  f"grains, a {cond.cylinder_diameter_mm:g} mm cylinder filled {cond.fill_height_mm:g} mm, lifted at "
                  f"{cond.lift_speed_mm_s:g} mm/s")
    also = f", {copied} to copy from ${REUSE_ENV}" if copied else ""
    cached = (f"{sum(have)} cached, recomputed with --force (each kept until its new result is complete)"
              if force else f"{sum(have)} cached{also}")
    say(f"{len(requests)} run(s), {cached}; preset [bold]{preset}[/] ({where})" + modulus_note(shear_modulus)
        + precision_note(precision))
    if conditions is None:
        _note_measured_rigs(run, cond, measured, say)
    if floor_follows_grains(walls):
        say("[yellow]note:[/] the floor's static friction follows the grains' in these runs (no "
            "floor_static_friction in the conditions, no wall_static_friction): a rig's floor does not "
            "change with the grains, and on sphere heaps this choice can reverse static friction's effect "
            "(docs/physics.md, 'Wall friction'). Give the floor's measured values if you know them.")
    cohesive = cohesion_modulus_note(walls, pre.numerics.shear_modulus)
    if cohesive:
        say(f"[yellow]note:[/] {cohesive}")
    return Plan(run, requests, pre, force)


@checked
def run_simulation(plan: Plan, workers: int = 1, dask: Optional[str] = None, on_done: Optional[Callable] = None,
                   on_progress: Optional[Callable] = None) -> SimulateResult:
    """Run a :func:`plan_simulation`'s heaps (cached ones are read) on ``workers`` processes or a Dask
    cluster; ``on_done(request, row)`` after each heap, ``on_progress(t, t_max, phase)`` within one."""
    with art.run_lock(check_run_dir(plan.run)):
        rows = run_campaign(plan.requests, plan.run, workers, on_done=on_done, on_progress=on_progress, dask=dask,
                            force=plan.force)
    return SimulateResult(plan.run, rows)


@writes_run
def simulate_heap(run: Path, params: Pairs = None, design: Optional[Path] = None, *, workers: int = 1,
                  dask: Optional[str] = None, say: Optional[Say] = None, **options) -> SimulateResult:
    """Plan and run a simulation (:func:`plan_simulation` takes the ``options``): writes
    RUN/simulate/results.parquet and RUN/simulate/runs/<hash>/ per heap. Raises if no heap formed."""
    check_dask(dask)
    result = run_simulation(plan_simulation(run, params, design, say=say, **options), workers, dask)
    for note in result.notes(markup=True):
        (say or plain)(note)
    return result.check()
