"""`calib measure-angle`: the options of calib_cli.stages.measure, a progress bar and its tables."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.progress import Progress

from .common import ForceOpt, RunOpt, console, df_table, say, skipped
from .names import MAX_FLANK_DIFF_DEG, MAX_RESIDUAL


def measure_angle(
    run: RunOpt,
    images: Annotated[Optional[Path], typer.Option(help="Folder of heap photographs (PNG/JPEG/TIFF/BMP).")] = None,
    conditions: Annotated[Optional[Path], typer.Option(help="CSV: image, condition_id [, condition variables, floor "
                          "and its floor_* values, pile]. pile names the pile a photograph shows, where each was "
                          "photographed from several sides: a pile that stands as a column in one view is a column "
                          "in all. Without the file all images are one condition.")] = None,
    angles: Annotated[Optional[Path], typer.Option(help="Instead of images: a CSV of angles already measured "
                      "(image, repose_angle in (0, 90) deg [, condition_id]), e.g. the paper's Table 1; "
                      "--conditions joins on its image column.")] = None,
    band: Annotated[tuple[float, float], typer.Option(help="Height band of the flank fit (fractions of the heap's "
                    "height), low,high, e.g. --band 0.2,0.8 (or --band 0.2 0.8).", metavar="<float,float>")] = (0.15, 0.85),
    keep_flagged: Annotated[bool, typer.Option("--keep-flagged", help="Count heaps flagged cut, column, not_cone or "
                            "asymmetric in the condition statistics, where their flanks could be fitted.")] = False,
    max_flank_diff: Annotated[float, typer.Option(help="Flanks further apart than this (deg) flag the heap "
                              "asymmetric.")] = MAX_FLANK_DIFF_DEG,
    max_residual: Annotated[float, typer.Option(help="A flank whose line fit leaves a larger RMS residual, in heap "
                            "heights, flags the heap not_cone.")] = MAX_RESIDUAL,
    force: ForceOpt = False,
):
    """Repose angle per photograph and per condition (paper 2.1, Table 1).

    Reads --images (and --conditions), or --angles. Writes RUN/measure/angles.parquet,
    conditions.parquet (n, mean, median, sd, range, cv_percent, se, ci95), profiles.parquet and
    an annotated overlay PNG per image in RUN/measure/overlays/. Unreadable, blank or heap-less
    images get a status and a message; so do silhouettes that are no heap's cone: cut by the frame
    (cut), a standing column (column), a flank not straight (not_cone) or flanks too unlike
    (asymmetric). Those are left out of the per-condition statistics (unless --keep-flagged), and
    the output says how many and why. The exit code is non-zero only if no image is left to count.
    """
    from ..dem.heap import FLOOR_VARIABLES
    from ..stages.measure import floors_alike, measure_angle as measure

    bar: list = []

    def progress(i, n):  # a bar while images are measured (not for --angles, nor a stage up to date)
        if not bar:
            bar.append(Progress(console=console, transient=True))
            bar[0].start()
            bar.append(bar[0].add_task("measuring", total=n))
        bar[0].update(bar[1], completed=i)
        if i == n:
            bar[0].stop()

    try:
        res = measure(run, images, conditions, angles, band, force, say=say, progress=progress,
                      keep_flagged=keep_flagged, max_flank_diff=max_flank_diff, max_residual=max_residual)
    finally:
        if bar and not bar[0].finished:
            bar[0].stop()
    if res.skipped:
        return skipped(res.stage)
    console.print(df_table(res.angles[["image", "condition_id", "angle_left", "angle_right", "repose_angle", "status"]],
                           f"measure-angle -> {res.dir / 'angles.parquet'}"))
    for note in res.notes(markup=True):
        console.print(note)
    show_conditions(res)
    alike = floors_alike(res.conditions)
    if alike:
        console.print(f"[yellow]warning:[/] floors {', '.join(alike)} have no values that tell them apart "
                      f"({', '.join(FLOOR_VARIABLES)}): they will be simulated as one floor")


def show_conditions(res, out: Console = console) -> None:
    """measure-angle's per-condition statistics (paper Table 1) as the command prints them."""
    out.print(df_table(res.summary(), "Per condition (cf. paper Table 1)", width=out.width))
