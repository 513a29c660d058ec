"""Shared CLI plumbing: options, settings resolution, errors, rich tables."""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
from pathlib import Path
from typing import Annotated, Callable, Iterable, Optional

import numpy as np
import pandas as pd
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from .. import artifacts as art
from ..campaign import heap_setups, row_laws, row_moduli  # noqa: F401 (re-exported: the CLI's helpers)
from ..dem.heap import Numerics, Preset, get_preset
from ..errors import CalibError
from ..settings import load_settings
from ..space import ParameterSpace

console = Console()
err_console = Console(stderr=True)

RunOpt = Annotated[Path, typer.Option("--run", help="Run directory (created if missing).", show_default=False)]
SettingsOpt = Annotated[
    Optional[Path],
    typer.Option("--settings", help="Settings TOML (default: RUN/settings.toml if present, else built-in paper setup)."),
]
SettingOpt = Annotated[
    Optional[list[str]],
    typer.Option("--setting", "-s", help="Override one setting, e.g. -s pb.alpha=0.1 (repeatable)."),
]
ForceOpt = Annotated[bool, typer.Option("--force", help="Rerun even if inputs and settings are unchanged.")]
ResponsesOpt = Annotated[
    Optional[Path],
    typer.Option("--responses", help="CSV/Parquet of responses (factor columns in natural units + repose_angle) "
                                     "from another engine or a paper, instead of simulated results."),
]

ShearModulusOpt = Annotated[
    Optional[float],
    typer.Option("--shear-modulus", help="Shear modulus of the grains and walls [Pa]. Default: the run's setting "
                 "heap.shear_modulus (where the command has a run), else the preset's reduced 5 MPa. Cohesive "
                 "heaps depend on it (docs/physics.md, 'Stiffness'); the time step shrinks as G^-1/2. Set it once "
                 "for a run, as heap.shear_modulus in RUN/settings.toml, rather than on each command.",
                 show_default=False),
]

SETTINGS_FILE = "settings.toml"

#: Pa: the accepted shear moduli (a soft gel to steel); outside, a typo rather than a material
SHEAR_MODULUS_RANGE = (1e5, 1e11)


def heap_preset(name: str, shear_modulus: Optional[float] = None) -> Preset:
    """The named preset, with the grains' and walls' shear modulus replaced when one is given."""
    pre = get_preset(name)
    if shear_modulus is None:
        return pre
    lo, hi = SHEAR_MODULUS_RANGE
    if not (np.isfinite(shear_modulus) and lo <= shear_modulus <= hi):
        raise CalibError(f"shear modulus {shear_modulus:g} Pa (--shear-modulus or heap.shear_modulus) is outside "
                         f"[{lo:g}, {hi:g}] Pa")
    num = dataclasses.replace(pre.numerics, shear_modulus=float(shear_modulus), wall_shear_modulus=float(shear_modulus))
    return dataclasses.replace(pre, numerics=num)


def heap_setup(cfg: dict, preset: Optional[str], shear_modulus: Optional[float]) -> tuple[str, Optional[float]]:
    """The preset and shear modulus of a command's heaps: the option where given, else the run's
    settings (``[heap]`` preset and shear_modulus), else ``default`` at its own reduced modulus.

    A modulus equal to the preset's own comes back as None, so that naming it changes neither the
    heaps' cache keys nor the stages' hashes. The preset and the modulus are checked here, before
    any stage or heap starts.
    """
    name = preset if preset is not None else cfg["heap"]["preset"]
    g = shear_modulus if shear_modulus is not None else cfg["heap"]["shear_modulus"]
    g = None if g is None else float(g)
    try:
        heap_preset(name, g)
    except CalibError as e:
        if preset is None and shear_modulus is None:
            raise CalibError(f"the run's heap settings: {e}") from None
        raise
    own = get_preset(name).numerics
    if own.shear_modulus == own.wall_shear_modulus == g:  # the preset itself, to the last bit
        g = None
    return name, g


def modulus_settings(shear_modulus: Optional[float]) -> dict:
    """The modulus as a stage setting, only when given: stages run at the presets' modulus keep their hash."""
    return {} if shear_modulus is None else {"shear_modulus": shear_modulus}


def warn_other_modulus(run: Path, shear_modulus: Optional[float], what: str) -> None:
    """Warn when the run's design heaps (what a surrogate was fitted to) had another shear modulus."""
    from ..campaign import current_results

    rows = current_results(run)
    if rows.empty or "design" not in rows.columns:
        return
    rows = rows[rows["design"].isin(["pb", "ascent", "bbd"])]
    want = Numerics.shear_modulus if shear_modulus is None else shear_modulus
    have = set(row_moduli(rows))
    if have - {want}:
        err_console.print(f"[yellow]warning:[/] the design heaps of {run} were simulated at a shear modulus of "
                          f"{', '.join(f'{m / 1e6:g}' for m in sorted(have))} MPa, {what} at {want / 1e6:g} MPa: "
                          f"give --shear-modulus the same value (docs/physics.md, 'Stiffness')", highlight=False)


def modulus_note(shear_modulus: Optional[float]) -> str:
    return "" if shear_modulus is None else f", shear modulus {shear_modulus / 1e6:g} MPa"


#: set while a pipeline runs a command in-process (calib run): its errors reach the pipeline, which names the step
_PROPAGATE = contextvars.ContextVar("calib_errors_propagate", default=False)


@contextlib.contextmanager
def errors_propagate():
    """Commands called inside raise their CalibError and KeyboardInterrupt instead of printing them and exiting."""
    token = _PROPAGATE.set(True)
    try:
        yield
    finally:
        _PROPAGATE.reset(token)


def handle_errors(fn: Callable) -> Callable:
    """A user error becomes one red line and exit code 2; Ctrl-C exits 130 (inside errors_propagate: raised)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if _PROPAGATE.get():
            return fn(*args, **kwargs)
        try:
            return fn(*args, **kwargs)
        except CalibError as e:
            # escape: a message may hold brackets ('.[lammps]', [low, high]) that rich reads as markup
            err_console.print(f"[bold red]error:[/] {escape(str(e))}", highlight=False, soft_wrap=True)
            raise typer.Exit(2) from None
        except KeyboardInterrupt:
            err_console.print("[bold red]interrupted:[/] nothing partial was written to the run directory")
            raise typer.Exit(130) from None

    return wrapper


def resolve_settings(run: Path, settings: Optional[Path], overrides: Optional[Iterable[str]]) -> dict:
    files = []
    if settings is not None:
        files.append(settings)
    elif (Path(run) / SETTINGS_FILE).is_file():
        files.append(Path(run) / SETTINGS_FILE)
    return load_settings(files, overrides or ())


def check_run_dir(run: Path) -> Path:
    run = Path(run)
    if run.exists() and not run.is_dir():
        raise CalibError(f"--run {run} exists and is not a directory")
    return run


def skipped(stage: art.Stage) -> None:
    console.print(f"[green]✓[/] {stage.group} {stage.name}: inputs and settings unchanged, nothing to do "
                  f"(use --force to rerun)")


def space_from_design(path: Path) -> ParameterSpace | None:
    if not Path(path).is_file():
        return None
    prov = art.read_provenance(path)
    if "space" not in prov:
        return None
    return ParameterSpace.from_dicts(prov["space"])


def match_to_design(design: pd.DataFrame, results: pd.DataFrame, factors: list[str], response: str,
                    stage: str | None = None) -> pd.DataFrame:
    """Mean response (over repeats) of the results at each design run.

    Results written by ``simulate-heap --design`` carry ``design`` and ``run_id``
    and are matched by them, so that two runs of a design at the same point (a
    Plackett-Burman design can repeat a point in its factor columns) stay separate
    replicates; other results are matched by their factor values.
    """
    X = design[factors].to_numpy(dtype=float)
    R = results[factors].to_numpy(dtype=float)
    yv = results[response].to_numpy(dtype=float)
    by_id = stage is not None and {"design", "run_id"} <= set(results.columns) and "run_id" in design.columns
    means, counts, runs = [], [], []
    for i, row in enumerate(X):
        if by_id:
            hit = ((results["design"] == stage) & (results["run_id"] == design["run_id"].iloc[i])).to_numpy().copy()
            hit &= np.all(np.isclose(R, row[None, :], rtol=1e-9, atol=1e-12), axis=1)
        else:
            hit = np.all(np.isclose(R, row[None, :], rtol=1e-9, atol=1e-12), axis=1)
        runs.append(int(hit.sum()))
        hit &= np.isfinite(yv)
        counts.append(int(hit.sum()))
        means.append(float(yv[hit].mean()) if hit.any() else np.nan)
    out = design.copy()
    out[response] = means
    out["n_repeats"] = counts
    out["n_runs"] = runs  # simulated, with or without a response (a column, no heap, a timeout)
    return out


def bbd_fixed(run: Path, cfg: dict) -> dict[str, float]:
    """Heap parameters the response surface held fixed: the constant parameter columns of
    RUN/bbd/design.parquet (what the surrogate was trained at), else settings bbd.fixed.
    Simulations at the calibrated point (validation, compare) must use the same values."""
    from ..dem.heap import PARAMETERS

    path = Path(run) / "bbd" / "design.parquet"
    if path.is_file():
        d = art.read_table(path, what="BBD design")
        return {**{c: float(d[c].iloc[0]) for c in d.columns if c in PARAMETERS and d[c].nunique() == 1},
                **bbd_laws(run)}
    return {k: float(v) for k, v in cfg["bbd"]["fixed"].items() if k in PARAMETERS}


def bbd_laws(run: Path) -> dict[str, float]:
    """The contact-law switches (e.g. ``rolling_spring`` 1) every heap of the BBD was simulated with
    (`simulate-heap --set`): the surrogate learnt that law, so the calibrated point is simulated
    with it too. Only laws switched on, so that runs with the default laws keep their cache keys."""
    from ..campaign import current_results

    if not (Path(run) / "simulate" / "results.parquet").is_file():
        return {}
    rows = current_results(run)
    rows = rows[rows["design"] == "bbd"] if "design" in rows.columns else rows.iloc[:0]
    laws = row_laws(rows)
    return {k: v for k, v in laws[0].items() if all(law.get(k) == v for law in laws)} if laws else {}


def simulated_responses(run: Path, design_path: Path, factors: list[str], response: str,
                        allow_failed: bool = False) -> pd.DataFrame:
    """The design's rows with the simulated response from RUN/simulate/results.parquet.

    Every design run must have been simulated. A run simulated without a response (no heap,
    a standing column, a timeout) is an error unless ``allow_failed`` (the ascent path, whose
    steps need not all form heaps): its response is then NaN."""
    results_path = Path(run) / "simulate" / "results.parquet"
    hint = (f"run `calib simulate-heap --run {run} --design {design_path}` first, "
            f"or pass --responses FILE with responses from another engine")
    if not Path(design_path).is_file():
        raise CalibError(f"no design at {design_path}; create it first (`design` subcommand) or pass --responses FILE")
    if not results_path.is_file():
        raise CalibError(f"no simulated responses in {run}: {hint}")
    from ..campaign import current_results

    design = art.read_table(design_path, what="design")
    art.read_table(results_path, columns=[*factors, response], what="simulation results")  # validates the file
    results = current_results(run)
    if results.empty:
        raise CalibError(f"no simulated responses of the current kernel in {run}: {hint}")
    stage = Path(design_path).parent.name
    setups = heap_setups(results[results["design"] == stage] if "design" in results.columns else results)
    if len(setups) > 1:
        raise CalibError(f"the {stage} design's heaps in {run} were simulated with {len(setups)} setups "
                         f"({'; '.join(setups)}), which the analysis would average as repeats: keep one preset "
                         f"and shear modulus per run directory")
    out = match_to_design(design, results, factors, response, stage=stage)
    missing = int((out["n_runs"] == 0).sum())
    if missing:
        raise CalibError(f"{missing} of {len(out)} design runs have not been simulated: {hint}")
    failed = out.index[out["n_repeats"] == 0]
    if len(failed) and not allow_failed:
        ids = ", ".join(str(v) for v in out.loc[failed, "run_id"]) if "run_id" in out.columns else str(len(failed))
        raise CalibError(f"design run(s) {ids} were simulated but gave no angle (no heap, a standing column or a "
                         f"timeout; see the status column of {results_path}): the fit needs a response at every run - "
                         f"narrow the factor ranges, or pass --responses FILE")
    return out


def fmt(v, digits: int = 5) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(v)
    if isinstance(v, (float, np.floating)):
        return f"{v:.{digits}g}" if np.isfinite(v) else ""
    return str(v)


def pvalue(p: float) -> str:
    return "<0.0001" if p < 1e-4 else f"{p:.4f}"


def df_table(df: pd.DataFrame, title: str, formats: dict[str, Callable] | None = None) -> Table:
    formats = formats or {}
    t = Table(title=title, title_justify="left", header_style="bold")
    for c in df.columns:
        t.add_column(str(c), justify="left" if df[c].dtype == object else "right")
    for _, r in df.iterrows():
        t.add_row(*[escape(formats.get(c, fmt)(r[c])) for c in df.columns])
    return t

