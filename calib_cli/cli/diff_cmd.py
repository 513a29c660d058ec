"""`calib diff-runs`: a run's headline numbers beside a reference run's (what `make calibrate` ends with)."""

from __future__ import annotations

from pathlib import Path

import typer
from typing_extensions import Annotated

from rich.markup import escape
from rich.table import Table

from .common import console


def diff_runs_cmd(
    run: Annotated[Path, typer.Argument(help="The run directory to check, e.g. a fresh calibration.")],
    reference: Annotated[Path, typer.Argument(help="The run directory it should agree with, e.g. "
                                              "sample_runs/calibration.")],
    rtol: Annotated[float, typer.Option(min=0.0, help="Relative tolerance of 'same'.")] = 1e-6,
    strict: Annotated[bool, typer.Option(help="Exit 1 when any number differs.")] = False,
):
    """Print a run's headline numbers (measured target, screening, bracket, fits, calibrated parameters,
    validation, comparison) beside a reference run's, and why they differ where they do."""
    from ..stages.rundiff import diff_runs

    d = diff_runs(run, reference, rtol)
    t = Table(title=f"{run} against {reference}", title_justify="left", header_style="bold",
              width=min(console.width, 100))
    t.add_column("quantity", ratio=5)
    t.add_column("this run", ratio=3)
    t.add_column("reference", ratio=3)
    t.add_column("same", no_wrap=True)
    for r in d.table.itertuples(index=False):
        t.add_row(*(escape(str(v)) for v in r), style=None if r.same == "yes" else "yellow")
    console.print(t)
    n = len(d.table)
    verdict = "[green]every number as in the reference[/]" if d.same else \
        f"[yellow]{int((d.table['same'] != 'yes').sum())} of {n} numbers differ[/]"
    console.print(f"{verdict}")
    for r in d.reasons:
        console.print(f"  - {r}")
    if strict and not d.same:
        raise typer.Exit(1)
