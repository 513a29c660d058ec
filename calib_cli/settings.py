"""Stage settings: built-in defaults < TOML file < command-line overrides.

The built-in defaults are the paper's setup (Tables 2 and 6, GA/PSO settings of
sections 3.5-3.6), so a bare ``calib`` call does what the paper did. A settings
file in ``stages/settings/`` overrides any part; ``--setting pb.alpha=0.1`` overrides one key.
Unknown keys are an error (a typo must not be silently ignored).
"""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path
from typing import Any, Iterable, Mapping

from .errors import CalibError
from .space import Factor, ParameterSpace

DEFAULTS: dict[str, Any] = {
    "response": "repose_angle",
    # measured repose angle, paper Table 1 mean
    "target": 32.07,
    # the full factor table: every calibratable contact parameter with its screening range
    "factors": {
        "static_friction": {"low": 0.05, "high": 0.5, "unit": "-", "symbol": "X1",
                            "label": "Coefficient of static friction"},
        "rolling_friction": {"low": 0.03, "high": 0.4, "unit": "-", "symbol": "X2",
                             "label": "Coefficient of rolling friction"},
        "surface_energy": {"low": 0.5, "high": 2.0, "unit": "J/m2", "symbol": "X3",
                           "label": "Surface energy"},
        "restitution": {"low": 0.1, "high": 0.4, "unit": "-", "symbol": "X4",
                        "label": "Coefficient of restitution"},
    },
    "pb": {
        "factors": ["static_friction", "rolling_friction", "surface_energy", "restitution"],
        "runs": 12,
        "alpha": 0.05,
    },
    "ascent": {
        # gradient: along the first-order model's gradient, signed toward the target;
        # diagonal: every significant factor from its low to its high level together (paper Table 5)
        "method": "gradient",
        "steps": 5,
        # target of the path's relative error; empty -> the global target
        "target": None,
        # factors not carried forward, in natural units; missing ones sit at their centre
        "fixed": {},
    },
    "bbd": {
        # empty -> the factors carried forward by the screening (pb), or all pb factors
        "factors": [],
        "center_points": 5,
        # explicit ranges {name = [low, high]}; empty -> the ascent bracket, else the factor table
        "ranges": {},
        "fixed": {},
        "alpha": 0.05,
    },
    "surrogate": {
        "models": ["rsm", "bp", "pso-bp"],
        "hidden": 8,
        "epochs": 100,  # paper 3.5.1
        "seed": 0,
    },
    "invert": {
        # paper 3.5.3: 50 generations, population 10, crossover 0.4, mutation 0.2
        "generations": 50,
        "population": 10,
        "crossover": 0.4,
        "mutation": 0.2,
        "seed": 0,
        # the near-optimal set: every point whose predicted error is within this many degrees
        "tolerance": 0.25,
        "samples": 20000,
        "restarts": 10,
        # with --validate: corrections of the surrogate by the validation heaps (0: the paper's
        # single validation, no correction)
        "refine": 0,
        # a round is accepted when the rms over the conditions of z (compare's statistic) is at most this
        "refine_z": 1.0,
    },
    # the heaps of this run directory: every command that simulates them (simulate-heap, invert
    # --validate, compare, diagnose) takes these unless its --preset / --shear-modulus says otherwise,
    # so that a run directory is simulated at one setup without repeating the options on each command
    "heap": {
        "preset": "default",
        # Pa; None (no key in a TOML file) -> the preset's reduced 5 MPa (docs/physics.md, 'Stiffness')
        "shear_modulus": None,
    },
}

_OPEN_TABLES = {"factors", "ascent.fixed", "bbd.fixed", "bbd.ranges"}


def _merge(base: dict, over: Mapping, path: str = "") -> dict:
    """Deep-merge ``over`` into ``base``; only open tables accept new keys."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        key = f"{path}.{k}" if path else k
        if path not in _OPEN_TABLES and k not in base:
            raise CalibError(f"unknown setting {key!r}")
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _merge(out[k], v, key)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _parse_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_overrides(items: Iterable[str]) -> dict:
    """``["pb.alpha=0.1", "target=33"]`` -> nested dict."""
    out: dict = {}
    for item in items or ():
        if "=" not in item:
            raise CalibError(f"setting {item!r} is not KEY=VALUE")
        key, text = item.split("=", 1)
        parts = key.strip().split(".")
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = _parse_value(text.strip())
    return out


def read_toml(path: Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CalibError(f"settings file not found: {path}")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CalibError(f"settings file {path} is not valid TOML: {e}") from None


def with_overrides(text: str, items: Iterable[str]) -> str:
    """Settings TOML ``text`` with ``KEY=VALUE`` overrides written in front of it as dotted keys
    (``heap.shear_modulus = 1.5e8``: before any table header TOML reads them as top-level keys),
    so that a file's comments and layout survive. A value that is not TOML is written as a string,
    as ``parse_overrides`` reads it. Checked as ``load_settings`` checks a file."""
    items = list(items)
    parse_overrides(items)  # every item KEY=VALUE, with parse_overrides' message where not
    lines = []
    for item in items:
        key, val = (t.strip() for t in item.split("=", 1))
        try:
            tomllib.loads(f"v = {val}")
        except tomllib.TOMLDecodeError:
            val = json.dumps(val)
        lines.append(f"{key} = {val}")
    out = "# set with calib init -s\n" + "\n".join(lines) + "\n\n" + text
    try:
        data = tomllib.loads(out)
    except tomllib.TOMLDecodeError as e:
        raise CalibError(f"cannot write -s {' '.join(items)} into the settings: {e} (a key the file sets "
                         "already? edit the file)") from None
    validate(_merge(DEFAULTS, data))
    return out


def load_settings(files: Iterable[Path] = (), overrides: Iterable[str] = ()) -> dict:
    """Resolve the settings: defaults, then each TOML file in order, then overrides."""
    s = copy.deepcopy(DEFAULTS)
    for f in files:
        if f is not None:
            s = _merge(s, read_toml(f))
    s = _merge(s, parse_overrides(overrides))
    validate(s)
    return s


def factor_space(settings: Mapping, names: Iterable[str] | None = None) -> ParameterSpace:
    table = settings["factors"]
    names = list(table) if names is None else list(names)
    facs = []
    for n in names:
        if n not in table:
            raise CalibError(f"factor {n!r} is not in the factor table; known: {', '.join(table)}")
        spec = dict(table[n])
        unknown = set(spec) - {"low", "high", "unit", "label", "symbol"}
        if unknown:
            raise CalibError(f"factor {n!r}: unknown keys {sorted(unknown)}")
        if "low" not in spec or "high" not in spec:
            raise CalibError(f"factor {n!r}: needs low and high")
        facs.append(Factor(name=n, **spec))
    return ParameterSpace(tuple(facs))


def validate(s: Mapping) -> None:
    for k, v in DEFAULTS.items():
        if isinstance(v, Mapping) and not isinstance(s[k], Mapping):
            raise CalibError(f"setting {k!r} must be a table, got {s[k]!r}")
    factor_space(s)  # every factor well-formed
    for stage in ("pb", "bbd"):
        for n in s[stage].get("factors", []):
            if n not in s["factors"]:
                raise CalibError(f"{stage}.factors names unknown factor {n!r}")
    if not 0 < float(s["pb"]["alpha"]) < 1 or not 0 < float(s["bbd"]["alpha"]) < 1:
        raise CalibError("alpha must lie in (0, 1)")
    if s["ascent"]["method"] not in ("gradient", "diagonal"):
        raise CalibError(f"ascent.method must be 'gradient' or 'diagonal', got {s['ascent']['method']!r}")
    if int(s["ascent"]["steps"]) < 3:
        raise CalibError("ascent.steps must be at least 3 (a bracket needs neighbours)")
    if int(s["bbd"]["center_points"]) < 1:
        raise CalibError("bbd.center_points must be at least 1")
    for m in s["surrogate"]["models"]:
        if m not in ("rsm", "bp", "pso-bp"):
            raise CalibError(f"surrogate.models: unknown model {m!r} (rsm, bp, pso-bp)")
    iv = s["invert"]
    if not (0 <= iv["crossover"] <= 1 and 0 <= iv["mutation"] <= 1):
        raise CalibError("invert.crossover and invert.mutation must lie in [0, 1]")
    if int(iv["generations"]) < 1 or int(iv["population"]) < 2 or float(iv["tolerance"]) <= 0:
        raise CalibError("invert needs generations >= 1, population >= 2 and a positive tolerance")
    if int(iv["refine"]) < 0 or not float(iv["refine_z"]) > 0:
        raise CalibError("invert.refine must be >= 0 and invert.refine_z > 0")
    h = s["heap"]
    if not isinstance(h["preset"], str):
        raise CalibError(f"heap.preset must be a preset's name, got {h['preset']!r}")
    g = h["shear_modulus"]
    if g is not None and (isinstance(g, bool) or not isinstance(g, (int, float))):
        raise CalibError(f"heap.shear_modulus must be a number in Pa, got {g!r}")
    for n, rng in s["bbd"]["ranges"].items():
        if n not in s["factors"] or len(rng) != 2:
            raise CalibError(f"bbd.ranges.{n} must be [low, high] for a known factor")
    for key in ("ascent", "bbd"):
        for n in s[key]["fixed"]:
            if n not in s["factors"]:
                raise CalibError(f"{key}.fixed names unknown factor {n!r}")
