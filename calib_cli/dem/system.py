"""A particle system with a floor and a liftable cylinder, and the factory of its stepper."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibError
from .compile import STATE_DTYPES, compiled
from .forces import forces_of
from .integrate import NEED_CAPACITY, stepper
from .laws.columns import CYL, E_S, FLOOR, G_S, GAMMA, HIST, PP
from .materials import Interaction, Material, contact_model, param_row
from .neighbours import build_pairs, transfer_history
from .timestep import jkr_time_step, rayleigh_time_step


#: "double": every state array float64. "mixed": velocities, spins, forces, torques and contact histories
#: stored as float32 (the arithmetic stays float64: numba promotes a float32 against a float64 constant,
#: then stores the result rounded), positions float64, as a creeping grain's step v dt (2e-9 m at 0.1 mm/s)
#: is below float32's resolution of a position (4e-9 m at 50 mm). Half the bytes a contact moves, for the GPU
PRECISIONS = tuple(STATE_DTYPES)


class UnstableError(CalibError):
    """The integration went unstable: never return an angle from such a run."""


@dataclass
class Walls:
    floor: bool = True
    cylinder_radius: float = 0.0  # m; 0 = no cylinder
    lift_speed: float = 0.0  # m/s
    lift_start: float = np.inf  # s; the rim rises at lift_speed from this time


@dataclass
class Particles:
    pos: np.ndarray
    rad: np.ndarray
    vel: np.ndarray | None = None
    omg: np.ndarray | None = None

    def __post_init__(self):
        self.pos = np.ascontiguousarray(self.pos, dtype=np.float64).reshape(-1, 3)
        self.rad = np.ascontiguousarray(self.rad, dtype=np.float64).ravel()
        n = len(self.rad)
        self.vel = np.zeros((n, 3)) if self.vel is None else np.ascontiguousarray(self.vel, dtype=np.float64)
        self.omg = np.zeros((n, 3)) if self.omg is None else np.ascontiguousarray(self.omg, dtype=np.float64)
        if self.pos.shape[0] != n or not np.all(self.rad > 0):
            raise CalibError("particles need one position per radius and positive radii")


@dataclass
class System:
    """State and parameters of one simulation; :meth:`advance` integrates it.

    ``dt`` defaults to ``safety`` x the critical step: the smaller of the Rayleigh time
    of the smallest particle and the JKR contact step (:func:`.timestep.jkr_time_step`).
    The contact laws are the composition the interactions call for (:func:`.materials.contact_model`).
    """

    particles: Particles
    material: Material = field(default_factory=Material)
    wall_material: Material = field(default_factory=lambda: Material(shear_modulus=2e6))
    pp: Interaction = field(default_factory=Interaction)
    floor: Interaction = field(default_factory=Interaction)
    cylinder: Interaction = field(default_factory=Interaction)
    walls: Walls = field(default_factory=Walls)
    gravity: tuple = (0.0, 0.0, -9.81)
    dt: float | None = None
    safety: float = 0.2
    skin_ratio: float = 0.3  # Verlet skin as a fraction of the mean radius
    overlap_limit: float = 0.1  # overlap / radius above which the run is unstable
    speed_limit: float = 50.0  # m/s; nothing in a heap test moves this fast
    t: float = 0.0
    n_steps: int = 0
    n_rebuilds: int = 0
    max_overlap: float = 0.0
    precision: str = "double"  # PRECISIONS: what the state arrays store

    def __post_init__(self):
        if self.precision not in PRECISIONS:
            raise CalibError(f"precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}")
        for m, w in ((self.material, "particle material"), (self.wall_material, "wall material")):
            m.validate(w)
        for it, w in ((self.pp, "particle-particle"), (self.floor, "particle-floor"),
                      (self.cylinder, "particle-cylinder")):
            it.validate(w)
        p = self.particles
        n = len(p.rad)
        # products, not rad**3: numpy's float64 power runs SVML code on AVX-512 CPUs, which
        # differs from other CPUs' in the last place (docs/performance.md, "Reproducibility")
        self.mass = self.material.density * 4.0 / 3.0 * np.pi * (p.rad * p.rad * p.rad)
        self.inv_inertia = 1.0 / (0.4 * self.mass * (p.rad * p.rad))
        m_typ = float(self.mass.mean())
        self.prm = np.vstack([param_row(self.material, self.material, self.pp, m_typ),
                              param_row(self.material, self.wall_material, self.floor, m_typ),
                              param_row(self.material, self.wall_material, self.cylinder, m_typ)])
        rmin, rho = p.rad.min(), self.material.density
        self.rayleigh_dt = rayleigh_time_step(rmin, rho, self.material.shear_modulus, self.material.poisson)
        self.jkr_dt = min(jkr_time_step(rmin, rho, row[E_S], row[G_S], row[GAMMA], wall=w)
                          for row, w in ((self.prm[0], False), (self.prm[1], True), (self.prm[2], True)))
        self.critical_dt = min(self.rayleigh_dt, self.jkr_dt)
        if self.dt is None:
            self.dt = self.safety * self.critical_dt
        if not (0 < self.dt <= self.critical_dt):
            raise CalibError(f"time step {self.dt:.3g} s exceeds the critical step {self.critical_dt:.3g} s "
                             f"(Rayleigh {self.rayleigh_dt:.3g} s, JKR contact {self.jkr_dt:.3g} s): the run would "
                             f"be unstable; lower it")
        w = self.walls
        # one composition of laws a run: the walls that exist must ask for the grains' laws
        self.model = contact_model(self.pp, *[it for it, on in ((self.floor, w.floor),
                                                               (self.cylinder, w.cylinder_radius > 0)) if on])
        rmax = p.rad.max()
        # the widest gap any law acts across: the largest pair's (R* = r_max / 2), a grain on a wall (R* = r_max)
        self.gap = np.array([self.model.reach(self.prm[PP], rmax / 2.0), self.model.reach(self.prm[FLOOR], rmax),
                             self.model.reach(self.prm[CYL], rmax)])
        self.skin = self.skin_ratio * p.rad.mean()
        self.reach = self.skin + self.gap[PP]
        self.geo = np.array([w.cylinder_radius, 0.0, w.lift_speed, 1.0 if w.cylinder_radius > 0 else 0.0,
                             1.0 if w.floor else 0.0, 0.0])
        self.grav = np.asarray(self.gravity, dtype=np.float64)
        f = self.state_dtype
        p.vel, p.omg = p.vel.astype(f, copy=False), p.omg.astype(f, copy=False)
        self.force = np.zeros((n, 3), f)
        self.torque = np.zeros((n, 3), f)
        self.hf = np.zeros((n, HIST), f)
        self.hc = np.zeros((n, HIST), f)
        self.ncont = np.zeros(n)
        self.cnew = np.zeros(n)
        self._alloc(16 * n + 64)
        self._rebuild()
        compiled(self.model.spec, "forces", self.precision)  # once per machine: other processes wait, then load it
        forces_of(self.model.spec)(p.pos, p.vel, p.omg, p.rad, self.mass, self.inv_inertia, self.pi, self.pj,
                       self.npairs[0], self.ht, self.hf, self.hc, self.prm, self.gap, self.geo, self.grav, self.dt,
                       self.force, self.torque, self.ncont, self.cnew, self.pf)

    def _alloc(self, cap: int, keep: int = 0):
        old = getattr(self, "pi", None)
        f = self.state_dtype
        pi, pj, ht = np.zeros(cap, np.int64), np.zeros(cap, np.int64), np.zeros((cap, HIST), f)
        if old is not None and keep:
            pi[:keep], pj[:keep], ht[:keep] = self.pi[:keep], self.pj[:keep], self.ht[:keep]
        self.pi, self.pj, self.ht = pi, pj, ht
        self.spare_i, self.spare_j = np.zeros(cap, np.int64), np.zeros(cap, np.int64)
        self.spare_h = np.zeros((cap, HIST), f)
        self.pf = np.zeros((cap, 11))
        if not hasattr(self, "npairs"):
            self.npairs = np.zeros(1, np.int64)

    def _rebuild(self):
        p = self.particles
        while True:
            cnt = build_pairs(p.pos, p.rad, self.reach, self.spare_i, self.spare_j)
            if cnt >= 0:
                break
            self._alloc(2 * len(self.pi), keep=int(self.npairs[0]))
        transfer_history(self.pi, self.pj, self.ht, self.npairs[0], self.spare_i, self.spare_j, self.spare_h, cnt)
        self.pi[:cnt], self.pj[:cnt], self.ht[:cnt] = self.spare_i[:cnt], self.spare_j[:cnt], self.spare_h[:cnt]
        self.npairs[0] = cnt
        self.ref_pos = p.pos.copy()

    @property
    def state_dtype(self) -> type:
        """The dtype of the velocities, spins, forces, torques and contact histories (positions and the
        grains' constants are float64 in every precision)."""
        return STATE_DTYPES[self.precision]

    @property
    def n(self) -> int:
        return len(self.particles.rad)

    @property
    def drag(self) -> float:
        return float(self.geo[5])

    @drag.setter
    def drag(self, value: float) -> None:
        self.geo[5] = value

    @property
    def rim_height(self) -> float:
        return float(self.geo[1])

    def advance(self, nsteps: int) -> None:
        """Integrate ``nsteps`` steps; raises :class:`UnstableError` on blow-up."""
        p = self.particles
        # here, not at set-up: the GPU engine sets systems up, never steps them
        compiled(self.model.spec, "steps", self.precision)
        done = 0
        while done < nsteps:
            status, k, worst, reb = stepper(self.model.spec)(
                nsteps - done, self.t, self.dt, p.pos, p.vel, p.omg, self.force, self.torque, p.rad, self.mass,
                self.inv_inertia, self.pi, self.pj, self.npairs, self.ht, self.ref_pos, self.skin, self.reach,
                self.hf, self.hc, self.prm, self.gap, self.geo, self.walls.lift_start, self.grav, self.overlap_limit,
                self.speed_limit, self.spare_i, self.spare_j, self.spare_h, self.ncont, self.cnew, self.pf)
            done += k
            self.t += k * self.dt
            self.n_steps += k
            self.n_rebuilds += reb
            self.max_overlap = max(self.max_overlap, worst)
            if status == NEED_CAPACITY:
                self._alloc(2 * len(self.pi), keep=int(self.npairs[0]))
                continue
            if status == 2:
                raise UnstableError(
                    f"unstable run: overlap reached {worst:.1%} of a radius at t = {self.t:.4g} s "
                    f"(limit {self.overlap_limit:.0%}); lower the time step or raise the shear modulus")
            if status == 3:
                raise UnstableError(
                    f"unstable run: a particle exceeded {self.speed_limit:g} m/s (or went NaN) at t = {self.t:.4g} s; "
                    f"lower the time step")

    def kinetic_energy(self) -> float:
        p = self.particles
        return float(0.5 * np.sum(self.mass * np.sum(p.vel**2, axis=1))
                     + 0.5 * np.sum(np.sum(p.omg**2, axis=1) / self.inv_inertia))

    def potential_energy(self) -> float:
        return float(-np.sum(self.mass * (self.particles.pos @ self.grav)))


def make_stepper(system: System):
    """jax-md style: return ``step(n)`` advancing the system by n steps."""

    def step(n: int = 1) -> System:
        system.advance(n)
        return system

    return step
