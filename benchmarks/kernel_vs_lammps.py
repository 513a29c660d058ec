"""Throughput of the built-in kernel and LAMMPS on the same settled heap column, side by side.

Both engines start from the same state (a column of the `default` preset's particles,
settled by the built-in kernel inside its cylinder), use the same time step, skin,
materials and contact model as far as LAMMPS allows, and run the same number of steps
on one core each. Two cases:

* non-cohesive: LAMMPS `hertz/material` + `damping coeff_restitution` + `mindlin` +
  `rolling sds`, whose normal damping equals EDEM's (and ours); our rolling law is
  EDEM's constant directional torque, LAMMPS's is a spring-dashpot-slider (sds);
* cohesive: LAMMPS `jkr` with `damping viscoelastic` (it refuses coeff_restitution and tsuji
  with jkr), its coefficient matched to our damping at a typical contact.

Usage:  python benchmarks/kernel_vs_lammps.py [--steps 2000] [--preset default]
Prints particle-steps per second for each engine on one core and their ratio (equal core
counts), and the built-in kernel on all cores (its pair loop runs in parallel; LAMMPS on several
ranks is `--engine lammps --mpi N`, not timed here).
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import tempfile
import time

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from calib_cli.engines.lammps import open_lammps, write_data  # noqa: E402
from calib_cli.dem.heap import fill_cylinder, get_preset, interactions  # noqa: E402
from calib_cli.dem.materials import Material  # noqa: E402
from calib_cli.dem.system import System, Walls  # noqa: E402


def settled_column(preset: str, seed: int = 1):
    pre = get_preset(preset)
    c, num = pre.condition, pre.numerics
    parts = fill_cylinder(c, num.packing_fraction, np.random.default_rng(seed))
    pp, pf, pc = interactions({"static_friction": 0.5, "rolling_friction": 0.2, "restitution": 0.3})
    s = System(parts, material=Material(num.shear_modulus, num.poisson, num.density),
               wall_material=Material(num.wall_shear_modulus, num.poisson, num.density), pp=pp, floor=pf,
               cylinder=pc, walls=Walls(True, c.cylinder_diameter_mm * 0.5e-3, 0.0, np.inf))
    s.drag = num.settle_drag
    s.advance(int(0.25 / s.dt))
    s.drag = 0.0
    s.advance(int(0.05 / s.dt))
    return s, c, num


def ours(state: System, params: dict, steps: int, threads: int = 1):
    import numba

    numba.set_num_threads(threads)
    c_p = state.particles
    from calib_cli.dem.system import Particles

    p = Particles(c_p.pos.copy(), c_p.rad.copy(), c_p.vel.copy(), c_p.omg.copy())
    pp, pf, pc = interactions(params)
    s = System(p, material=state.material, wall_material=state.wall_material, pp=pp, floor=pf, cylinder=pc,
               walls=Walls(True, state.walls.cylinder_radius, 0.0, np.inf), dt=state.dt)
    s.advance(20)  # JIT warm-up outside the timing
    t = time.perf_counter()
    s.advance(steps)
    return time.perf_counter() - t, s


def lammps(state: System, params: dict, steps: int, cohesive: bool):
    p = state.particles
    E, nu, rho = state.material.youngs_modulus, state.material.poisson, state.material.density
    Rc = state.walls.cylinder_radius
    lo = p.pos.min(0) - 0.01
    hi = p.pos.max(0) + 0.05
    lo[2] = -0.001
    with tempfile.TemporaryDirectory() as d:
        data = os.path.join(d, "column.data")
        write_data(data, p.pos, p.rad, rho, lo, hi, p.vel, p.omg)
        mu, mur, e = params["static_friction"], params["rolling_friction"], params["restitution"]
        kt = 8 * 2e6 * 1e-4  # sds rolling stiffness of the order of a contact's tangential stiffness
        if cohesive:
            # viscoelastic: F_d = eta a m* v_n; eta matched to our 2 sqrt(5/6) |beta| sqrt(2 E* a m*) at a
            # typical contact (a = 1e-4 m, m* = 4e-5 kg): approximate, which is fine for a throughput figure
            Es = E / (2 * (1 - nu**2))
            beta = abs(math.log(e)) / math.sqrt(math.log(e) ** 2 + math.pi**2)
            eta = 2 * math.sqrt(5 / 6) * beta * math.sqrt(2 * Es / (1e-4 * 4e-5))
            normal = f"jkr {E:.6g} {eta:.6g} {nu} {params['surface_energy']} damping viscoelastic"
        else:
            normal = f"hertz/material {E:.6g} {e} {nu} damping coeff_restitution"
        model = f"{normal} tangential mindlin NULL 1.0 {mu} rolling sds {kt:.6g} 0.0 {mur}"
        wall = f"hertz/material {E:.6g} {e} {nu} damping coeff_restitution tangential mindlin NULL 1.0 {mu} " \
               f"rolling sds {kt:.6g} 0.0 {mur}"
        lmp = open_lammps()
        for cmd in [
            "units si", "atom_style sphere", "atom_modify map array", "boundary f f f", "newton off",
            "comm_modify vel yes", f"read_data {data}",
            f"neighbor {state.skin:.6g} bin", "neigh_modify delay 0 every 1 check yes",
            "pair_style granular", f"pair_coeff * * {model}",
            f"region cyl cylinder z 0 0 {Rc:.6g} {lo[2]} {hi[2]} side in units box",
            f"fix cylw all wall/gran/region granular {wall} region cyl",
            f"fix floor all wall/gran granular {wall} zplane 0.0 NULL",
            "fix grav all gravity 9.81 vector 0 0 -1", "fix nve all nve/sphere",
            f"timestep {state.dt:.10g}", "run 20",
        ]:
            lmp.command(cmd)
        t = time.perf_counter()
        lmp.command(f"run {steps}")
        wall_s = time.perf_counter() - t
        ke = lmp.get_thermo("ke")
        lmp.close()
    return wall_s, ke


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--preset", default="default")
    a = ap.parse_args()
    import numba
    state, cond, num = settled_column(a.preset)
    n = state.n
    print(f"settled column: {n} particles, {cond.particle_d_min_mm}-{cond.particle_d_max_mm} mm in a "
          f"{cond.cylinder_diameter_mm} mm cylinder; dt = {state.dt:.3g} s; {a.steps} steps; one core each")
    print(f"{'case':<14}{'calib 1 core':>14}{'LAMMPS 1 core':>15}{'ratio':>7}{'calib ' + str(numba.config.NUMBA_NUM_THREADS) + ' threads':>18}")
    for case, params, coh in [
        ("non-cohesive", {"static_friction": 0.5, "rolling_friction": 0.2, "restitution": 0.3}, False),
        ("cohesive", {"static_friction": 0.5, "rolling_friction": 0.2, "restitution": 0.3,
                      "surface_energy": 1.25}, True),
    ]:
        t_ours, s = ours(state, params, a.steps, 1)
        t_lmp, _ = lammps(state, params, a.steps, coh)
        t_par, _ = ours(state, params, a.steps, numba.config.NUMBA_NUM_THREADS)
        r_ours, r_lmp, r_par = n * a.steps / t_ours, n * a.steps / t_lmp, n * a.steps / t_par
        print(f"{case:<14}{r_ours:>14.3e}{r_lmp:>15.3e}{r_ours / r_lmp:>7.2f}{r_par:>18.3e}", flush=True)


if __name__ == "__main__":
    main()
