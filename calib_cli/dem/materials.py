"""Materials and interactions -> the run's contact model (which laws) and the parameter rows its
laws read (:mod:`.laws.columns`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, make_dataclass

import numpy as np

from ..errors import CalibError
from ..parameters import PARAMETERS as DECLARED
from . import laws
from .laws import ContactModel, all_laws, law_params
from .laws import columns
from .laws.damping import damping_ratio
from .laws.normal import jkr_constants
from .laws.rolling import rolling_spring_constants

#: an interaction's law switches (0/1): which law of a family a run uses (:func:`contact_model`)
LAW_SWITCHES = ("rolling_own_spin", "friction_net_force", "rolling_spring", "caps_pulloff")


@dataclass(frozen=True)
class Material:
    """Elastic solid. The shear modulus is reduced from the real material's, as is common
    DEM practice, so that the Rayleigh time step is large (SPEC section 5)."""

    shear_modulus: float = 2e6  # Pa
    poisson: float = 0.25
    density: float = 2600.0  # kg/m3 (concrete aggregate)

    @property
    def youngs_modulus(self) -> float:
        return 2.0 * self.shear_modulus * (1.0 + self.poisson)

    def validate(self, what: str = "material") -> None:
        if not (self.shear_modulus > 0 and np.isfinite(self.shear_modulus)):
            raise CalibError(f"{what}: shear modulus must be positive, got {self.shear_modulus}")
        if not -1.0 < self.poisson < 0.5:
            raise CalibError(f"{what}: Poisson's ratio must lie in (-1, 0.5), got {self.poisson}")
        if not (self.density > 0 and np.isfinite(self.density)):
            raise CalibError(f"{what}: density must be positive, got {self.density}")


@dataclass(frozen=True)
class _BuiltIn:
    """The built-in laws' values; a law's own follow (:class:`Interaction`)."""

    # the defaults a heap test gives too: one declaration each (calib_cli.parameters)
    static_friction: float = DECLARED["static_friction"].default
    rolling_friction: float = DECLARED["rolling_friction"].default
    restitution: float = DECLARED["restitution"].default
    surface_energy: float = DECLARED["surface_energy"].default  # J/m2
    #: 0: rolling torque from the pair's relative spin (SPEC 5, Ai et al. 2011 type A, EDEM's
    #: 'RVD'); 1: from each body's own spin (EDEM's 'Standard' rolling friction model)
    rolling_own_spin: float = 0.0
    #: 0: Coulomb cap mu_s x the repulsive part of the normal force (SPEC 5); 1: mu_s x |net
    #: normal force| (a literal reading of EDEM's JKR help: a contact near zero load slides freely)
    friction_net_force: float = 0.0
    #: 0: the constant directional torque above; 1: a spring-dashpot-slider (Ai et al. 2011 type C,
    #: LAMMPS `rolling sds`), which holds a static torque below mu_r |F_n| R (no creep)
    rolling_spring: float = 0.0
    #: 0: the caps above; 1: both caps (sliding and rolling) on |F_el + 2 F_c|, F_c = 3 pi g R* the
    #: JKR pull-off force (Thornton 1991, Marshall 2009; LAMMPS's jkr): the same as 0 without cohesion
    caps_pulloff: float = 0.0

    def validate(self, what: str = "interaction") -> None:
        """Each value within what its law accepts: a one-line error naming the value, not the whole row."""
        for name in ("static_friction", "rolling_friction", "restitution", "surface_energy"):
            if not np.isfinite(getattr(self, name)):
                raise CalibError(f"{what}: {name} must be finite (got {getattr(self, name)})")
        rules = [  # (the value's name, allowed, the rule a message states)
            ("static_friction", self.static_friction >= 0, "must be >= 0"),
            ("rolling_friction", self.rolling_friction >= 0, "must be >= 0"),
            ("restitution", 0 < self.restitution <= 1, "must lie in (0, 1]"),
            ("surface_energy", self.surface_energy >= 0, "must be >= 0"),
            *((s, getattr(self, s) in (0.0, 1.0), "must be 0 or 1") for s in LAW_SWITCHES),
        ]
        for name, ok, rule in rules:
            if not ok:
                raise CalibError(f"{what}: {name} {rule} (got {getattr(self, name):g})")
        for ok, why in ((not (self.rolling_spring and self.rolling_own_spin),
                         "rolling_spring and rolling_own_spin exclude each other (two rolling laws)"),
                        (not (self.caps_pulloff and self.friction_net_force),
                         "caps_pulloff and friction_net_force exclude each other (two friction caps)")):
            if not ok:
                raise CalibError(f"{what}: {why}")
        for p in law_params():
            why = p.check(getattr(self, p.name))
            if why is not None:
                raise CalibError(f"{what}: {why} (got {getattr(self, p.name):g})")


#: Contact parameters between two materials (EDEM's 'interaction' table): the built-in laws' values,
#: then each law's own (:func:`calib_cli.dem.laws.law_params`: a new law adds its fields here)
Interaction = make_dataclass(
    "Interaction", [(p.name, float, field(default=p.default)) for p in law_params()], bases=(_BuiltIn,),
    frozen=True, namespace={"__doc__": "Contact parameters between two materials (EDEM's 'interaction' table): "
                                       "the built-in laws' values, then each law's own."})
Interaction.__module__ = __name__


def effective_moduli(m1: Material, m2: Material) -> tuple[float, float]:
    """E* and G* of a material pair (Hertz-Mindlin)."""
    e_inv = (1 - m1.poisson**2) / m1.youngs_modulus + (1 - m2.poisson**2) / m2.youngs_modulus
    g_inv = (2 * (2 - m1.poisson) * (1 + m1.poisson) / m1.youngs_modulus
             + 2 * (2 - m2.poisson) * (1 + m2.poisson) / m2.youngs_modulus)
    return 1.0 / e_inv, 1.0 / g_inv


def param_row(m1: Material, m2: Material, it: Interaction, m_typ: float = 0.0) -> np.ndarray:
    """The laws' row of one interaction (columns: :mod:`.laws.columns`); ``m_typ`` (a typical grain's
    mass) sets the rolling spring's damping."""
    Es, Gs = effective_moduli(m1, m2)
    k13, att = jkr_constants(Es, it.surface_energy)
    kr, gr = rolling_spring_constants(Gs, m_typ) if it.rolling_spring else (0.0, 0.0)
    row = np.zeros(columns.NCOL)
    row[:columns.BUILT_IN] = [Es, Gs, it.static_friction, it.rolling_friction, damping_ratio(it.restitution),
                it.surface_energy, k13, att, math.sqrt(4.0 * Gs / Es), kr, gr]
    values = asdict(it)
    for law in (law for law in all_laws() if law.columns):
        row[list(law.columns)] = law.constants(**{p.name: values[p.name] for p in law.params})
    return row


def contact_model(*its: Interaction) -> ContactModel:
    """The laws a run's interactions (particle-particle first) compose (each law's ``selected`` rule,
    :func:`calib_cli.dem.laws.compose`: JKR where any has a surface energy, a liquid bridge where the
    grains carry a liquid, the rolling law and friction caps the switches name). The walls take the
    grains' law switches and settings."""
    pp = its[0]
    shared = (*LAW_SWITCHES, *(p.name for p in law_params() if p.setting))
    if any(getattr(it, k) != getattr(pp, k) for it in its[1:] for k in shared):
        raise CalibError(f"the walls take the grains' contact laws: {', '.join(shared)} must be the same on every "
                         "interaction")
    return laws.compose(*its)
