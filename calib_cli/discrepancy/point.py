"""The calibrated point of a run's model and heaps simulated at it, condition by condition: what compare
checks against the measurements (paper 3.6, validation, per condition) and diagnose and suggest-conditions
perturb."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Optional

import pandas as pd

from .. import artifacts as art
from ..heaps.runner import run_campaign
from ..dem.heap import LAWS
from ..errors import CalibError
from ..model import EFFECTS, Model, load_model
from ..heaps.inputs import (Pairs, build_requests, condition_seed, content_seed, given_pairs, heap_engine, heap_precision,
                            heap_preset, measured_seed, parse_params, table_conditions)
from ..stages.common import bbd_fixed, resolve_settings
from .stats import per_condition


#: calibrate's point: the posterior's most probable draw (calib_cli.stages.calibrate)
POINT = Path("calibrate") / "point.parquet"


def calibrated_point(run: Path, model: Model) -> Optional[Path]:
    """The table of the calibrated parameters: calibrate's most probable draw where it was made for the
    current model revision, else the inversion's solution (the paper's chain), else None."""
    point = run / POINT
    if point.is_file() and art.read_provenance(point).get("model_revision") == model.revision:
        return point
    sol = run / "invert" / "solution.parquet"
    return sol if sol.is_file() else None


def model_and_theta(run: Path, set_: Pairs = None) -> tuple[Model, dict[str, float]]:
    """The model and its calibrated parameter values: the BBD's fixed values < the calibrated point
    (:func:`calibrated_point`) < --set. Without a model file (revision 0) simulate-heap pins nothing, so an effect
    the calibration switched on (a non-neutral value, e.g. surface_energy 0.5) joins the model."""
    model = load_model(run)
    given = parse_params(given_pairs(set_, "--set")) if set_ else {}
    known = {e.parameter for e in EFFECTS.values()}
    base = {}
    sol = calibrated_point(run, model)
    if sol is not None:
        s = art.read_table(sol).iloc[0]
        base = {k: float(s[k]) for k in s.index if k in known}
    # parameters the response surface held fixed keep their fixed values (the surrogate and
    # the inversion know nothing else about them)
    fixed = {k: v for k, v in bbd_fixed(run, resolve_settings(run, None, None)).items() if k in known or k in LAWS}
    theta = {**fixed, **base, **given}
    _check_given(model, given)
    if model.revision == 0:
        used = [e.name for e in EFFECTS.values() if e.name not in model.effects and e.parameter in theta
                and not (e.neutral == e.neutral and theta[e.parameter] == e.neutral)]
        if used:
            model = Model((*model.effects, *used), 0, f"default model + {', '.join(used)} (set by the calibration)")
    missing = [p for p in model.parameters if p not in theta]
    if missing:
        raise CalibError(f"no calibrated value for {', '.join(missing)}: run `calib calibrate` (or `calib invert`) or "
                         "pass --set NAME=VALUE")
    # with the contact laws the BBD's heaps had (or --set gives): its surrogate learnt those
    return model, {**{p: theta[p] for p in model.parameters}, **{k: theta[k] for k in LAWS if theta.get(k)}}


def fitted_parameters(run: Path, model: Model, set_: Pairs = None) -> list[str]:
    """The model's parameters the calibration fitted to the measured means: those its calibrated point
    (:func:`calibrated_point`) gives and --set does not override. One the response surface held fixed (the BBD's
    ``fixed``), or set by hand, took no degree of freedom from them (compare's chi2/dof, docs/method.md); nor did
    an effect's parameter at its neutral value in the posterior's point, a draw of the model without the effect
    (an answer averaged on and off takes its point from the likelier model, :func:`most_probable`)."""
    given = parse_params(given_pairs(set_, "--set")) if set_ else {}
    sol = calibrated_point(run, model)
    point = art.read_table(sol).iloc[0] if sol is not None else pd.Series(dtype=float)
    neutral = {e.parameter: e.neutral for e in EFFECTS.values()} if sol == run / POINT else {}
    return [p for p in model.parameters if p in point.index and p not in given
            and not (p in neutral and float(point[p]) == neutral[p])]


def _check_given(model: Model, given: dict[str, float]) -> None:
    """Refuse a --set value for a parameter the model file's revision does not calibrate: it would be
    dropped (model.pin) and the comparison run without it. Its neutral value is what the model uses
    anyway; without a model file (revision 0) the effect joins the model instead."""
    if model.revision == 0:
        return
    owner = {e.parameter: e for e in EFFECTS.values()}
    dropped = sorted(k for k, v in given.items()
                     if k not in LAWS and k not in model.parameters and not (k in owner and v == owner[k].neutral))
    if dropped:
        adds = sorted({owner[k].name for k in dropped if k in owner})
        hint = f"; `calib model add {' / '.join(adds)}` to calibrate it" if adds else ""
        raise CalibError(f"the model (revision {model.revision}) has no parameter {', '.join(dropped)}: its "
                         f"parameters are {', '.join(model.parameters)}{hint}")


def simulate_at(run, model, theta, conds, preset, repeats, workers, tag, seed=0, shear_modulus=None, seeds="table"):
    """Mean, sd, n of the simulated angle per condition at parameters theta, on the run's engine."""
    rows = simulate_points(run, model, [(0, theta)], conds, preset, repeats, workers, tag, seed, shear_modulus,
                           by_condition=True, seeds=seeds)
    return per_condition(rows, conds["condition_id"]), rows


#: how :func:`simulate_points` seeds a heap: by its condition's row in ``conds`` (the measured table's order), by
#: the condition's values (:func:`condition_seed`: a finite difference's common draws, any order; a candidate
#: condition's), by a measured condition's name and values (:func:`measured_seed`), or by everything it
#: simulates (:func:`content_seed`: a design's points draw apart)
SEEDINGS = {"table": None, "condition": lambda base, q: condition_seed(base, q.condition, q.repeat),
            "measured": lambda base, q: measured_seed(base, q.condition_id, q.condition, q.repeat),
            "content": lambda base, q: content_seed(base, q.params, q.condition, q.repeat)}

#: compare's and diagnose's choice (--seeds), and the seeding (:data:`SEEDINGS`) it names: by the condition
#: (the default: its heaps stay the same, and cached, when the measured table gains, loses or reorders rows), or
#: by its row, as runs made before the choice existed were seeded (their pipelines keep it, so their heaps stay
#: theirs)
MEASURED_SEEDINGS = {"condition": "measured", "table": "table"}


def check_seeding(seeds: str) -> str:
    """``seeds`` if it is one of :data:`MEASURED_SEEDINGS`, else a one-line error."""
    if seeds not in MEASURED_SEEDINGS:
        raise CalibError(f"--seeds must be one of {', '.join(MEASURED_SEEDINGS)}, got {seeds!r}")
    return seeds


def run_seeding(run: Path) -> str:
    """The seeding a run's comparison used, for its next compare and diagnose to follow (diagnose's base point is
    then compare's own heaps): its residuals' provenance says, and where silent, by row (every comparison made
    before the choice); a run without a comparison yet, by the condition's values."""
    res = run / "compare" / "residuals.parquet"
    if not res.is_file():
        return "condition"
    try:
        seeds = art.read_provenance(res).get("seeds", "table")
    except CalibError as e:  # compare itself would overwrite the file: the way out must not run through it
        raise CalibError(f"{e}; it says how this run's compare heaps were seeded: give --seeds condition or "
                         "--seeds table") from None
    if seeds not in MEASURED_SEEDINGS:
        raise CalibError(f"{res} says its heaps were seeded {seeds!r}, which is none of "
                         f"{', '.join(MEASURED_SEEDINGS)}: give --seeds condition or --seeds table")
    return seeds


def seeding_settings(seeds: str) -> dict[str, str]:
    """The seeding as a stage lock's setting (and a table's provenance): left out for the row seeding, so the
    locks written before the choice existed, which all seeded so, stay up to date."""
    return {} if seeds == "table" else {"seeds": seeds}


def simulate_points(run, model, points, conds, preset, repeats, workers, tag, seed=0, shear_modulus=None,
                    by_condition=False, seeds="table"):
    """The results rows of every point (run id, parameters) under every condition of ``conds``, ``repeats``
    heaps each, on the run's engine, seeded as ``seeds`` says (:data:`SEEDINGS`); numbered by point (a
    design's), or ``by_condition`` (one point's, as compare's)."""
    cfg = resolve_settings(run, None, None)
    engine = heap_engine(cfg)
    pre = heap_preset(preset, shear_modulus, heap_precision(cfg, engine))
    reqs = build_requests([(rid, model.pin(theta)) for rid, theta in points], table_conditions(pre.condition, conds),
                          pre.numerics, seed=seed, repeats=repeats, preset=preset, design=tag, model=model.hash,
                          label_by_condition=by_condition, engine=engine)
    if SEEDINGS[seeds] is not None:
        reqs = [replace(q, seed=SEEDINGS[seeds](seed, q)) for q in reqs]
    return run_campaign(reqs, run, workers, rows_suffice=True)
