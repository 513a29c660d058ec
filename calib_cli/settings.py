"""Stage settings: built-in defaults < TOML file < command-line overrides.

The built-in defaults are the paper's setup (Tables 2 and 6, GA/PSO settings of
sections 3.5-3.6), so a bare ``calib`` call does what the paper did. A settings
file in ``stages/settings/`` overrides any part; ``--setting pb.alpha=0.1`` overrides one key.
Unknown keys are an error (a typo must not be silently ignored).
"""

from __future__ import annotations

import copy
import fnmatch
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

from .doe.sizes import check_runs
from .errors import CalibError
from .parameters import ENGINE_NAMES, PRECISION_NAMES, PRESET_NAMES, QUANTITIES, check
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
        # builtin (the CPU kernel) or gpu (every heap of a command together on an NVIDIA GPU)
        "engine": "builtin",
        # double, or mixed: velocities, spins, forces and contact histories in float32, positions in
        # float64 (docs/artefacts.md, the [heap] table); the built-in and GPU engines
        "precision": "double",
    },
}

_OPEN_TABLES = {"factors", "ascent.fixed", "bbd.fixed", "bbd.ranges"}


@dataclass(frozen=True)
class Rule:
    """What one setting's value must be: its kind, and a range where one is obvious."""

    kind: str  # number | integer | text | texts (a list of text) | pair (a list of two numbers)
    low: float | None = None
    high: float | None = None
    open: bool = False  # the bounds themselves excluded
    empty: bool = False  # may be left unset (no TOML value; None)

    def accepts(self, v: Any) -> bool:
        if v is None:
            return self.empty
        if self.kind == "text":
            return isinstance(v, str)
        if self.kind == "texts":
            return isinstance(v, list) and all(isinstance(x, str) for x in v)
        if self.kind == "pair":
            return isinstance(v, list) and len(v) == 2 and all(_is_number(x) for x in v)
        if not (_is_number(v) if self.kind == "number" else isinstance(v, int) and not isinstance(v, bool)):
            return False
        lo_ok = self.low is None or (v > self.low if self.open else v >= self.low)
        return lo_ok and (self.high is None or (v < self.high if self.open else v <= self.high))

    def describe(self) -> str:
        what = {"number": "a number", "integer": "an integer", "text": "a text (in quotes)",
                "texts": "a list of texts, e.g. ['a', 'b']", "pair": "a list [low, high] of two numbers"}[self.kind]
        if self.kind == "integer" and self.low == 1 and self.high is None:
            what = "a positive integer"
        elif self.low is not None and self.high is not None:
            what += f" in {'(' if self.open else '['}{self.low:g}, {self.high:g}{')' if self.open else ']'}"
        elif self.low is not None:
            what += f" {'>' if self.open else '>='} {self.low:g}"
        return what + (" (or left unset)" if self.empty else "")


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


_PROBABILITY, _POSITIVE = Rule("number", 0, 1, open=True), Rule("integer", 1)
#: the rules a setting's default does not imply (its type is derived from DEFAULTS, :func:`rule`): ranges,
#: settings whose default is None, and the open tables' entries (``*`` stands for any name)
RULES: dict[str, Rule] = {
    "pb.alpha": _PROBABILITY, "bbd.alpha": _PROBABILITY, "pb.runs": _POSITIVE, "ascent.steps": Rule("integer", 3),
    "ascent.target": Rule("number", empty=True), "bbd.center_points": _POSITIVE,
    "surrogate.hidden": _POSITIVE, "surrogate.epochs": _POSITIVE, "surrogate.seed": Rule("integer", 0),
    # the GA's sizes bounded where one would fill the memory (samples x factors x 8 bytes) or run for days
    "invert.generations": Rule("integer", 1, 100_000), "invert.population": Rule("integer", 2, 100_000),
    "invert.seed": Rule("integer", 0),
    "invert.crossover": Rule("number", 0, 1), "invert.mutation": Rule("number", 0, 1),
    "invert.tolerance": Rule("number", 0, 90, open=True), "invert.samples": Rule("integer", 1, 10_000_000),
    "invert.restarts": Rule("integer", 1, 1_000),
    "invert.refine": Rule("integer", 0), "invert.refine_z": Rule("number", 0, open=True),
    "heap.shear_modulus": Rule("number", empty=True), "heap.engine": Rule("text"),
    "heap.precision": Rule("text"),
    "factors.*.low": Rule("number"), "factors.*.high": Rule("number"), "factors.*.unit": Rule("text"),
    "factors.*.label": Rule("text"), "factors.*.symbol": Rule("text"),
    "ascent.fixed.*": Rule("number"), "bbd.fixed.*": Rule("number"), "bbd.ranges.*": Rule("pair"),
}
_KINDS = {bool: None, int: "integer", float: "number", str: "text", list: "texts"}


def rule(key: str) -> Rule | None:
    """The rule of a dotted setting key: :data:`RULES`, else its default's type; None for a table."""
    for pattern, r in RULES.items():
        if fnmatch.fnmatchcase(key, pattern) and pattern.count(".") == key.count("."):
            return r
    node: Any = DEFAULTS
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    kind = _KINDS.get(type(node))
    return Rule(kind) if kind else None


def check_types(over: Mapping, where: str = "", path: str = "") -> None:
    """Every value of a settings source (a TOML file's table, -s overrides) of the kind its setting
    takes, in one sentence naming the key, the value and the rule; ``where`` names the source."""
    for k, v in over.items():
        key = f"{path}.{k}" if path else str(k)
        r = rule(key)
        if isinstance(v, Mapping):
            if r is not None:  # a table where one value belongs (-s 'invert.population={a=1}')
                raise CalibError(f"setting {key} = {dict(v)!r}{where} must be {r.describe()}, not a table")
            check_types(v, where, key)
            continue
        if r is not None and not r.accepts(v):
            raise CalibError(f"setting {key} = {v!r}{where} must be {r.describe()}")
        _check_declared(key, v, where)


#: settings that hold a declared quantity (calib_cli.parameters): checked against its ranges
_DECLARED = {"heap.shear_modulus": "shear_modulus", "target": "repose_angle", "ascent.target": "repose_angle"}


def _check_declared(key: str, v: Any, where: str) -> None:
    """A setting's value against its quantity's declaration (a shear modulus of 150 Pa, an angle of inf),
    a factor's range against its parameter's; the preset's name among the presets."""
    parts = key.split(".")
    name = _DECLARED.get(key) or (parts[1] if len(parts) == 3 and parts[0] == "factors" and parts[2] in ("low", "high")
                                 else None)
    if len(parts) == 3 and parts[0] in ("ascent", "bbd") and parts[1] in ("fixed", "ranges"):
        name = parts[2]  # a value held fixed, or a design's range: within the parameter's own bounds too
    for x in (v if isinstance(v, list) else [v]):
        if name in QUANTITIES and _is_number(x):
            check(name, x, f"setting {key}{where}")
        elif name and _is_number(x):
            _check_law_value(name, x, f"setting {key}{where}")
    if isinstance(v, list) and len(v) == 2 and parts[1:2] == ["ranges"] and all(map(_is_number, v)) and v[0] >= v[1]:
        raise CalibError(f"setting {key} = {v!r}{where} must be [low, high] with low < high")
    if key == "heap.engine" and v not in ENGINE_NAMES:
        raise CalibError(f"setting heap.engine = {v!r}{where} must be one of {', '.join(ENGINE_NAMES)}")
    if key == "heap.precision" and v not in PRECISION_NAMES:
        raise CalibError(f"setting heap.precision = {v!r}{where} must be one of {', '.join(PRECISION_NAMES)}")
    if key == "heap.preset" and v not in PRESET_NAMES:
        close = [p for p in PRESET_NAMES if p.casefold() == str(v).casefold()]
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise CalibError(f"setting heap.preset = {v!r}{where} is an unknown preset{hint}; choose one of "
                         f"{', '.join(PRESET_NAMES)}")


def _check_law_value(name: str, v: Any, where: str) -> None:
    """A factor of a contact law's own value (a capillary bridge's surface tension) against its declaration.
    The laws import numba, so they are read only when a factor names such a value."""
    from .dem.laws import law_params

    why = next((p.check(float(v)) for p in law_params() if p.name == name), None)
    if why:
        raise CalibError(f"{where}: {why} (got {float(v):g})")


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


def parse_overrides(items) -> dict:
    """``["pb.alpha=0.1", "target=33"]`` (one such string alone too), or from Python ``{"pb.alpha": 0.1}``
    -> nested dict."""
    out: dict = {}
    if isinstance(items, Mapping):
        for key, value in items.items():
            _put(out, str(key), value)
        return out
    for item in [items] if isinstance(items, str) else items or ():
        if "=" not in item:
            raise CalibError(f"setting {item!r} is not KEY=VALUE")
        key, text = item.split("=", 1)
        if "\n" in text or "\r" in text:  # "30\nheap.preset='smoke'": settings.toml would get a line nobody gave
            raise CalibError(f"setting {key.strip()!r}: its value holds a line break; give one value, each setting "
                             "as its own -s KEY=VALUE")
        _put(out, key, _parse_value(text.strip()))
    return out


def _put(out: dict, key: str, value) -> None:
    """``value`` at the dotted ``key`` of the nested ``out``; a key given twice is an error."""
    parts = key.strip().split(".")
    node = out
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise CalibError(f"setting {key.strip()}: {p} is a value, not a table")
    if parts[-1] in node:
        raise CalibError(f"setting {key.strip()} is given twice: give it once")
    node[parts[-1]] = value


def read_toml(path: Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CalibError(f"settings file not found: {path}")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CalibError(f"settings file {path} is not valid TOML: {e}") from None


def override_items(items) -> list[str]:
    """``KEY=VALUE`` strings from what a caller gave: strings as typed, one string, or a mapping (its values
    written as TOML: JSON's numbers, strings and booleans are TOML's)."""
    if isinstance(items, Mapping):
        return [f"{k}={json.dumps(v)}" for k, v in items.items()]
    return [items] if isinstance(items, str) else list(items or ())


def with_overrides(text: str, items) -> str:
    """Settings TOML ``text`` with ``KEY=VALUE`` overrides. Where TOML allows, they are written in front of
    it as dotted keys (``heap.shear_modulus = 1.5e8``: before any table header TOML reads them as
    top-level keys), so that a file's comments and layout survive. Where it does not (a key the file sets,
    or one under a table the file declares: ``-s pb.alpha=0.1`` beside ``[pb]``) the file is read, the
    overrides set in it, and the result written out whole, the file as given kept below as comments.
    A value that is not TOML is written as a string, as ``parse_overrides`` reads it. Checked as
    ``load_settings`` checks a file. From Python ``items`` may be a mapping ({"heap.shear_modulus": 1.5e8})
    or one string."""
    import tomli_w

    items = override_items(items)
    over = parse_overrides(items)  # every item KEY=VALUE, with parse_overrides' message where not
    lines = []
    for item in items:
        key, val = (t.strip() for t in item.split("=", 1))
        try:
            tomllib.loads(f"v = {val}")
        except tomllib.TOMLDecodeError:
            val = json.dumps(val)
        lines.append(f"{key} = {val}")
    head = "# set with calib init -s\n" + "\n".join(lines) + "\n\n"
    try:
        out = head + text
        data = tomllib.loads(out)
    except tomllib.TOMLDecodeError:
        try:
            data = _set_in(tomllib.loads(text), over)
        except tomllib.TOMLDecodeError as e:
            raise CalibError(f"the settings file is not valid TOML: {e}") from None
        kept = "".join(f"# {line}\n" if line.strip() else "#\n" for line in text.splitlines())
        out = (f"# the settings file below with calib init -s {' '.join(items)} set in it\n"
               + tomli_w.dumps(data) + "\n# the settings file as given:\n" + kept)
    check_types(data)
    validate(_merge(DEFAULTS, data))
    return out


def _set_in(data: dict, over: Mapping) -> dict:
    """``data`` with every value of the nested ``over`` set in it (tables merged, values replaced)."""
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(data.get(k), dict):
            _set_in(data[k], v)
        else:
            data[k] = copy.deepcopy(v)
    return data


def load_settings(files: Iterable[Path] = (), overrides: Iterable[str] = ()) -> dict:
    """Resolve the settings: defaults, then each TOML file in order, then overrides."""
    s = copy.deepcopy(DEFAULTS)
    for f in files:
        if f is not None:
            data = read_toml(f)
            s = _merge(s, data)
            check_types(data, f" in {f}")
    over = parse_overrides(overrides)
    s = _merge(s, over)
    check_types(over)
    validate(s)
    return s


def factor_space(settings: Mapping, names: Iterable[str] | None = None) -> ParameterSpace:
    table = settings["factors"]
    names = list(table) if names is None else list(names)
    facs = []
    for n in names:
        if n not in table:
            raise CalibError(f"factor {n!r} is not in the factor table; known: {', '.join(table)}")
        if not isinstance(table[n], Mapping):
            raise CalibError(f"setting factors.{n} = {table[n]!r} must be a table {{low = ..., high = ...}}")
        spec = dict(table[n])
        unknown = set(spec) - {"low", "high", "unit", "label", "symbol"}
        if unknown:
            raise CalibError(f"factor {n!r}: unknown keys {sorted(unknown)}")
        if "low" not in spec or "high" not in spec:
            raise CalibError(f"factor {n!r}: needs low and high")
        facs.append(Factor(name=n, **spec))
    return ParameterSpace(tuple(facs))


def _check_factor_names(table: Mapping) -> None:
    """Refuse a factor named like a parameter but misspelt (``static_fricton``: at most two letters off): its
    range would be taken for a factor of its own while the parameter kept the default range. A name like no
    parameter (a paper's factor of its own, ``restitution_pw``) stands."""
    from .parameters import PARAMETERS

    for n in table:
        # two letters off, not a parameter's name with a suffix of its own (restitution_pw)
        close = [] if n in PARAMETERS else [p for p in PARAMETERS if _edits(n, p) <= 2 and not n.startswith(p)
                                            and not p.startswith(n)]
        if close:
            raise CalibError(f"setting factors.{n} names no parameter: did you mean factors.{close[0]}? (as it is, "
                             f"{close[0]} keeps its default range)")


def _edits(a: str, b: str) -> int:
    """The Levenshtein distance: letters inserted, deleted or changed to make ``a`` into ``b``."""
    row = list(range(len(b) + 1))
    for i, x in enumerate(a, 1):
        prev, row[0] = row[0], i
        for j, y in enumerate(b, 1):
            prev, row[j] = row[j], min(row[j] + 1, row[j - 1] + 1, prev + (x != y))
    return row[-1]


def validate(s: Mapping) -> None:
    """Resolved settings, checked as a whole: each value's kind (as :func:`check_types`, which
    load_settings calls per source first, to name a file) and how settings relate."""
    check_types(s)
    for k, v in DEFAULTS.items():
        if isinstance(v, Mapping) and not isinstance(s[k], Mapping):
            raise CalibError(f"setting {k!r} must be a table, got {s[k]!r}")
    factor_space(s)  # every factor well-formed
    _check_factor_names(s["factors"])
    for stage in ("pb", "bbd"):
        for n in s[stage].get("factors", []):
            if n not in s["factors"]:
                raise CalibError(f"{stage}.factors names unknown factor {n!r}")
    # kinds and ranges: check_types, per source; what is left relates settings to each other
    if s["ascent"]["method"] not in ("gradient", "diagonal"):
        raise CalibError(f"ascent.method must be 'gradient' or 'diagonal', got {s['ascent']['method']!r}")
    models = s["surrogate"]["models"]
    for m in models:
        if m not in ("rsm", "bp", "pso-bp"):
            raise CalibError(f"surrogate.models: unknown model {m!r} (rsm, bp, pso-bp)")
    if not models or len(set(models)) < len(models):
        raise CalibError(f"surrogate.models = {models!r} must name each model to fit once, at least one "
                         "(rsm, bp, pso-bp)")
    for n, rng in s["bbd"]["ranges"].items():
        if n not in s["factors"]:
            raise CalibError(f"bbd.ranges.{n} must be [low, high] for a known factor")
    check_runs(s["pb"]["runs"], len(s["pb"]["factors"]), "setting pb.runs")
    for key in ("ascent", "bbd"):
        for n in s[key]["fixed"]:
            if n not in s["factors"]:
                raise CalibError(f"{key}.fixed names unknown factor {n!r}")
