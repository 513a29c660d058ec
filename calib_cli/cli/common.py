"""Shared CLI plumbing: options, settings resolution, errors, rich tables.

Light on purpose: `calib --help` and every command's --help import this package, so nothing here
(nor in the command modules) imports numpy, pandas or a stage at import time; what a command needs
it imports when it runs (tests/test_startup.py holds that, benchmarks/startup.py times it)."""

from __future__ import annotations

import contextlib
import contextvars
import errno
import functools
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Callable, Optional

import typer
from rich.console import Console, Group
from rich.markup import escape
from rich.table import Table
from typer.core import TyperCommand, TyperGroup

from ..errors import CalibError
from ..parameters import PRESET_NAMES

if TYPE_CHECKING:
    import pandas as pd

    from .. import artifacts as art


def check_run_dir(run: Path) -> Path:
    """calib_cli.stages.common.check_run_dir, imported when a command runs (it imports pandas)."""
    from ..stages.common import check_run_dir as check

    return check(run)


def _bare_flags(params) -> None:
    """A flag takes no value, so its help shows none: typer would show <bool>, which reads as if
    `--force true` were the way to write it (it fails: 'unexpected extra argument')."""
    for p in params:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""


def split_commas(params, args: list[str]) -> list[str]:
    """`--band 0.1,0.9` (or `--band=0.1,0.9`) read as `--band 0.1 0.9`: an option of N values takes them
    comma-separated as well as space-separated. A value with another number of commas is left as it was."""
    nargs = {o: p.nargs for p in params if getattr(p, "param_type_name", "") == "option" and p.nargs > 1
             for o in p.opts}
    if not nargs:
        return list(args)
    out, i = [], 0
    while i < len(args):
        a = args[i]
        i += 1
        if a == "--":
            return [*out, a, *args[i:]]
        name, eq, value = a.partition("=")
        if name in nargs and (eq or i < len(args)):
            if not eq:
                value = args[i]
                i += 1
            parts = value.split(",")
            out += [name, *parts] if len(parts) == nargs[name] else [a] if eq else [a, value]
            continue
        out.append(a)
    return out


def unwrap_paragraphs(text: Optional[str]) -> Optional[str]:
    """Each paragraph of a command's help on one line, to be wrapped at the terminal's width: typer joins the
    first paragraph's lines but keeps the later ones' line breaks, which a terminal narrower than the
    docstring shows as ragged lines. Blocks marked ``\\b`` (click's "keep as written") are kept, and what
    follows a ``\\f`` (click's "not for --help") is dropped, as typer would."""
    if not text:
        return text
    return "\n\n".join(p if p.lstrip().startswith("\b") else " ".join(p.split())
                       for p in text.partition("\f")[0].split("\n\n"))


class CalibCommand(TyperCommand):
    """Every calib command: flags shown without a value, options of several values comma-separated too."""

    def format_help(self, ctx, formatter) -> None:
        _bare_flags(self.get_params(ctx))
        self.help = unwrap_paragraphs(self.help)
        return super().format_help(ctx, formatter)

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        _refuse_empty_run(ctx, args)
        return super().parse_args(ctx, split_commas(self.params, args))


def _refuse_empty_run(ctx, args: list[str]) -> None:
    """An empty --run (a script's unset variable: --run "$RUN") would be read as the current directory and put
    a run's files into whatever folder the command ran in: refused, as click would a bad value."""
    for i, a in enumerate(args):
        value = args[i + 1] if a == "--run" and i + 1 < len(args) else a[6:] if a.startswith("--run=") else None
        if value is not None and not value.strip():
            raise typer.BadParameter("is empty: give the run directory", ctx, param_hint="'--run'")


class CalibGroup(TyperGroup):
    """calib and its sub-apps (model, pb, ascent, bbd): their own --help shows flags without a value."""

    def format_help(self, ctx, formatter) -> None:
        _bare_flags(self.get_params(ctx))
        self.help = unwrap_paragraphs(self.help)
        return super().format_help(ctx, formatter)

#: Output to a log or a pipe (make, CI) is 120 columns, not rich's 80, which cut the result tables' headers
#: to "sta…"; a terminal's own width and $COLUMNS still win.
_WIDTH = None if sys.stdout.isatty() or os.environ.get("COLUMNS") else 120
console = Console(width=_WIDTH)
err_console = Console(stderr=True, width=_WIDTH)

RunOpt = Annotated[Path, typer.Option("--run", help="Run directory (docs/artefacts.md lists what it holds). One "
                                               "command writes it at a time: a second stops with an error naming "
                                               "the first.", show_default=False)]
SettingsOpt = Annotated[
    Optional[Path],
    typer.Option("--settings", help="Settings TOML (default: RUN/settings.toml if present, else built-in paper setup)."),
]
SettingOpt = Annotated[
    Optional[list[str]],
    typer.Option("--setting", "-s", help="Override one setting, e.g. -s pb.alpha=0.1 (repeatable)."),
]
ForceOpt = Annotated[bool, typer.Option("--force", help="Rerun even if inputs and settings are unchanged.")]
SideViewsOpt = Annotated[bool, typer.Option("--side-views", help="The surrogates learn each simulated heap from the "
                                           "mean of its 4 side views instead of the one a photograph has (where every "
                                           "heap in the fit recorded them; heaps from older versions did not); the "
                                           "hidden-effect and control pipelines use it after `calib model add`: "
                                           "docs/method.md.")]


def _evidence_switch(name: str, help: str):
    """A --NAME/--no-NAME option for one piece of the posterior's evidence; unset (None) means the default."""
    return Annotated[Optional[bool], typer.Option(f"--{name}/--no-{name}", show_default=False, help=help)]


ScatterOpt = _evidence_switch(
    "scatter", "Weigh each condition's pile-to-pile scatter as well as its mean: cohesive heaps scatter more than dry "
    "ones of the same mean angle. It assumes the lab's piles scatter as the simulated ones do (no operator or photo "
    "scatter beyond). Default: wherever the simulated scatter changes with the parameters.")
ProfileOpt = _evidence_switch(
    "profile", "Weigh each condition's heap profile as well as its angle: the photographs' mean fullness (1 for a "
    "cone's straight flanks, above 1 for convex ones) against the simulated heaps' side views. It assumes the "
    "photographs show the heap's silhouette as the side views do. Default: wherever the photographs and enough heaps "
    "give one.")
ColumnsOpt = _evidence_switch(
    "columns", "Weigh how many of each condition's photographed piles stood as columns, against the chance that a "
    "simulated fill stands. Default: wherever the photographs were measured and some simulated fill stood.")
SeedsOpt = Annotated[Optional[str], typer.Option(
    "--seeds", show_default=False,
    help="How the heaps are seeded: condition (by the condition's name and values, so its heaps stay the same, and "
    "cached, when the measured table gains, loses or reorders rows) or table (by the condition's row, as runs made "
    "before this option were seeded). Default: as the run's comparison was seeded, and condition for a run's first.")]
AtRevisionOpt = Annotated[Optional[int], typer.Option("--at-revision", min=0, help="Do nothing unless the model is at "
                                                     "this revision (a pipeline's step for one revision).",
                                                     show_default=False)]
ResponsesOpt = Annotated[
    Optional[Path],
    typer.Option("--responses", help="CSV/Parquet of responses (factor columns in natural units + repose_angle) "
                                     "from another engine or a paper, instead of simulated results."),
]

#: the presets, in one help text for every command that simulates
PRESETS_HELP = (" | ".join(PRESET_NAMES) + ": the heaps' geometry (where no conditions table gives it), particle count "
                "and numerics.")
PresetOpt = Annotated[Optional[str], typer.Option(help=PRESETS_HELP + " Default: the run's setting heap.preset, else "
                                                  "default.", show_default=False)]

ShearModulusOpt = Annotated[
    Optional[float],
    typer.Option("--shear-modulus", help="Shear modulus of the grains and walls [Pa]. Default: the run's setting "
                 "heap.shear_modulus (where the command has a run), else the preset's reduced 5 MPa. Cohesive "
                 "heaps depend on it (docs/physics.md, 'Stiffness'); the time step shrinks as G^-1/2. Set it once "
                 "for a run, as heap.shear_modulus in RUN/settings.toml, rather than on each command.",
                 show_default=False),
]

def say(message: str, err: bool = False) -> None:
    """A stage's message (rich markup) on the console, a warning on stderr."""
    if err:
        err_console.print(message, highlight=False)
    else:
        console.print(message)


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
            # a campaign keeps the heaps it finished: "nothing was written" would send a user to redo them
            err_console.print("[bold red]interrupted:[/] nothing partial was written to the run directory (finished "
                              "heaps and stages are kept; the same command resumes)")
            raise typer.Exit(130) from None
        except OSError as e:
            said = os_error_words(e)
            if said is None:
                raise
            err_console.print(f"[bold red]error:[/] {escape(said)}", highlight=False, soft_wrap=True)
            raise typer.Exit(2) from None

    return wrapper


#: the write failures that are the machine's state, not a bug: a one-line error (exit 2), not exit 70
_UNWRITABLE = {errno.EACCES: "the folder is read-only or not yours", errno.EPERM: "not permitted",
               errno.EROFS: "a read-only file system", errno.ENOSPC: "the disk is full",
               errno.EDQUOT: "the disk quota is used up"}
#: a path of the wrong kind, or one gone meanwhile: what a user (or another program) did to the run directory
_MISPLACED = {errno.EISDIR: "a folder where a file belongs", errno.ENOTDIR: "a file where a folder belongs",
              errno.ENOENT: "it does not exist, or was removed meanwhile",
              errno.ENAMETOOLONG: "a name longer than the file system takes",
              errno.ELOOP: "symbolic links that lead round in a circle"}


def os_error_words(e: OSError):
    """One line for an OSError that is the machine's or the run directory's state (None for another: a bug)."""
    where = str(e.filename2 or e.filename or "the run directory")  # a rename's target, not its temporary file
    where = where if len(where) <= 200 else f"{where[:200]}..."
    if e.errno in _UNWRITABLE:
        return (f"cannot write {where}: {e.strerror or e} ({_UNWRITABLE[e.errno]}); nothing half-written was kept")
    if e.errno in _MISPLACED:
        fix = "move it aside" if e.errno in (errno.EISDIR, errno.ENOTDIR) else "check the path"
        return f"cannot use {where}: {e.strerror or e} ({_MISPLACED[e.errno]}): {fix} and run the command again"
    return None


def skipped(stage: art.Stage) -> None:
    console.print(f"[green]✓[/] {stage.group} {stage.name}: inputs and settings unchanged, nothing to do "
                  f"(use --force to rerun)")


def fmt(v, digits: int = 5) -> str:
    import numpy as np

    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(v)
    if isinstance(v, (float, np.floating)):
        return f"{v:.{digits}g}" if np.isfinite(v) else ""
    return str(v)


def pvalue(p: float) -> str:
    return "<0.0001" if p < 1e-4 else f"{p:.4f}"


def df_table(df: pd.DataFrame, title: str, formats: dict[str, Callable] | None = None,
             width: int | None = None) -> Table | Group:
    """``df`` as a table; one wider than the console (``width``) comes as several, each repeating
    the first column (the row's name) with as many of the others as fit, so nothing is cut to "…"."""
    formats = formats or {}
    cells = {c: [escape(formats.get(c, fmt)(v)) for v in df[c]] for c in df.columns}
    width = width or console.width
    full = _table(df, cells, list(df.columns), title)
    if len(df.columns) < 3 or _width(full) <= width:
        return full
    key, groups = df.columns[0], [[]]
    for c in df.columns[1:]:
        if groups[-1] and _width(_table(df, cells, [key, *groups[-1], c], title)) > width:
            groups.append([])
        groups[-1].append(c)
    return Group(*[_table(df, cells, [key, *g], f"{title} ({i} of {len(groups)})" if i == 1 else f"({i} of "
                          f"{len(groups)})") for i, g in enumerate(groups, 1)])


def _table(df: pd.DataFrame, cells: dict[str, list[str]], columns: list, title: str) -> Table:
    import pandas as pd

    t = Table(title=title, title_justify="left", header_style="bold")
    for c in columns:
        t.add_column(str(c), justify="right" if pd.api.types.is_numeric_dtype(df[c]) else "left")
    for i in range(len(df)):
        t.add_row(*[cells[c][i] for c in columns])
    return t


def _width(t: Table) -> int:
    """The table's width with no column squeezed."""
    return Console(width=10_000).measure(t).maximum



def posterior_table(table: pd.DataFrame) -> pd.DataFrame:
    """A posterior's summary as printed: per parameter its median and 90 % interval (3 digits, as its
    verdict says them), the interval's width over its range, whether identified or pressed against an
    edge of its range, the Bayes factor of its effect off ("< x" where it is a bound), and the chains'
    autocorrelation time (tau, in steps) and whether they are long enough for it."""
    import numpy as np
    import pandas as pd

    from ..posterior.evidence import bf_text, edges

    upper = table["bf_upper"] if "bf_upper" in table.columns else pd.Series(False, index=table.index)
    bf = [bf_text(b, u) if np.isfinite(b) else "" for b, u in zip(table["bf_off"], upper)]
    three = {c: [float(f"{v:.3g}") for v in table[c]] for c in ("median", "q05", "q95")}
    out = table[["parameter"]].assign(**three, rel_width=table["rel_width"].round(2), identified=table["identified"])
    edge = edges(table)
    if (edge != "").any():
        out = out.assign(at_edge=edge)
    return out.assign(bf_off=bf, tau=table["autocorr_time"].round(1), chain_ok=table["chain_ok"])


def other_revision(run: Path, at_revision: Optional[int]) -> bool:
    """With --at-revision N: True (and says so) when the run's model is at another revision."""
    if at_revision is None:
        return False
    from ..model import load_model

    rev = load_model(check_run_dir(run)).revision
    if rev != at_revision:
        console.print(f"[green]✓[/] the model is at revision {rev}, this step is for revision {at_revision}: "
                      "nothing to do")
    return rev != at_revision
