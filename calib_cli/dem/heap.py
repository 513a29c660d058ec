"""The heap (angle-of-repose) test of paper section 2.2, scaled by presets.

A vertical cylinder on the floor is filled with polydisperse spheres, they settle,
the cylinder is lifted at a set speed, the heap forms on the floor, and the run
ends when the particles are at rest (rms speed below a threshold) or at a time
limit. The paper's rig is 150 mm x 300 mm, lifted at 300 mm/min; presets scale it
down for speed (see docs/physics.md for the ranges each preset is valid for).
"""

from __future__ import annotations

import math
import time
import zipfile
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from ..errors import CalibError
from . import KERNEL_VERSION
from ..profile import line_fit
from .angle import CoordAngle, no_angle, repose_angle_coords
from .laws import ContactModel, law_params
from ..parameters import PARAMETERS as DECLARED, check_rig
from .materials import LAW_SWITCHES, Interaction, Material, contact_model
from .system import Particles, System, UnstableError, Walls

#: parameters the heap test takes (natural units). wall_* set the floor and the cylinder alike and
#: default to the particle values, except wall_surface_energy (default 0); cylinder_* set the
#: cylinder alone and default to wall_*. The floor's own values belong to the rig: FLOOR_VARIABLES
WALL_VALUES = ("static_friction", "rolling_friction", "surface_energy", "restitution")
PARAMETERS = ("static_friction", "rolling_friction", "surface_energy", "restitution", "rolling_own_spin",
              "friction_net_force", "rolling_spring", "caps_pulloff",
              *(f"{w}_{k}" for w in ("wall", "cylinder") for k in WALL_VALUES),
              *(p.name for p in law_params()))
#: the floor material's values against the grains (e.g. from an inclined-plane test on the rig's
#: plate): heap-test variables, so conditions on different floors differ; unset (NaN): wall_*
FLOOR_VARIABLES = tuple(f"floor_{k}" for k in WALL_VALUES)
PARTICLE_DEFAULTS = {**{k: DECLARED[k].default for k in WALL_VALUES},  # calib_cli.parameters declares them
                     "rolling_own_spin": 0.0, "friction_net_force": 0.0, "rolling_spring": 0.0, "caps_pulloff": 0.0,
                     **{p.name: p.default for p in law_params()}}
#: law switches (0/1) and a law's fixed settings (e.g. the liquid's contact angle, a bridge's volume),
#: not calibrated values: the walls take the grains' choice
LAWS = (*LAW_SWITCHES, *(p.name for p in law_params() if p.setting))
#: values the walls never take from the grains: no wall sticks (a wet fill glued to the lifting cylinder is
#: an effect of its own, and would be carried up with it), and a law may say so of its own (a wall holds
#: no liquid bridge)
WALL_ZERO = ("surface_energy", *(p.name for p in law_params() if p.wall_zero))


#: the numeric heap-test variables (columns of a conditions table); `floor` is a name, the floor
#: material's values are FLOOR_VARIABLES
CONDITION_VARIABLES = ("particle_d_min_mm", "particle_d_max_mm", "cylinder_diameter_mm", "fill_height_mm",
                       "lift_speed_mm_s", *FLOOR_VARIABLES)


@dataclass(frozen=True)
class HeapCondition:
    """Heap-test variables (the columns of a conditions table, SPEC section 6)."""

    particle_d_min_mm: float = 3.0
    particle_d_max_mm: float = 5.0
    cylinder_diameter_mm: float = 50.0
    fill_height_mm: float = 120.0
    lift_speed_mm_s: float = 50.0
    floor: str = "default"
    floor_static_friction: float = math.nan
    floor_rolling_friction: float = math.nan
    floor_surface_energy: float = math.nan
    floor_restitution: float = math.nan

    def floor_values(self) -> dict[str, float]:
        """The floor material's values this condition gives (FLOOR_VARIABLES that are not NaN)."""
        return {k: float(getattr(self, k)) for k in FLOOR_VARIABLES if not math.isnan(getattr(self, k))}

    def validate(self) -> None:
        infinite = [k for k in CONDITION_VARIABLES[:5] if math.isinf(getattr(self, k))]
        if infinite:  # every comparison below lets inf through; an infinite rig never finishes filling
            raise CalibError(f"heap condition {infinite[0]} must be a finite number, got {getattr(self, infinite[0])}")
        check_rig(self.particle_d_min_mm, self.particle_d_max_mm, self.cylinder_diameter_mm, self.fill_height_mm)
        if not self.lift_speed_mm_s > 0:
            raise CalibError(f"lift speed must be positive, got {self.lift_speed_mm_s} mm/s")
        if self.floor_values():
            Interaction(**{k.removeprefix("floor_"): v for k, v in self.floor_values().items()}).validate(
                f"floor {self.floor!r}")


@dataclass(frozen=True)
class Numerics:
    """Numerical settings of the heap run (not physics the user calibrates)."""

    shear_modulus: float = 5e6  # Pa, reduced (SPEC 5)
    poisson: float = 0.25
    density: float = 2600.0  # kg/m3
    wall_shear_modulus: float = 5e6
    safety: float = 0.2  # fraction of the critical step (Rayleigh / JKR contact)
    packing_fraction: float = 0.6  # of the settled fill, sets the particle count
    settle_speed: float = 0.01  # m/s: rms speed at which the fill counts as settled
    settle_drag: float = 10.0  # 1/s: background drag during the fill only (kills the fill's fall)
    settle_time_max: float = 1.0  # s
    rest_speed: float = 0.005  # m/s: rms speed at which the heap counts as at rest
    rest_time_min: float = 1.0  # s after the lift: the same creep time for every heap (docs/physics.md)
    time_max: float = 6.0  # s, total
    chunk: int = 400  # steps between checks
    precision: str = "double"  # what the state arrays store (calib_cli.dem.system.PRECISIONS)


@dataclass(frozen=True)
class Preset:
    condition: HeapCondition
    numerics: Numerics
    note: str


PRESETS: dict[str, Preset] = {
    "smoke": Preset(HeapCondition(6.0, 8.0, 50.0, 50.0, 100.0), Numerics(time_max=3.0),
                    "a few hundred 6-8 mm grains in a 50 mm cylinder: seconds; checks the chain, not the physics"),
    # a tall, narrow fill: at the paper's surface energies a 70 mm x 70 mm fill of 3-5 mm grains stood
    # as a column (3 of 7 Table 6 points); 50 mm x 120 mm carries enough weight to collapse (measured)
    "default": Preset(HeapCondition(3.0, 5.0, 50.0, 120.0, 50.0), Numerics(),
                      "the paper's 3-5 mm grains in a 50 mm cylinder filled 120 mm high: about 4,000 particles"),
    "paper": Preset(HeapCondition(3.0, 5.0, 150.0, 150.0, 5.0), Numerics(time_max=45.0),
                    "the paper's rig: 150 mm cylinder, 3-5 mm grains, lifted at 300 mm/min (about 45,000 particles)"),
}


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise CalibError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[name]


def interactions(params: Mapping[str, float], condition: HeapCondition | None = None
                 ) -> tuple[Interaction, Interaction, Interaction]:
    """(particle-particle, particle-floor, particle-cylinder) interactions.

    A wall's value is, first found: the condition's ``floor_*`` (for the floor) or ``cylinder_*``
    (for the cylinder), ``wall_*``, the particles' own (surface energy: 0). A rig's floor and its
    cylinder are different materials (the paper's is an organic-glass cylinder on a plate), and
    EDEM asks for each particle-geometry pair separately."""
    unknown = set(params) - set(PARAMETERS)
    if unknown:
        raise CalibError(f"unknown heap parameter(s) {sorted(unknown)}; known: {', '.join(PARAMETERS)}")
    own = {k: float(v) for k, v in params.items() if not k.startswith(("wall_", "cylinder_"))}
    p = {**PARTICLE_DEFAULTS, **own}
    # walls share the particles' friction and restitution unless given; they do not stick (WALL_ZERO)
    w = {k: float(params.get(f"wall_{k}", 0.0 if k in WALL_ZERO else p[k])) for k in PARTICLE_DEFAULTS}
    pp = Interaction(**p)
    floor = condition.floor_values() if condition is not None else {}
    pf = Interaction(**{k: floor.get(f"floor_{k}", v) for k, v in w.items()})
    pc = Interaction(**{k: float(params.get(f"cylinder_{k}", v)) for k, v in w.items()})
    pp.validate("particle-particle parameters")
    pf.validate("particle-floor parameters")
    pc.validate("particle-cylinder parameters")
    return pp, pf, pc


def heap_model(params: Mapping[str, float], condition: HeapCondition | None = None) -> ContactModel:
    """The composition of contact laws a heap test of these parameters runs (its floor and its cylinder
    are walls, which take the grains' laws): what its cache key names (calib_cli.heaps.keys)."""
    return contact_model(*interactions(params, condition))


def fill_cylinder(cond: HeapCondition, packing: float, rng: np.random.Generator) -> Particles:
    """Particles on a jittered hexagonal close-packed lattice inside the cylinder, enough
    to fill it to the fill height at the given packing fraction once settled.
    Diameters uniform in [d_min, d_max]."""
    d_min, d_max = cond.particle_d_min_mm * 1e-3, cond.particle_d_max_mm * 1e-3
    Rc = cond.cylinder_diameter_mm * 0.5e-3
    H = cond.fill_height_mm * 1e-3
    mean_d3 = (d_max**4 - d_min**4) / (4 * (d_max - d_min)) if d_max > d_min else d_max**3
    n = int(round(packing * math.pi * Rc**2 * H / (math.pi / 6 * mean_d3)))
    s = d_max * 1.04
    dz = s * math.sqrt(2.0 / 3.0)
    layers = []
    nl = 0
    while sum(len(l) for l in layers) < n:
        # ABC stacking: each layer's triangular lattice shifted
        off = [(0.0, 0.0), (s / 2, s / (2 * math.sqrt(3))), (0.0, s / math.sqrt(3))][nl % 3]
        rows = np.arange(-Rc / (s * math.sqrt(3) / 2) - 1, Rc / (s * math.sqrt(3) / 2) + 1)
        pts = [(c * s + (r % 2) * s / 2 + off[0], r * s * math.sqrt(3) / 2 + off[1])
               for r in rows for c in np.arange(-Rc / s - 1, Rc / s + 1)]
        p = np.array(pts)
        p = p[np.hypot(p[:, 0], p[:, 1]) <= Rc - 0.55 * s]
        if len(p) == 0:
            raise CalibError("the cylinder is too narrow for one layer of particles")
        layers.append(np.column_stack([p, np.full(len(p), s / 2 + nl * dz)]))
        nl += 1
    pts = np.vstack(layers)[:n]
    d = rng.uniform(d_min, d_max, n) if d_max > d_min else np.full(n, d_max)
    pts = pts + rng.uniform(-1, 1, (n, 3)) * ((s - d)[:, None] / 2) * 0.5
    return Particles(pts, d / 2, vel=rng.normal(0, 0.01, (n, 3)))


@dataclass
class HeapResult:
    system: System
    status: str  # ok | column | no_heap | timeout | unstable
    message: str
    angle: CoordAngle
    t_settled: float
    t_lift_end: float
    t_end: float
    wall_s: float
    params: dict
    condition: HeapCondition
    numerics: Numerics
    seed: int
    energy: list = field(default_factory=list)  # (t, kinetic energy, rim height)
    angle_drift: float = float("nan")  # deg/s over the last DRIFT_WINDOW s (creep; docs/physics.md)

    @property
    def n_particles(self) -> int:
        return self.system.n

    @property
    def n_steps(self) -> int:
        return self.system.n_steps


#: s: the angle's rate of change is fitted over this window at the end of the rest phase
DRIFT_WINDOW = 0.3


class DriftMeter:
    """The rest phase's clock and the heap's creep: the coordinate angle is sampled over the
    last ``DRIFT_WINDOW`` s before the earliest end, and its least-squares slope (deg/s) tells
    how far from static the heap still is when it is measured. Shared by both engines."""

    def __init__(self, t_start: float, min_duration: float):
        self.t_done = t_start + min_duration
        self.samples: list[tuple[float, float]] = []

    def done(self, t: float) -> bool:
        return t >= self.t_done

    def sample(self, t: float, pos: np.ndarray, rad: np.ndarray) -> None:
        if self.samples and self.samples[-1][0] == t:  # a test resumed from a checkpoint samples its last t again
            return
        if t >= self.t_done - DRIFT_WINDOW:
            a = repose_angle_coords(pos, rad).angle
            if np.isfinite(a):
                self.samples.append((t, a))

    def rate(self) -> float:
        if len(self.samples) < 3:
            return float("nan")
        t, a = np.array(self.samples[-64:]).T
        t, a = t[t >= t[-1] - DRIFT_WINDOW], a[t >= t[-1] - DRIFT_WINDOW]
        if len(t) < 3 or np.ptp(t) <= 0:
            return float("nan")
        return line_fit(t, a)[1]  # not np.polyfit: its LAPACK solve differs by CPU in the last place


#: wall seconds between two checkpoints of a heap (run_heap's ``every``)
CHECKPOINT_EVERY = 300.0


def run_heap(params: Mapping[str, float], condition: HeapCondition | None = None, numerics: Numerics | None = None,
             seed: int = 0, progress: Callable[[float, float, str], None] | None = None,
             checkpoint: Path | None = None, every: float = CHECKPOINT_EVERY) -> HeapResult:
    """Simulate one heap test on the CPU kernel and measure its angle from the particle coordinates.

    ``progress(t, t_max, phase)`` is called after each chunk. A run whose integration blows up
    (:class:`UnstableError`) comes back with status ``unstable`` and no angle, so a campaign records
    it and goes on; a time step that cannot be stable is refused before any step (a :class:`CalibError`).
    With ``checkpoint`` (a file), the test goes on from it where one exists and saves its state there
    every ``every`` seconds, so that a stopped heap (hours at the ``paper`` preset) loses at most that.
    """
    test = resume(HeapTest(params, condition, numerics, seed, progress), checkpoint)
    last = time.monotonic()
    try:
        while not test.done:
            test.system.advance(test.numerics.chunk)
            test.advanced()
            if checkpoint is not None and not test.done and time.monotonic() - last > every:
                save_checkpoint(checkpoint, test.state())
                last = time.monotonic()
    except UnstableError as e:
        return test.result(str(e))
    return test.result()


def resume(test: "HeapTest", checkpoint: Path | None) -> "HeapTest":
    """``test`` restored from ``checkpoint`` where that file exists and reads; else as it is (an
    unreadable checkpoint is deleted: the test starts afresh)."""
    if checkpoint is None or not Path(checkpoint).is_file():
        return test
    try:
        with np.load(checkpoint, allow_pickle=False) as z:
            return test.restore({k: z[k] for k in z.files})
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error, CalibError):
        # a truncated or emptied .npz (damage from outside: the writes are atomic) is no checkpoint
        Path(checkpoint).unlink(missing_ok=True)
        return test


def save_checkpoint(path: Path, state: Mapping[str, np.ndarray]) -> None:
    """``state`` to ``path`` in one step (artifacts' atomic write): never half a checkpoint."""
    import io

    from ..artifacts import atomic_write_bytes

    buf = io.BytesIO()
    np.savez(buf, **state)
    atomic_write_bytes(path, buf.getvalue())


def heap_system(params: Mapping[str, float], cond: HeapCondition, num: Numerics, seed: int) -> System:
    """The heap test's system before its first step: the fill (seeded) in the cylinder on the floor."""
    pp, pf, pc = interactions(params, cond)
    parts = fill_cylinder(cond, num.packing_fraction, np.random.default_rng(seed))
    return System(parts, material=Material(num.shear_modulus, num.poisson, num.density),
                  wall_material=Material(num.wall_shear_modulus, num.poisson, num.density), pp=pp, floor=pf,
                  cylinder=pc, walls=Walls(True, cond.cylinder_diameter_mm * 0.5e-3, cond.lift_speed_mm_s * 1e-3,
                                            np.inf), safety=num.safety, precision=num.precision)


class HeapTest:
    """One heap test (paper section 2.2: settle, lift, rest) on its system, for whoever advances it:
    while not :attr:`done`, advance :attr:`system` by ``numerics.chunk`` steps and call :meth:`advanced`;
    then :meth:`result`. The CPU engine (:func:`run_heap`) steps one system; the GPU engine steps many
    together (:func:`calib_cli.dem.gpu.run_heaps`); both follow this one protocol."""

    def __init__(self, params: Mapping[str, float], condition: HeapCondition | None = None,
                 numerics: Numerics | None = None, seed: int = 0, progress: Callable | None = None):
        self.params, self.seed, self.progress = dict(params), seed, progress
        self.condition = condition or PRESETS["default"].condition
        self.numerics = numerics or PRESETS["default"].numerics
        self.condition.validate()
        self.t0 = time.perf_counter()
        self.system = heap_system(params, self.condition, self.numerics, seed)
        self.energy: list = []
        self.t_settled = self.t_lift_end = self.fill_top = np.nan
        self.drift: DriftMeter | None = None
        self.stage = "settle"  # where the protocol stands: settle, lift or rest
        self._steps = self._protocol()
        self.phase: str | None = next(self._steps, None)  # the phase the next chunk belongs to

    @property
    def done(self) -> bool:
        return self.phase is None

    def advanced(self) -> None:
        """The system has been advanced by one chunk: on to the protocol's next decision."""
        self.phase = next(self._steps, None)

    def result(self, unstable: str | None = None) -> HeapResult:
        """The finished test's result; ``unstable``: the integration blew up, with this message."""
        sysm, cond, num = self.system, self.condition, self.numerics
        wall = time.perf_counter() - self.t0
        if unstable is not None:
            return HeapResult(sysm, "unstable", unstable, no_angle(), np.nan, np.nan, sysm.t, wall, self.params,
                              cond, num, self.seed, self.energy)
        status, message, ang = _verdict(sysm, cond, num, self.fill_top, self.t_lift_end)
        return HeapResult(sysm, status, message, ang, self.t_settled, self.t_lift_end, sysm.t, wall, self.params,
                          cond, num, self.seed, self.energy, self.drift.rate())

    def _chunk(self, phase: str):
        yield phase  # the driver advances the system here
        sysm = self.system
        self.energy.append((sysm.t, sysm.kinetic_energy(), sysm.rim_height))
        if self.progress:
            self.progress(sysm.t, self.numerics.time_max, phase)

    def _protocol(self):
        """Settle, lift, rest; yields before each chunk, and starts in the stage it stopped in (a test
        restored from a checkpoint, :meth:`restore`). ``t_lift_end`` stays NaN when the cylinder never
        cleared the grains."""
        sysm, cond, num = self.system, self.condition, self.numerics
        parts, Rc, d_max = sysm.particles, cond.cylinder_diameter_mm * 0.5e-3, cond.particle_d_max_mm * 1e-3
        if self.stage == "settle":
            # 1. settle inside the cylinder, with a background drag that only this phase has
            sysm.drag = num.settle_drag
            while sysm.t < num.settle_time_max:
                yield from self._chunk("settle")
                if _rms_speed(sysm) < num.settle_speed and sysm.t > 0.05:
                    break
            sysm.drag = 0.0
            self.t_settled = sysm.t
            self.fill_top = float(np.max(parts.pos[:, 2] + parts.rad))
            # 2. lift until the rim clears the settled fill, then remove the cylinder
            sysm.walls.lift_start = self.t_settled
            sysm.geo[2] = cond.lift_speed_mm_s * 1e-3
            self.stage = "lift"
        if self.stage == "lift":
            while sysm.t < num.time_max:
                yield from self._chunk("lift")
                # the cylinder is done once its rim clears every grain still inside it: a fill that
                # collapses meets the rising rim long before the rim reaches the settled fill's top
                if sysm.rim_height > min(self.fill_top, _top_inside(parts, Rc)) + d_max:
                    self.t_lift_end = sysm.t
                    break
            sysm.geo[3] = 0.0
            sysm.geo[2] = 0.0
            # 3. rest: at least rest_time_min, then until the rms speed is below rest_speed
            self.drift = DriftMeter(self.t_lift_end if np.isfinite(self.t_lift_end) else sysm.t, num.rest_time_min)
            self.stage = "rest"
        while sysm.t < num.time_max:
            self.drift.sample(sysm.t, parts.pos, parts.rad)
            if _rms_speed(sysm) < num.rest_speed and self.drift.done(sysm.t):
                break
            yield from self._chunk("rest")

    # -------------------------------------------------------------- checkpoints
    def state(self) -> dict[str, np.ndarray]:
        """Everything a stopped test needs to go on exactly as if it had not stopped (taken between chunks):
        the system's state, neighbour list and contact history, and where the protocol stands."""
        s, p = self.system, self.system.particles
        n = int(s.npairs[0])  # the list's used part: its arrays' spare room is most of them
        arrays = {k: getattr(s, k)[:n] if k in PAIR_STATE else getattr(s, k) for k in SYSTEM_STATE}
        return {**{k: np.array(v) for k, v in arrays.items()}, "pos": p.pos, "vel": p.vel, "omg": p.omg,
                "scalars": np.array([s.t, s.n_steps, s.n_rebuilds, s.max_overlap, s.walls.lift_start,
                                     self.t_settled, self.t_lift_end, self.fill_top,
                                     self.drift.t_done if self.drift else np.nan]),
                "stage": np.array(self.stage), "phase": np.array(self.phase or ""),
                "energy": np.array(self.energy, dtype=float).reshape(-1, 3),
                "drift": np.array(self.drift.samples if self.drift else [], dtype=float).reshape(-1, 2)}

    def restore(self, state: Mapping[str, np.ndarray]) -> "HeapTest":
        """Go on from :meth:`state` (of a test of the same parameters, condition, numerics and seed)."""
        s, p = self.system, self.system.particles
        n = len(state["pi"])
        if n > len(s.pi):
            s._alloc(2 * n)
        for k in SYSTEM_STATE:
            if k in PAIR_STATE:
                getattr(s, k)[:n] = state[k]
            else:
                getattr(s, k)[...] = state[k]
        p.pos[...], p.vel[...], p.omg[...] = state["pos"], state["vel"], state["omg"]
        t, steps, rebuilds, worst, lift_start, self.t_settled, self.t_lift_end, self.fill_top, t_done = state["scalars"]
        s.t, s.n_steps, s.n_rebuilds, s.max_overlap, s.walls.lift_start = t, int(steps), int(rebuilds), worst, lift_start
        self.energy = [tuple(r) for r in state["energy"]]
        self.stage = str(state["stage"])
        if self.stage == "rest":
            self.drift = DriftMeter(0.0, 0.0)
            self.drift.t_done, self.drift.samples = float(t_done), [tuple(r) for r in state["drift"]]
        self._steps = self._protocol()
        self.phase = next(self._steps, None)
        if self.phase != (str(state["phase"]) or None):
            raise CalibError("a heap's checkpoint does not resume where it stopped: delete it to start afresh")
        return self


#: the System arrays a checkpoint keeps (besides the grains' positions, velocities and spins)
SYSTEM_STATE = ("force", "torque", "pi", "pj", "ht", "npairs", "ref_pos", "hf", "hc", "ncont", "cnew", "geo")
PAIR_STATE = ("pi", "pj", "ht")


def _rms_speed(sysm: System) -> float:
    v = sysm.particles.vel
    return float(np.sqrt(np.sum(sysm.mass * np.sum(v * v, axis=1)) / np.sum(sysm.mass)))


def _top_inside(parts: Particles, Rc: float) -> float:
    """The top of the grains still inside the cylinder's radius (0 when none is)."""
    p = parts.pos
    inside = p[:, 0] ** 2 + p[:, 1] ** 2 < Rc * Rc
    return float(np.max(p[inside, 2] + parts.rad[inside])) if inside.any() else 0.0


def _verdict(sysm: System, cond: HeapCondition, num: Numerics, fill_top: float, t_lift_end: float) -> tuple:
    """(status, message, coordinate angle): timeout (lift or rest unfinished), column, no_heap or ok."""
    parts = sysm.particles
    status, message = "ok", ""
    if not np.isfinite(t_lift_end):
        status, message = "timeout", f"the cylinder had not cleared the particles at t = {sysm.t:.2f} s"
    elif _rms_speed(sysm) >= num.rest_speed:
        status, message = "timeout", (f"not at rest at the time limit {num.time_max:g} s "
                                      f"(rms speed {_rms_speed(sysm) * 1e3:.1f} mm/s)")
    ang = repose_angle_coords(parts.pos, parts.rad)
    # a cohesive fill can stand as a column after the lift: that is not a heap (issue 3)
    Rc = cond.cylinder_diameter_mm * 0.5e-3
    if ang.height > 0.7 * min(fill_top, cond.fill_height_mm * 1e-3) and ang.base_radius < 1.5 * Rc:
        status, message = "column", (f"no heap: the fill stood as a column ({ang.height * 1e3:.0f} mm high, "
                                     f"base radius {ang.base_radius * 1e3:.0f} mm)")
    elif not np.isfinite(ang.angle):
        status, message = "no_heap", "no flank could be fitted to the final state"
    return status, message, ang


def condition_dict(c: HeapCondition) -> dict:
    """The condition's variables, without the floor values it leaves unset (NaN): the cache keys of
    conditions made before the floor had values of its own stay what they were."""
    return {k: v for k, v in asdict(c).items() if not (isinstance(v, float) and math.isnan(v))}


def run_key(params: Mapping, condition: HeapCondition, numerics: Numerics, seed: int, model: str = "") -> dict:
    """Everything that determines a run's result (its cache key)."""
    return {"params": {k: float(v) for k, v in sorted(params.items())}, "condition": condition_dict(condition),
            "numerics": _numerics_key(numerics), "seed": int(seed), "model": model, "kernel": KERNEL_VERSION}


def _numerics_key(numerics: Numerics) -> dict:
    """The numerics a heap's key names; "double" precision, the default, is left out, so the keys of
    heaps computed before there was a choice stay theirs."""
    d = asdict(numerics)
    if d["precision"] == "double":
        del d["precision"]
    return d
