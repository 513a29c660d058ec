"""What every stage shares: the run directory's settings, designs and simulated responses, the
messages a stage gives while it runs, and the result it returns.

A stage is a plain function ``stage(run, ...) -> Result``: it reads and writes the run directory
(through :mod:`calib_cli.artifacts`), skips itself when its inputs and settings are unchanged, and
returns a result whose ``summary()`` is what the command line prints. Notes and warnings it gives
while it runs (rich markup) go to ``say``: the command line prints them on its consoles, and
without one they are printed as plain text.
"""

from __future__ import annotations

import functools
import inspect
import os
import sys
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Optional, Protocol, TypeVar, Union

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..dem.heap import Numerics
from ..errors import CalibError
from ..model import MAX_REVISION
from ..heaps.index import heap_setups, row_laws, row_moduli
from ..settings import load_settings
from ..space import ParameterSpace

SETTINGS_FILE = "settings.toml"
#: left by `calib init` beside the settings file: a run that has it and lacks the file lost it
INITIALISED = ".initialised"
R = TypeVar("R")

#: The version of each stage's code (by its folder in the run directory). Raise a stage's number when a
#: change moves what it writes: its locks then stop being up to date, so every run directory recomputes
#: it (and the stages after it, whose inputs move). tests/test_stage_versions.py recomputes the paper's
#: committed chain and fails when a stage's outputs moved at an unchanged version, or when a committed
#: lock's version is not the code's (regenerate that run: make paper).
#: measure 2: heaps that are not cones (a standing column, cut by the frame, ...) are left out of the statistics
#: diagnose 2: the ranking names the parameter each candidate is confounded with (confounded_with, confound)
#: suggest 3: an information gain beyond the simulated heaps' range is shown, not ranked
#: posterior 3: a changing pile scatter is a Gaussian process over the repeated piles' log variances
#: posterior 4: with --scatter, that process's error is shared by a parameter set's conditions
#: suggest 4: its surrogate's pile variances are that process's
#: posterior 6: the scatter and the profile weighed wherever they can be; no verdict while the surrogate is unsure;
#: a Bayes factor with no draw near its value is an upper bound
#: posterior 8, calibrate-answer 3: a posterior pressed against a bound of its box that could be wider is not
#: identified (its `edge` column)
#: posterior 9, calibrate 2, calibrate-answer 4: the surrogate/measurement variance ratio over 4,096 posterior
#: draws, not 256 (its Monte Carlo spread was as wide as its distance from the bar)
#: posterior 10, calibrate 3, calibrate-answer 5: each condition's pile variance moderated across the
#: conditions (limma's empirical Bayes) in the measured means' variances
#: compare 2: chi2/dof divides by the degrees of freedom the fit took from the measured means, not C - p;
#: 3: its figures tell the conditions apart and draw chi2/dof beside the RMSE
#: synth-lab 1: a synthetic lab's photographs, conditions.csv and truth.toml (its folder is the stage's group)
#: posterior 11, calibrate 4, calibrate-answer 6: while a parameter presses against an edge of its box no
#: parameter is identified and no effect gets a verdict (the `box_cut` column)
#: posterior 12, calibrate-answer 7: an effect whose Bayes factor the box cuts is not averaged on and off
#: (answers locked at 11 / 6 before that change could still hold the average)
#: posterior 13, calibrate-answer 8: the verdict of an effect the data favour off says off, not "0 to 0";
#: 14 / 9: nor is that parameter called identified (its narrow interval is the off model's neutral value)
#: suggest 6: each gain's 90 % range over the surrogate's own uncertainty, its chance of being the largest and
#: what it may lose against the best (info_gain_q05/q95, p_best_gain, gain_regret_q90), and region_heaps
#: suggest 7: the realisations read at evenly spaced draws (a stride gave up to twice the points asked)
#: diagnose 3: ranked by p-value (a one-sided candidate's is halved), and a residual's trend is quoted as observed
#: only where it is significant
CODE_VERSIONS = {"measure": 2, "pb": 1, "ascent": 1, "bbd": 1, "surrogate": 1, "invert": 1, "compare": 3,
                 "diagnose": 3, "posterior": 14, "suggest": 7, "calibrate": 4,
                 "calibrate-answer": 9, "synth-lab": 1}


def stage(run: Path, group: str, name: str, version: Optional[str] = None, **kwargs) -> art.Stage:
    """The :class:`~calib_cli.artifacts.Stage` of a stage function, at its code's version (that of
    ``version`` where a group's stages change apart)."""
    return art.Stage(run, group, name, code=CODE_VERSIONS[version or group], **kwargs)


#: what an argument of each simple annotation must be, and how a message names it; "pair" is
#: ``tuple[float, float]`` (measure's band), "names" ``tuple[str, ...]`` (suggest's effects to simulate)
_KINDS = {int: "an integer", float: "a number", bool: "True or False", str: "a string",
          Path: "a path (str or Path)", "pair": "two numbers", "names": "a name or a list of names (strings)"}

#: the range of the library's count and seed arguments, by name (where the argument is an integer): the
#: command line's options take the same (a seed is numpy's, a count beyond these runs out of memory or time)
ARG_RANGES = {"seed": (0, 2 ** 32 - 1), "repeats": (1, 1000), "workers": (1, 1024), "budget": (1, 100_000),
              "first": (1, 100_000), "batch": (1, 100_000), "walkers": (2, 10_000), "steps": (10, 10_000_000),
              "design": (0, 1_000_000), "validate": (0, 1000), "refine": (0, 100), "top": (1, 10_000),
              "piles": (1, 10_000), "at_revision": (0, MAX_REVISION), "revision": (0, MAX_REVISION), "heaps": (0, 10_000)}


def _kind(hint) -> Optional[tuple]:
    """The simple type an annotation asks for (:data:`_KINDS`, or a class of calib's own, a :class:`Plan`
    say) and whether None is allowed; None where the annotation is anything else (a dict, a callable, a
    union of types), which is not checked here."""
    if typing.get_origin(hint) in (Union, types.UnionType):
        rest = [a for a in typing.get_args(hint) if a is not type(None)]
        one = _kind(rest[0]) if len(rest) == 1 else None
        return (one[0], len(rest) < len(typing.get_args(hint))) if one else None
    if hint in _KINDS:
        return hint, False
    if typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        if args == (float, float):
            return "pair", False
        if args == (str, ...):
            return "names", False
    if isinstance(hint, type) and hint.__module__.startswith("calib_cli.") and not issubclass(hint, Protocol):
        return hint, False
    return None


def _fits(value, kind: type) -> bool:
    if kind is bool:
        return isinstance(value, (bool, np.bool_))
    if isinstance(value, (bool, np.bool_)):
        return False  # True is an int to Python, not a budget
    if kind is int:
        return isinstance(value, (int, np.integer))
    if kind is float:
        return isinstance(value, (int, float, np.integer, np.floating))  # NaN and range: the stage's own checks
    if kind is Path:
        return isinstance(value, (str, os.PathLike))
    if kind == "pair":
        return (isinstance(value, (tuple, list, np.ndarray, pd.Series)) and len(value) == 2
                and all(_fits(v, float) for v in value))
    if kind == "names":  # one name, or a collection of them (a column of a table)
        return isinstance(value, str) or (isinstance(value, (tuple, list, set, frozenset, np.ndarray, pd.Series,
                                                             pd.Index))
                                          and all(isinstance(v, str) for v in value))
    return isinstance(value, kind)


def _what(kind) -> str:
    return _KINDS.get(kind) or f"a {kind.__name__}"


def checked(fn: Callable[..., R]) -> Callable[..., R]:
    """A library entry point whose arguments of a simple annotation (int, float, bool, str, Path, or one of
    them or None) are checked before it runs, and its integer counts and seeds against :data:`ARG_RANGES`:
    ``calibrate(run, budget="x")`` fails with one line naming the argument, not with Python's error from
    deep inside the stage."""
    sig, kinds = inspect.signature(fn), None

    @functools.wraps(fn)
    def call(*args, **kwargs):
        nonlocal kinds
        if kinds is None:  # on the first call: the module's names exist only once it is imported
            try:
                hints = typing.get_type_hints(fn)
            except Exception:  # an annotation this Python cannot resolve: nothing is checked, as before
                hints = {}
            kinds = {n: k for n, h in hints.items() if (k := _kind(h)) is not None}
        try:
            bound = sig.bind(*args, **kwargs)
        except TypeError as e:
            raise CalibError(f"{fn.__name__}: {e}") from None
        for name, value in bound.arguments.items():
            kind = kinds.get(name)
            if not kind or (value is None and kind[1]):
                continue
            if not _fits(value, kind[0]):
                raise CalibError(f"{fn.__name__}({name}={_short(value)}): {name} takes {_what(kind[0])}"
                                 + (" or None" if kind[1] else ""))
            lo, hi = ARG_RANGES.get(name, (None, None)) if kind[0] is int else (None, None)
            if lo is not None and not lo <= value <= hi:
                raise CalibError(f"{name} {value} is out of range ({lo} to {hi})")  # reads as --name too
        return fn(*args, **kwargs)

    return call


def _short(value) -> str:
    """An argument as a one-line message shows it: a DataFrame's or an array's repr runs to many lines."""
    text = repr(value)
    return text if "\n" not in text and len(text) <= 80 else f"<{type(value).__name__}>"


def writes_run(fn: Callable[..., R]) -> Callable[..., R]:
    """A stage function that writes its run directory (its first argument) holds the run's lock
    (:func:`~calib_cli.artifacts.run_lock`) for its whole call: a second command on the same run
    directory then fails at once instead of losing rows of the tables both rewrite. Its arguments are
    :func:`checked` first."""

    @checked
    @functools.wraps(fn)
    def locked(*args, **kwargs):
        run = check_run_dir(args[0] if args else kwargs["run"])
        new = not run.exists() and kwargs.get("settings") is None
        with art.run_lock(run):
            result = fn(*args, **kwargs)
        # a mistyped --run would otherwise go on quietly, on settings nobody chose (init writes the run's own)
        if new and run.is_dir() and not (run / SETTINGS_FILE).is_file():
            (kwargs.get("say") or plain)(f"note: {run} was a new run directory, on the built-in settings (`calib "
                                         f"init --run {run} --settings FILE` gives it yours)")
        return result

    return locked


class Say(Protocol):
    def __call__(self, message: str, err: bool = False) -> None: ...


def plain(message: str, err: bool = False) -> None:
    """Print a stage's message (rich markup) as plain text: the default outside the command line."""
    from rich.text import Text

    print(Text.from_markup(message).plain, file=sys.stderr if err else sys.stdout)


def shown(lines: list[str], markup: bool) -> list[str]:
    """A result's lines as the command line prints them (``markup``: rich markup kept for its console), else
    as plain text, for a notebook."""
    if markup:
        return lines
    from rich.text import Text

    return [Text.from_markup(line).plain for line in lines]


@dataclass
class Result:
    """What a stage did: its :class:`~calib_cli.artifacts.Stage` (``.dir`` holds the artefacts) and
    whether it was skipped (inputs and settings unchanged). Subclasses add their tables."""

    stage: art.Stage
    skipped: bool = False

    @property
    def dir(self) -> Path:
        return self.stage.dir

    def summary(self):
        return f"{self.stage.group} {self.stage.name}: " + ("up to date" if self.skipped else f"wrote {self.dir}")


def resolve_settings(run: Path, settings: Optional[Path], overrides: Optional[Iterable[str]]) -> dict:
    files = []
    if settings is not None:
        files.append(settings)
    elif (Path(run) / SETTINGS_FILE).is_file():
        files.append(Path(run) / SETTINGS_FILE)
    elif (Path(run) / SETTINGS_FILE).exists():  # a folder there: the defaults would stand in for the user's
        raise CalibError(f"{Path(run) / SETTINGS_FILE} is not a file: move it aside (calib init --run {run} "
                         "--settings FILE writes it)")
    elif (Path(run) / INITIALISED).is_file():  # the built-in defaults would silently stand in for the user's
        raise CalibError(f"{Path(run) / SETTINGS_FILE} is missing (calib init wrote it): restore it, or write it "
                         f"again with calib init --run {run} --settings FILE")
    return load_settings(files, overrides or ())


def check_run_dir(run: Path) -> Path:
    run = Path(run)
    if run.exists() and not run.is_dir():
        raise CalibError(f"--run {run} exists and is not a directory")
    return run


def check_not_empty(run: Path) -> None:
    """Refuse a run directory with nothing in it (a mistyped --run, which the run lock has just made) for a
    command that reads what others wrote: 'no calibrated value' sent its user to calibrate the wrong folder."""
    if not run.is_dir() or not any(p.name != art.RUN_LOCK for p in run.iterdir()):
        raise CalibError(f"{run} holds nothing yet (no measurement, no calibration): is --run the right folder?")


def warn_other_modulus(run: Path, shear_modulus: Optional[float], what: str, say: Optional[Say] = None) -> None:
    """Warn when the run's design heaps (what a surrogate was fitted to) had another shear modulus."""
    from ..heaps.index import current_results

    rows = current_results(run)
    if rows.empty or "design" not in rows.columns:
        return
    rows = rows[rows["design"].isin(["pb", "ascent", "bbd"])]
    want = Numerics.shear_modulus if shear_modulus is None else shear_modulus
    have = set(row_moduli(rows))
    if have - {want}:
        (say or plain)(f"[yellow]warning:[/] the design heaps of {run} were simulated at a shear modulus of "
                          f"{', '.join(f'{m / 1e6:g}' for m in sorted(have))} MPa, {what} at {want / 1e6:g} MPa: "
                          f"give --shear-modulus the same value (docs/physics.md, 'Stiffness')", err=True)


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
    from ..heaps.index import current_results

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
    from ..heaps.index import current_results

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


