"""Contact laws as sub-models, composed by name (in the spirit of LAMMPS's GRANULAR package).

A contact's model is one law per family:

===========  ==========================================  ====================================
family       laws                                        module
===========  ==========================================  ====================================
normal       ``hertz``, ``jkr``                          :mod:`.normal`
cohesion     ``none``, ``capillary``                     :mod:`.capillary`
damping      ``edem``                                    :mod:`.damping`
cap          ``repulsive``, ``net``, ``pulloff``         :mod:`.cap`
tangential   ``mindlin``                                 :mod:`.tangential`
rolling      ``rvd``, ``standard``, ``sds``              :mod:`.rolling`
===========  ==========================================  ====================================

The rolling laws keep EDEM's names where EDEM has the law (``rvd``: "RVD Rolling Friction",
``standard``: "Standard Rolling Friction") and LAMMPS's where only LAMMPS has it (``sds``).

Each family's module documents the one signature all its laws share. A :class:`ContactModel` names
the composition; its :attr:`~ContactModel.spec` string is a compile-time constant of the kernel
(numba specialises the force loop on it), so a law is chosen once per run, not tested per contact.
The family dispatchers below (``normal(spec, ...)`` and so on) resolve the name while numba types
the caller and inline the law.

Adding a law: write it in a module with its family's signature, and add one :class:`Law` entry to
:data:`REGISTRY` (with a version: a heap's cache key names each law and its version, so changing a
law's arithmetic means raising its version); test it, document it (docs/physics.md). A law with
values of its own declares them in its module (:class:`~.params.Param`: the interaction, the heap
test's parameters, the walls' rule and the validation take them from there), takes its columns with
:func:`.columns.allocate`, computes them in ``constants``, says when a run composes it
(``selected``; two laws of one family selected by the same values are refused), and may bring a diagnose
candidate (an :class:`~calib_cli.effects.Effect`, ``pinned_when_absent=False``): the entry names them.
:mod:`.capillary` is the example. Tests then ask for the effect's name in ``calib_cli/cli/names.py`` and
a composition using the law in ``benchmarks/gpu_compile.py`` (docs/physics.md).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Callable

import numpy as np
from numba import types
from numba.core.target_extension import current_target
from numba.extending import overload

from ...effects import Effect
from ...errors import CalibError
from . import cap, capillary, damping, normal, rolling, tangential
from .params import Param

FAMILIES = ("normal", "cohesion", "damping", "cap", "tangential", "rolling")


@dataclass(frozen=True)
class Law:
    family: str
    name: str
    fn: Callable  # the compiled law
    version: int
    reference: str
    #: the gap beyond contact over which it acts, of an interaction row and the largest pair's R*
    reach: Callable[[np.ndarray, float], float] | None = None
    #: whether a run of these interactions (particle-particle, then the walls) composes this law; at most
    #: one law of a family may say so (:func:`compose`), the family's first law is the default
    selected: Callable[..., bool] | None = None
    #: the interaction values only this law reads, its parameter-row columns and their values
    #: (``constants(**values) -> tuple``, one per column)
    params: tuple[Param, ...] = ()
    columns: tuple[int, ...] = ()
    constants: Callable[..., tuple] | None = None
    #: the effect diagnose can add to a model to test for this law (None: not a candidate)
    effect: Effect | None = None


REGISTRY: dict[str, dict[str, Law]] = {f: {} for f in FAMILIES}


def register(law: Law) -> Law:
    REGISTRY[law.family][law.name] = law
    return law


for _law in [
    Law("normal", "hertz", normal.hertz, 1, "Hertz 1882; paper Eq. 6"),
    Law("normal", "jkr", normal.jkr, 1, "Johnson, Kendall & Roberts 1971; paper Eqs. 2-3", normal.jkr_reach,
        selected=lambda *its: any(it.surface_energy > 0 for it in its)),
    Law("cohesion", "none", capillary.none, 1, "-"),
    Law("cohesion", "capillary", capillary.capillary, 1,
        "Willett et al. 2000 (force), Lian, Thornton & Adams 1993 (rupture)", capillary.capillary_reach,
        selected=capillary.selected, params=capillary.PARAMS, constants=capillary.constants,
        columns=(capillary.BRIDGE_F, capillary.BRIDGE_RUPTURE, capillary.BRIDGE_GAP), effect=capillary.EFFECT),
    Law("damping", "edem", damping.edem, 1, "Tsuji et al. 1992; EDEM Hertz-Mindlin"),
    Law("cap", "repulsive", cap.repulsive, 1, "the built-in default"),
    Law("cap", "net", cap.net, 1, "EDEM's JKR help, literally", selected=lambda pp, *w: pp.friction_net_force > 0),
    Law("cap", "pulloff", cap.pulloff, 1, "Thornton 1991; LAMMPS jkr", selected=lambda pp, *w: pp.caps_pulloff > 0),
    Law("tangential", "mindlin", tangential.mindlin, 1, "Mindlin & Deresiewicz 1953; EDEM Hertz-Mindlin"),
    Law("rolling", "rvd", rolling.rvd, 1, "Ai et al. 2011 type A; EDEM 'RVD'"),
    Law("rolling", "standard", rolling.standard, 1, "Ai et al. 2011 type A on own spin; EDEM 'Standard'",
        selected=lambda pp, *w: pp.rolling_own_spin > 0),
    Law("rolling", "sds", rolling.sds, 1, "Ai et al. 2011 type C; LAMMPS rolling sds",
        selected=lambda pp, *w: pp.rolling_spring > 0),
]:
    register(_law)


def all_laws() -> list[Law]:
    """Every registered law, family by family in registry order."""
    return [law for family in REGISTRY.values() for law in family.values()]


def law_params() -> tuple[Param, ...]:
    """Every law's own parameters, in registry order (the interaction's fields after the built-in ones)."""
    return tuple(p for law in all_laws() for p in law.params)


def law_effects() -> list[Effect]:
    """The diagnose candidates the laws bring, in registry order."""
    return [law.effect for law in all_laws() if law.effect is not None]


def compose(*interactions) -> "ContactModel":
    """The laws a run of these interactions (particle-particle first, then the walls) composes: per
    family the law whose ``selected`` says so, else the family's first (its default). A contact has one
    law per family: values that select two of one family are refused, not resolved by order."""
    chosen = {}
    for family, laws in REGISTRY.items():
        picked = [law.name for law in laws.values() if law.selected is not None and law.selected(*interactions)]
        if len(picked) > 1:
            raise CalibError(f"the values given select {len(picked)} {family} laws ({', '.join(picked)}); a contact "
                             f"has one {family} law: give the values of one of them")
        chosen[family] = picked[0] if picked else next(iter(laws))
    return ContactModel(**chosen)


@dataclass(frozen=True)
class ContactModel:
    """One law per family, by name (defaults: the built-in Hertz-Mindlin with constant-torque rolling)."""

    normal: str = "hertz"
    cohesion: str = "none"
    damping: str = "edem"
    cap: str = "repulsive"
    tangential: str = "mindlin"
    rolling: str = "rvd"

    def __post_init__(self):
        for f in FAMILIES:
            name = getattr(self, f)
            if name not in REGISTRY[f]:
                raise CalibError(f"unknown {f} law {name!r}; known: {', '.join(REGISTRY[f])}")

    @property
    def spec(self) -> str:
        """``normal=jkr;cohesion=none;...``: the compile-time constant the kernel is specialised on."""
        return ";".join(f"{f}={getattr(self, f)}" for f in FAMILIES)

    @property
    def laws(self) -> list[Law]:
        return [REGISTRY[f][getattr(self, f)] for f in FAMILIES]

    @property
    def key(self) -> dict[str, str]:
        """Each family's law and its version (what a heap computed with this model depends on)."""
        return {law.family: f"{law.name}@{law.version}" for law in self.laws}

    def reach(self, row: np.ndarray, Rs_max: float) -> float:
        """The widest gap beyond contact at which any of its laws acts (0 for contact-only laws)."""
        return max([0.0] + [law.reach(row, Rs_max) for law in self.laws if law.reach is not None])

    @classmethod
    def parse(cls, spec: str) -> "ContactModel":
        parts = dict(p.split("=", 1) for p in spec.split(";") if p)
        return cls(**{k: v for k, v in parts.items() if k in {f.name for f in fields(cls)}})


def _law_of(spec, family: str):
    if not isinstance(spec, types.StringLiteral):
        return None
    return ContactModel.parse(spec.literal_value).laws[FAMILIES.index(family)].fn


def _inline_on_cpu(expr, caller_info, callee_info) -> bool:
    """Inline a law into its caller on the CPU (numba's IR inliner); on the GPU call it instead, where
    numba-cuda's inliner fails on these laws (and its own compiler inlines the call anyway)."""
    return "cuda" not in str(current_target()).lower()


def _dispatcher(family: str, params: str):
    """``family(spec, <params>)``: calls the law that ``spec`` (a string literal) names for ``family``.

    Made with exec because numba's overloads need explicit parameters (no *args) and each family has
    its own; the generated text is only the forwarding call."""
    ns: dict = {"overload": overload, "_law_of": _law_of, "_inline_on_cpu": _inline_on_cpu}
    exec(f"def {family}(spec, {params}):\n    raise NotImplementedError('compiled only')\n"
         f"@overload({family}, inline=_inline_on_cpu)\n"
         f"def _typing(spec, {params}):\n"
         f"    law = _law_of(spec, {family!r})\n"
         f"    if law is None:\n        return None\n"
         f"    def impl(spec, {params}):\n        return law({params})\n"
         f"    return impl\n", ns)
    fn = ns[family]
    fn.__doc__ = f"The run's {family} law: ``{family}(spec, {params})`` (see :mod:`calib_cli.dem.laws`)."
    return fn


normal_law = _dispatcher("normal", "delta, Rs, a_old, ht, k, prm, row")
cohesion_law = _dispatcher("cohesion", "delta, Rs, a, ht, k, prm, row")
damping_law = _dispatcher("damping", "a, ms, prm, row")
cap_law = _dispatcher("cap", "Fel, Frep, Rs, prm, row")
tangential_law = _dispatcher("tangential", "ht, k, nx, ny, nz, tx, ty, tz, a_old, a, ct, cap, prm, row, dt")
rolling_law = _dispatcher("rolling", "tix, tiy, tiz, tjx, tjy, tjz, ht, k, nx, ny, nz, Ri, Rj, Rs, Ii_inv, Ij_inv, "
                          "ci, cj, wix, wiy, wiz, wjx, wjy, wjz, Nr, prm, row, dt")
