"""The model: a named set of physical effects, revisioned (SPEC section 6).

Each effect declares its parameters with bounds and a neutral value at which the effect
is off. A parameter of an effect that is not in the model is pinned at its neutral value in
every simulation. ``RUN/model.toml`` holds the current revision; every change writes a new
revision and keeps the old ones in ``RUN/model/rev-NNNN.toml``. The model's hash is part of
every simulation's cache key, so a model change never reuses runs of another model.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import tomli_w

from . import artifacts as art
from .dem.heap import LAWS
from .dem.laws import law_effects
from .effects import Effect
from .errors import CalibError


EFFECTS: dict[str, Effect] = {e.name: e for e in [
    Effect("sliding_friction", "static_friction", 0.05, 1.0, 0.3, 0.15, "Coulomb sliding friction between grains",
           "steeper heaps everywhere, little dependence on grain size or heap size"),
    Effect("rolling_friction", "rolling_friction", 0.0, 0.5, 0.0, 0.1,
           "constant-directional-torque rolling resistance (grain shape)",
           "steeper heaps everywhere; stronger for grains that roll freely"),
    Effect("cohesion", "surface_energy", 0.0, 3.0, 0.0, 0.5, "JKR cohesion (moisture, fines)",
           "the residual grows as particle size falls and as the heap gets smaller: cohesion scales as 1/d",
           unit="J/m2"),
    Effect("restitution", "restitution", 0.05, 1.0, 0.5, 0.2, "normal restitution (energy lost in impacts)",
           "matters for fast, dynamic heap formation (a fast lift); small in slow tests"),
    Effect("wall_friction", "wall_static_friction", 0.0, 1.0, float("nan"), 0.2,
           "floor and cylinder friction distinct from the grains' own",
           "the residual changes with the cylinder diameter (wall area per grain), the floor material and the "
           "heap size (on a slippery floor a bigger heap spreads further)"),
    Effect("wall_rolling", "wall_rolling_friction", 0.0, 0.5, float("nan"), 0.1,
           "rolling resistance on the floor distinct from the grains'",
           "the toe of the heap: the residual changes with the floor material and heap size"),
    *law_effects(),  # the effects contact laws bring (calib_cli.dem.laws), after the built-in ones
]}
#: wall_* effects are neutral when they equal the particles' own value (NaN marks "tied")

DEFAULT_EFFECTS = ["sliding_friction", "rolling_friction", "restitution"]
#: the highest model revision a run can hold (`--at-revision`'s range too)
MAX_REVISION = 1_000_000
MODEL_FILE = "model.toml"


@dataclass(frozen=True)
class Model:
    effects: tuple[str, ...]
    revision: int = 1
    note: str = ""

    def __post_init__(self):
        bad = [e for e in self.effects if e not in EFFECTS]
        if bad:
            raise CalibError(f"unknown effect(s) {bad}; known: {', '.join(EFFECTS)}")

    @property
    def parameters(self) -> list[str]:
        return [EFFECTS[e].parameter for e in self.effects]

    @property
    def candidates(self) -> list[str]:
        return [e for e in EFFECTS if e not in self.effects]

    @property
    def hash(self) -> str:
        return art.hash_obj(sorted(self.effects))

    def pin(self, params: dict[str, float]) -> dict[str, float]:
        """Parameters of a simulation: given values for the model's effects, neutral for the rest;
        contact-law switches (``rolling_spring``, ...: which law, not an effect's value) as given."""
        out = {k: float(params[k]) for k in LAWS if k in params}
        for name, eff in EFFECTS.items():
            if name in self.effects:
                if eff.parameter in params:
                    out[eff.parameter] = float(params[eff.parameter])
            elif eff.neutral == eff.neutral and eff.pinned_when_absent:  # not NaN: a value of its own
                out[eff.parameter] = eff.neutral
        return out

    def check(self, params: dict[str, float]) -> None:
        """Refuse a value for a parameter the model does not own: one of an absent effect away from
        its neutral value, or one no effect owns. An absent effect's parameter at its neutral value
        says "off", as the model does (a settings file may fix surface_energy = 0 in every revision)."""
        owner = {e.parameter: e.name for e in EFFECTS.values()}
        params = {k: v for k, v in params.items() if k not in LAWS}  # a law is chosen, not calibrated
        loose = sorted(set(params) - set(owner))
        if loose:  # pin() would drop them silently
            raise CalibError(f"{', '.join(loose)} belong(s) to no effect; the effects own {', '.join(owner)}")
        stray = [k for k, v in params.items() if owner[k] not in self.effects and v != EFFECTS[owner[k]].neutral]
        if stray:
            raise CalibError(f"{', '.join(stray)} belong(s) to effect(s) "
                             f"{', '.join(sorted({owner[k] for k in stray}))} not in the model "
                             f"(revision {self.revision}); `calib model add` it first")

    def to_toml(self) -> str:
        return tomli_w.dumps({"revision": self.revision, "effects": list(self.effects), "note": self.note})


def _archived(run: Path) -> list[int]:
    """The revisions RUN/model/ keeps (rev-NNNN.toml), in order."""
    d = Path(run) / "model"
    names = (q.stem[4:] for q in d.glob("rev-*.toml")) if d.is_dir() else ()
    return sorted(int(n) for n in names if n.isdigit())


def load_model(run: Path) -> Model:
    p = Path(run) / MODEL_FILE
    if p.exists() and not p.is_file():
        raise CalibError(f"{p} is not a file: move it aside (the model's revisions are kept in {p.parent / 'model'})")
    if not p.is_file():
        kept = _archived(run)
        if kept:  # read as the default model, revision 0, it would be compared and calibrated as one
            last = Path(run) / "model" / f"rev-{kept[-1]:04d}.toml"
            which = f"revision {kept[0]}" if len(kept) == 1 else f"revisions {kept[0]}-{kept[-1]}"
            raise CalibError(f"{p} is missing, but {p.parent / 'model'} keeps {which}: "
                             f"restore the current one (cp {last} {p})")
        return Model(tuple(DEFAULT_EFFECTS), 0, "default model (no model.toml yet)")
    try:
        d = tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CalibError(f"{p} is not a valid model file (not TOML: {e})") from None
    effects = d.get("effects")
    if not isinstance(effects, list) or not all(isinstance(e, str) for e in effects):
        raise CalibError(f"{p} is not a valid model file: it needs effects = [\"name\", ...] (`calib model add` "
                         f"writes it), got {effects!r}")
    revision = d.get("revision", 1)
    if isinstance(revision, bool) or not isinstance(revision, int) or not 0 <= revision <= MAX_REVISION:
        raise CalibError(f"{p} is not a valid model file: revision must be a whole number from 0 to {MAX_REVISION}, "
                         f"got {revision!r}")  # 1.5 is no revision, and a table cannot hold 10^23
    if not effects or len(set(effects)) < len(effects):
        raise CalibError(f"{p} is not a valid model file: effects must name each effect once, got {effects!r} "
                         "(`calib model add` and `model remove` write it)")
    _check_kept(p, revision, effects)
    try:
        return Model(tuple(effects), revision, str(d.get("note", "")))
    except (TypeError, ValueError) as e:
        raise CalibError(f"{p} is not a valid model file ({e})") from None


def _check_kept(p: Path, revision: int, effects: list) -> None:
    """Refuse a model.toml whose effects are not those of the revision it names as kept in RUN/model/: edited
    by hand, its calibration would be filed, and its earlier folders replaced, under the other model's number."""
    kept = p.parent / "model" / f"rev-{revision:04d}.toml"
    try:
        other = tomllib.loads(kept.read_text()).get("effects") if kept.is_file() else None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError):
        return  # a damaged copy: the current file is the one read
    if isinstance(other, list) and set(map(str, other)) != set(effects):
        raise CalibError(f"{p} names revision {revision} with effects {', '.join(effects)}, but {kept} keeps that "
                         f"revision with {', '.join(map(str, other))}: change the model with `calib model add` or "
                         f"`model remove` (they number a new revision), or restore it (cp {kept} {p})")


def save_model(run: Path, model: Model) -> Model:
    """Write a new revision (kept in RUN/model/) and make it current. It is numbered after every revision
    kept, so that a model.toml set back to an earlier revision never overwrites a later one: compare's
    history and calibrate's folders name revisions by number."""
    run = Path(run)
    with art.run_lock(run):  # a compare running meanwhile would label its residuals with the wrong revision
        old = load_model(run)
        if (run / "model").exists() and not (run / "model").is_dir():
            raise CalibError(f"{run / 'model'} is not a folder: move it aside (it keeps the model's revisions)")
        new = Model(model.effects, max([old.revision, *_archived(run)]) + 1, model.note)
        art.atomic_write_bytes(run / "model" / f"rev-{new.revision:04d}.toml", new.to_toml().encode())
        art.atomic_write_bytes(run / MODEL_FILE, new.to_toml().encode())
    return new
