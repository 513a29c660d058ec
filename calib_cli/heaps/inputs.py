"""Heap inputs: a command's parameters, conditions and heap setup (preset, shear modulus, engine, precision),
checked, and turned into :class:`~calib_cli.heaps.keys.Request` objects with the one seed scheme
every command uses.

A campaign is a list of *points* (a design run id and its parameter values; a single point has
id 0) crossed with *conditions* (a condition id and its :class:`HeapCondition`) and repeats. Each
heap's seed is ``derive_seed(base, index, repeat)`` with the index of :func:`seed_index`: the
point's id on one rig, ``id * 1000 + k + 1`` for the k-th condition of a table. The seed, with
the parameters, condition, numerics and model, makes the heap's cache key (``Request.hash``): a
change here re-simulates every committed run, and tests/test_requests.py checks that it does not.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Iterable, Mapping, Optional, Sequence, Union

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..dem.heap import CONDITION_VARIABLES, PARAMETERS, HeapCondition, Numerics, Preset, condition_dict, get_preset
from ..dem.materials import LAW_SWITCHES
from ..engines.clumps import SPHERES
from ..errors import CalibError
from ..parameters import CONDITION_VARIABLES as CONDITION_QUANTITIES
from ..parameters import PRECISION_NAMES, QUANTITIES, check, is_bool
from ..settings import _parse_value
from .keys import Request, derive_seed

#: the heap-test variables a conditions table (or a surrogate's inputs) may carry
COND_VARS = list(CONDITION_VARIABLES)

#: Pa: the accepted shear moduli (a soft gel to steel); outside, a typo rather than a material
SHEAR_MODULUS_RANGE = (1e5, 1e11)


# ------------------------------------------------------------------ heap setup
def heap_preset(name: str, shear_modulus: Optional[float] = None, precision: str = "double") -> Preset:
    """The named preset, with the grains' and walls' shear modulus replaced when one is given, in
    ``precision`` (``heap.precision``: what the heaps' state arrays store)."""
    pre = get_preset(name)
    if precision != pre.numerics.precision:
        if precision not in PRECISION_NAMES:
            raise CalibError(f"precision must be one of {', '.join(PRECISION_NAMES)}, got {precision!r}")
        pre = dataclasses.replace(pre, numerics=dataclasses.replace(pre.numerics, precision=precision))
    if shear_modulus is None:
        return pre
    lo, hi = SHEAR_MODULUS_RANGE
    if not (np.isfinite(shear_modulus) and lo <= shear_modulus <= hi):
        raise CalibError(f"shear modulus {shear_modulus:g} Pa (--shear-modulus or heap.shear_modulus) is outside "
                         f"[{lo:g}, {hi:g}] Pa")
    num = dataclasses.replace(pre.numerics, shear_modulus=float(shear_modulus), wall_shear_modulus=float(shear_modulus))
    return dataclasses.replace(pre, numerics=num)


#: the engines a run directory's heaps can be simulated on by every command (``[heap] engine``)
RUN_ENGINES = ("builtin", "gpu")


def heap_engine(cfg: dict, engine: Optional[str] = None) -> str:
    """The engine of a command's heaps: the option where given, else the run's ``[heap] engine``."""
    name = engine if engine is not None else cfg["heap"].get("engine", "builtin")
    if engine is None and name not in RUN_ENGINES:
        raise CalibError(f"the run's heap settings: engine must be one of {', '.join(RUN_ENGINES)}, got {name!r}")
    return name


def heap_precision(cfg: dict, engine: str = "builtin") -> str:
    """The run's ``[heap] precision`` for heaps on ``engine``; LAMMPS computes in its own double precision."""
    precision = cfg["heap"].get("precision", "double")
    if precision not in PRECISION_NAMES:
        raise CalibError(f"the run's heap settings: precision must be one of {', '.join(PRECISION_NAMES)}, "
                         f"got {precision!r}")
    if precision != "double" and engine == "lammps":
        raise CalibError(f"heap.precision = {precision!r} applies to the built-in and GPU engines; LAMMPS computes "
                         "in double precision: set heap.precision = \"double\" for its heaps")
    return precision


def run_heap_settings(cfg: dict, engine: Optional[str] = None) -> dict:
    """The heaps' engine (the option ``engine`` where given, else the run's) and the run's precision in a stage's
    settings where they are not the defaults (built-in, double), so the locks made before either was a setting
    stay valid."""
    engine = heap_engine(cfg, engine)
    precision = heap_precision(cfg, engine)
    return {**({} if engine == "builtin" else {"engine": engine}),
            **({} if precision == "double" else {"precision": precision})}


def precision_note(precision: str) -> str:
    """What a command says of its heaps' precision: nothing for double."""
    return "" if precision == "double" else f", {precision} precision"


def check_engine(engine: str, mpi: int = 1, shape: str = "sphere") -> tuple[str, ...]:
    """The grain shapes, after checking that the engine can run them (its extra installed, a GPU there)."""
    if engine not in ("builtin", "lammps", "gpu"):
        raise CalibError(f"unknown engine {engine!r}: builtin, lammps or gpu")
    if mpi > 1 and engine != "lammps":
        raise CalibError("--mpi applies to --engine lammps (the built-in kernel runs one heap per core)")
    from ..engines.clumps import parse_shapes

    shapes = parse_shapes(shape)
    if shapes != SPHERES and engine != "lammps":
        raise CalibError("--shape needs --engine lammps: the built-in kernel and the GPU engine have spheres only")
    if shapes != SPHERES and mpi > 1:
        raise CalibError("--shape runs on one LAMMPS rank (--mpi 1)")
    if engine == "lammps":
        from ..engines.lammps import open_lammps

        open_lammps().close()  # fail now, with the extra named, not after the first run
    if engine == "gpu":
        from ..dem.gpu import cuda_module

        cuda_module()  # fail now: no GPU, or no CUDA driver
    return shapes


def heap_setup(cfg: dict, preset: Optional[str], shear_modulus: Optional[float]) -> tuple[str, Optional[float]]:
    """The preset and shear modulus of a command's heaps: the option where given, else the run's
    settings (``[heap]`` preset and shear_modulus), else ``default`` at its own reduced modulus.

    A modulus equal to the preset's own comes back as None, so that naming it changes neither the
    heaps' cache keys nor the stages' hashes. The preset and the modulus are checked here, before
    any stage or heap starts.
    """
    name = preset if preset is not None else cfg["heap"]["preset"]
    g = shear_modulus if shear_modulus is not None else cfg["heap"]["shear_modulus"]
    try:
        g = None if g is None else float(g)
    except (TypeError, ValueError, OverflowError):  # a 400-digit integer is a number float() cannot hold
        raise CalibError(f"the shear modulus (--shear-modulus or heap.shear_modulus) must be a number in Pa, got "
                         f"{str(g)[:40]}") from None
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


def modulus_note(shear_modulus: Optional[float]) -> str:
    return "" if shear_modulus is None else f", shear modulus {shear_modulus / 1e6:g} MPa"


# ------------------------------------------------------------------ parameters and conditions
def parse_pairs(items: Optional[Iterable[str]], what: str) -> dict:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}`` (values read as TOML, else kept as text); a key
    given twice is an error (the last would silently win)."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise CalibError(f"{what} {item!r} is not KEY=VALUE")
        k, v = item.split("=", 1)
        if k.strip() in out:
            raise CalibError(f"{what} {k.strip()} is given twice ({out[k.strip()]!r} and {v.strip()!r}): give it once")
        out[k.strip()] = _parse_value(v.strip())
    return out


#: KEY=VALUE strings as typed, a mapping from Python, or nothing
Pairs = Union[Mapping, Iterable[str], None]


def given_pairs(items: Pairs, what: str) -> dict:
    """KEY=VALUE strings (the command line's; one string is one pair, not its characters) or a mapping
    (Python's) as a dict."""
    if isinstance(items, Mapping):
        return dict(items)
    return parse_pairs([items] if isinstance(items, str) else items, what)


def parse_params(values: Mapping, where: str = "--set") -> dict[str, float]:
    """Heap parameter values a user gave, checked: known names, numbers in the range the model accepts
    and a real material plausibly has (:func:`calib_cli.parameters.check`)."""
    out = {}
    for k, v in values.items():
        if k not in PARAMETERS:
            raise CalibError(f"unknown parameter {k!r}{_did_you_mean(k, PARAMETERS)}; known: {', '.join(PARAMETERS)}")
        if k in QUANTITIES:
            out[k] = check(k, v, where)
            continue
        if is_bool(v) and k not in LAW_SWITCHES:  # true is a law switched on, not a liquid's value
            raise CalibError(f"parameter {k} must be a number, got {v!r}")
        try:
            f = float(v)
        except (TypeError, ValueError, OverflowError):
            raise CalibError(f"parameter {k} must be a number, got {v!r}") from None
        if not np.isfinite(f):
            raise CalibError(f"parameter {k} must be finite, got {v!r}")
        out[k] = f
    return out


def _did_you_mean(name: str, known) -> str:
    import difflib

    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.75)
    return f" (did you mean {close[0]}?)" if close else ""


def checked_condition(items, where: str = "--condition") -> dict:
    """``--condition`` values (KEY=VALUE strings, or a mapping from Python), checked against the rig's
    plausible ranges (:mod:`calib_cli.parameters`); unknown names are :func:`make_condition`'s to refuse.
    ``where`` names their source in a message (synth-lab's --sizes, --floor)."""
    given = given_pairs(items, where)
    for k, v in given.items():
        if k in CONDITION_QUANTITIES and not (isinstance(v, float) and math.isnan(v)):
            check(k, v, where)
    return given


def make_condition(base: HeapCondition, overrides: Mapping) -> HeapCondition:
    """The base condition with some variables replaced (``floor`` is a name), validated."""
    fields = {f.name for f in dataclasses.fields(HeapCondition)}
    bad = set(overrides) - fields
    if bad:
        first = sorted(bad)[0]
        raise CalibError(f"unknown condition variable(s) {sorted(bad)}{_did_you_mean(first, fields)}; known: "
                         f"{', '.join(sorted(fields))}")
    try:
        c = dataclasses.replace(base, **{k: (str(v) if k == "floor" else float(v)) for k, v in overrides.items()})
    except (TypeError, ValueError, OverflowError):
        raise CalibError(f"condition values must be numbers: {dict(overrides)}") from None
    c.validate()
    return c


def condition_from_row(base: HeapCondition, row) -> HeapCondition:
    """The base condition with the variables a conditions-table row gives (missing or NaN: kept),
    and the floor's name, which the results rows then show beside its values."""
    return make_condition(base, {k: row[k] for k in (*CONDITION_VARIABLES, "floor")
                                 if k in row.index and pd.notna(row[k])})


def table_conditions(base: HeapCondition, table: pd.DataFrame) -> list[tuple[str, HeapCondition]]:
    """(condition_id, condition) of each distinct condition of a conditions table, in its order."""
    # not checked against the plausible ranges here: a table a user wrote was checked where it entered
    # (calib_cli.conditions), and a measured one then; a deliberate extreme (CALIB_ALLOW_EXTREME) stays allowed
    return [(str(row["condition_id"]), condition_from_row(base, row))
            for _, row in table.drop_duplicates("condition_id").iterrows()]


# ------------------------------------------------------------------ seeds and requests
def seed_index(point_id: int, condition_index: Optional[int]) -> int:
    """The run index a heap's seed derives from (with the base seed and the repeat): the point's id
    on one rig (``condition_index`` None), else ``point_id * 1000 + condition_index + 1`` for the
    (0-based) condition of a table, so that every condition draws its own heaps."""
    return int(point_id) if condition_index is None else int(point_id) * 1000 + int(condition_index) + 1


def build_requests(points: Sequence[tuple[int, Mapping[str, float]]],
                   conditions: Sequence[tuple[str, HeapCondition]], numerics: Numerics, *, seed: int,
                   repeats: int = 1, first_repeat: int = 0, from_table: bool = True, preset: str = "",
                   design: str = "", model: str = "", label_by_condition: bool = False,
                   engine: str = "builtin", mpi: int = 1, shapes: tuple[str, ...] = SPHERES) -> list[Request]:
    """Every point under every condition, ``repeats`` heaps each (repeat numbers from ``first_repeat``).

    ``from_table``: the conditions are rows of a conditions table, each with its own seeds
    (:func:`seed_index`); else the one rig of the point (the preset's, or a single condition
    standing for it), seeded by the point's id alone. ``label_by_condition``: the results rows of a
    single point take the condition's 1-based position as their run id (validation, compare,
    diagnose, a synthetic lab) instead of the point's id (a design).
    """
    return [Request(dict(p), c, numerics, derive_seed(seed, seed_index(rid, k if from_table else None), r), preset,
                    design, k + 1 if label_by_condition else int(rid), r, model, cid, engine, mpi, tuple(shapes))
            for rid, p in points for k, (cid, c) in enumerate(conditions)
            for r in range(first_repeat, first_repeat + repeats)]


def request_from_row(row) -> Request:
    """The request a built-in engine's results row was made from (parameters, condition, preset
    with the row's shear modulus, seed, model), to simulate it again; its hash is the row's
    run_hash unless the row lacks something that went into it."""
    params = {k: float(row[k]) for k in PARAMETERS if k in row.index and pd.notna(row[k])}
    g, precision = row.get("shear_modulus"), row.get("precision")
    pre = heap_preset(row["preset"], float(g) if g is not None and pd.notna(g) else None,
                      precision if isinstance(precision, str) else "double")
    return Request(params, condition_from_row(pre.condition, row), pre.numerics, int(row["seed"]),
                   model=row["model"])


def condition_seed(base: int, condition: HeapCondition, repeat: int) -> int:
    """A heap's seed from its condition's values and its repeat alone: the heaps of one condition at several
    parameter points draw alike (common random numbers, as a finite difference wants), whatever the
    condition's place in a table (a candidate named beside others is the same heap, and cached)."""
    h = art.hash_obj({"condition": condition_dict(condition), "repeat": int(repeat)})
    return derive_seed(base, int(h[:7], 16), repeat)


def measured_seed(base: int, condition_id: str, condition: HeapCondition, repeat: int) -> int:
    """A measured condition's heap seed (compare's, diagnose's): from its name and values and its repeat, not its
    row, so a condition's heaps stay the same, and cached, when the measured table gains, loses or reorders rows;
    two conditions of the same values under two names (a rig measured twice) draw heaps of their own."""
    h = art.hash_obj({"condition": condition_dict(condition), "condition_id": str(condition_id),
                      "repeat": int(repeat)})
    return derive_seed(base, int(h[:7], 16), repeat)


def content_seed(base: int, params: Mapping[str, float], condition: HeapCondition, repeat: int) -> int:
    """A heap's seed from what it simulates (its parameters, its condition's values and its repeat),
    not from a design row or a conditions table's order: the same heap in another round, run or
    model revision, or after a condition is added to a table, is the same heap (and cached)."""
    h = art.hash_obj({"params": {k: float(v) for k, v in sorted(params.items())},
                      "condition": condition_dict(condition), "repeat": int(repeat)})
    return derive_seed(base, int(h[:7], 16), repeat)
