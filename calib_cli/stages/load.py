"""A finished stage's results read back from a run directory, computing nothing: what a notebook opens
after a command line (or a pipeline) made the run. Calling the stage's function instead checks its
inputs and settings against the ones given, and computes again where they differ (a default left as it
is, a settings file edited since).

    from calib_cli.stages.load import load
    load("sample_runs/hidden-effect", "posterior").summary()    # the answer, as `calib calibrate` printed it
    load("sample_runs/hidden-effect", "calibrate", revision=0)  # an earlier model revision's rounds
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple, Optional

from .. import artifacts as art
from ..errors import CalibError
from .common import Result, checked


class _Kind(NamedTuple):
    group: str  # the run directory's folder
    name: str  # the stage's name within it (its lock)
    result: str  # "module:Class" of the result it reads back
    made: str  # the file that tells the stage finished
    command: str  # the command that writes it


KINDS: dict[str, _Kind] = {
    "measure": _Kind("measure", "angles", "measure:MeasureResult", "angles.parquet", "measure-angle"),
    "pb-design": _Kind("pb", "design", "doe:DesignResult", "design.parquet", "pb design"),
    "pb": _Kind("pb", "analyze", "doe:PBResult", "effects.parquet", "pb analyze"),
    "ascent-design": _Kind("ascent", "design", "doe:DesignResult", "design.parquet", "ascent design"),
    "ascent": _Kind("ascent", "analyze", "doe:AscentResult", "path.parquet", "ascent analyze"),
    "bbd-design": _Kind("bbd", "design", "doe:DesignResult", "design.parquet", "bbd design"),
    "bbd": _Kind("bbd", "analyze", "doe:BBDResult", "fit.parquet", "bbd analyze"),
    "surrogate": _Kind("surrogate", "fit", "surrogate:FitResult", "metrics.parquet", "fit-surrogate"),
    "invert": _Kind("invert", "solve", "invert:InvertResult", "solution.parquet", "invert"),
    "calibrate": _Kind("calibrate", "rounds", "calibrate:CalibrateResult", "rounds.parquet", "calibrate"),
    "posterior": _Kind("posterior", "sample", "posterior:PosteriorStageResult", "summary.parquet", "calibrate"),
    "compare": _Kind("compare", "residuals", "compare:CompareResult", "residuals.parquet", "compare"),
    "diagnose": _Kind("diagnose", "rank", "diagnose:DiagnoseResult", "ranking.parquet", "diagnose"),
    "suggest": _Kind("suggest", "rank", "suggest:SuggestResult", "ranking.parquet", "suggest-conditions"),
}


@checked
def load(run: Path, stage: str, revision: Optional[int] = None) -> Result:
    """The result ``stage`` (a key of :data:`KINDS`) wrote in ``run``, as its function returns it (its
    ``summary()``, ``warnings()`` and tables), read from the files alone; ``skipped`` is True, since nothing
    ran. ``revision``: for ``calibrate``, an earlier model revision's rounds and last posterior. Raises
    :class:`~calib_cli.errors.CalibError` where the run holds no such result, naming the command that
    makes it."""
    import importlib

    kind = KINDS.get(stage)
    if kind is None:
        raise CalibError(f"no stage {stage!r} to load: one of {', '.join(KINDS)}")
    run = Path(run)
    if not run.is_dir():
        raise CalibError(f"{run} is not a run directory")
    if not (run / kind.group / kind.made).is_file():
        raise CalibError(f"{run} holds no {stage} result ({kind.group}/{kind.made}): `calib {kind.command} "
                         f"--run {run}` makes it")
    module, cls = kind.result.split(":")
    result = getattr(importlib.import_module(f"{__package__}.{module}"), cls)(art.Stage(run, kind.group, kind.name),
                                                                              True)
    if revision is not None:
        if stage != "calibrate":
            raise CalibError(f"revision= picks a calibration's model revision; {stage} keeps the current one's")
        result = result.at_revision(int(revision))
    return result
