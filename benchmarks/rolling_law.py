"""Does EDEM's 'Standard' rolling friction (or a friction cap on the net JKR force) make the
heaps respond to rolling friction first?

The kernel's rolling torque follows the pair's relative spin (SPEC 5; Ai et al. 2011 type A,
EDEM's 'RVD' model). EDEM's default 'Standard' model brakes each body against its *own* spin,
tau_i = -mu_r F_n R_i w_i/|w_i| (help.altair.com/edem, "Standard Rolling Friction Model"), so it
also brakes grains that turn together - a cohesive cluster rolling down the heap as one body.
The paper (EDEM) finds rolling friction the strongest factor (Eq. 7: 1.90 / 5.99 / 1.12 per coded
unit for static friction, rolling friction, surface energy); the relative law gives ~1-2 for it.

This runs a 2^3 factorial at the ends of the paper's ranges for static (0.112 / 0.438) and
rolling friction (0.122 / 0.308) and two surface energies, with each rolling law
(`rolling_own_spin` 0 and 1), seeds shared between the laws, built-in kernel at the `default`
numerics, and prints each factor's coefficient per coded unit with its standard error.
`--compare friction-cap` instead caps sliding at mu_s |net normal force| (`friction_net_force` 1)
rather than at mu_s x its repulsive part (SPEC 5): at a JKR contact near zero load the net force
vanishes, so cohesive contacts slide freely - one literal reading of EDEM's JKR help.
`--compare stiffness` runs the same laws at the reduced shear modulus of the presets (5 MPa) and at
`--stiff` (default 50 MPa, particles and walls), and at 5 MPa with the surface energies scaled by
(5 MPa / stiff)^(2/5): the JKR pull-off force 3 pi g R* does not depend on the stiffness, but the
work to break a contact does (~ g^(5/3) R*^(4/3) E*^(-2/3)), and the scaled energies give the soft
grains the stiff grains' work of separation (the rule of Washino et al. 2018).
`--compare walls` gives the floor and the cylinder fixed friction coefficients (`--wall`, default
static 0.5 and rolling 0.1) instead of the particles' own (the heap parameters' default, SPEC 5):
the paper gives no particle-geometry values, and with the particles' values a heap at mu_s 0.112
stands on a floor of friction 0.112; `--which both,floor,cylinder` adds the floor alone and the
cylinder alone at those values (the other wall keeps the grains'), to tell which of the two does
it (the floor's values are heap-test variables of the rig, the cylinder's heap parameters).
`--compare spring` puts the spring-dashpot-slider rolling law (`rolling_spring` 1: Ai et al. 2011
type C, LAMMPS's `rolling sds`) beside the constant torque: it holds a static torque, so a heap
does not creep after the lift (docs/physics.md, "Rolling spring").
`--compare caps` caps sliding and rolling on |F_el + 2 F_c| (`caps_pulloff` 1; F_c = 3 pi g R*, Thornton
1991, Marshall 2009, LAMMPS's jkr) instead of SPEC 5's repulsive part and |F_el|: a cohesive contact at zero
net load then resists rolling, where SPEC 5's rolling torque vanishes there.
`--spring` runs any other comparison with every variant on the rolling spring.
`--modulus` runs any comparison but `stiffness` at another shear modulus (particles and walls).
`--design pb` runs the paper's own screening design instead of the factorial: the 12 runs of its
Table 3 at their values (static friction 0.05 / 0.5, rolling friction 0.03 / 0.4, restitution
0.1 / 0.4), with surface energy times `--g-factor` (default 0.4: Table 2's 0.5 / 2 become
0.2 / 0.8 for the 40 mm rig, about the factor between the factorial's 0.3 / 0.7 and Table 6's
0.875 / 1.625), and prints the main effects beside those of the paper's Table 3 angles. The
paper's screening has static friction backwards (-1.12 per coded unit, p 0.034, its Table 4).
`--design ascent` runs its Table 5 path and `--design bbd` its Table 7 design (the five centre runs
as one point, since the same fills give the same heap) the same way; each prints the mean
difference, RMSE and correlation of the point means against the paper's angles.

Usage:  python benchmarks/rolling_law.py [--seeds 3] [--workers 2] [--g 0.3,0.7]
        [--rig calibration|default] [--run /tmp/calib-rolling-law]
        [--compare rolling|friction-cap|stiffness|walls|spring|caps] [--spring] [--stiff 5e7] [--wall 0.5,0.1]
        [--which both,floor,cylinder] [--modulus 5e8] [--design factorial|pb|ascent|bbd] [--g-factor 0.4]
        [--only LABEL-TEXT]
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import time
from dataclasses import replace
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

from calib_cli.dem.heap import FLOOR_VARIABLES, HeapCondition, Numerics, condition_dict, get_preset
from calib_cli.heaps.inputs import heap_preset
from calib_cli.heaps.keys import Request, derive_seed
from calib_cli.heaps.runner import run_campaign
from factorial import coded_levels, effects

RIGS = {"calibration": HeapCondition(4.0, 5.0, 40.0, 75.0, 50.0), "default": get_preset("default").condition}
BASE = {"rolling_own_spin": 0.0}  # the SPEC 5 laws; the same params dict in both comparisons (shared heaps)
COMPARE = ("rolling", "friction-cap", "stiffness", "walls", "spring", "caps")
PAPER = Path(__file__).resolve().parents[1] / "sample_data" / "paper"
TABLES = {"pb": "table3_pb.csv", "ascent": "table5_ascent.csv", "bbd": "table7_bbd.csv"}
FACTORS = ["static_friction", "rolling_friction", "surface_energy", "restitution"]


def design(a) -> tuple[list[str], list[dict[str, float]], np.ndarray | None, np.ndarray | None]:
    """(the factors varied; the points' parameters; their coded levels, for main effects, or None;
    the paper's angles at the points or None) of --design. The paper's tables are simulated at
    their own values but for surface energy, times --g-factor (cohesion scales with the heap's size,
    and the 40 mm rig is much smaller than the paper's 150 mm cylinder; docs/physics.md, "Cohesion
    and heap size")."""
    if a.design == "factorial":
        g = tuple(float(v) for v in (a.g or "0.3,0.7").split(","))
        levels = {"static_friction": (0.112, 0.438), "rolling_friction": (0.122, 0.308), "surface_energy": g}
        cells = list(itertools.product((-1, 1), repeat=3))
        points = [{**{k: levels[k][(x + 1) // 2] for k, x in zip(levels, c)}, "restitution": 0.2} for c in cells]
        return list(levels), points, np.array(cells, float), None
    t = pd.read_csv(PAPER / TABLES[a.design])
    if a.design == "bbd":  # its five centre runs are one point here: the same fills give the same heap
        t = t.groupby(FACTORS, sort=False, as_index=False).repose_angle.mean()
    t = t.assign(surface_energy=t.surface_energy * a.g_factor)
    names = [k for k in FACTORS if t[k].nunique() > 1]
    coded = None if a.design == "ascent" else coded_levels(t, names)
    return names, t[FACTORS].to_dict("records"), coded, t.repose_angle.to_numpy()


def variants(a, ap) -> dict[str, tuple[dict, Numerics, float]]:
    """label -> (law parameters, numerics, factor on the surface energy levels) of --compare, each
    on the rolling spring with --spring."""
    if not a.spring:
        return _variants(a, ap)
    if a.compare in ("rolling", "spring"):
        ap.error(f"--spring sets every variant's rolling law; --compare {a.compare} compares rolling laws")
    return {f"{law}, spring": ({**p, "rolling_spring": 1.0}, num, f) for law, (p, num, f) in _variants(a, ap).items()}


def _variants(a, ap) -> dict[str, tuple[dict, Numerics, float]]:
    if a.modulus is not None and a.compare == "stiffness":
        ap.error("--modulus sets every variant's modulus; --compare stiffness sets its own")
    num = heap_preset("default", a.modulus).numerics
    if a.compare == "rolling":
        return {"relative (SPEC 5, EDEM RVD)": (BASE, num, 1.0),
                "own spin (EDEM Standard)": ({"rolling_own_spin": 1.0}, num, 1.0)}
    if a.compare == "spring":
        return {"constant torque (SPEC 5, EDEM RVD)": (BASE, num, 1.0),
                "spring-dashpot-slider (LAMMPS sds)": ({**BASE, "rolling_spring": 1.0}, num, 1.0)}
    if a.compare == "caps":
        return {"SPEC 5 caps": (BASE, num, 1.0),
                "pull-off caps (Thornton)": ({**BASE, "caps_pulloff": 1.0}, num, 1.0)}
    if a.compare == "friction-cap":
        return {"repulsive part (SPEC 5)": (BASE, num, 1.0),
                "|net force|": ({**BASE, "friction_net_force": 1.0}, num, 1.0)}
    if a.compare == "walls":
        try:
            ws, wr = (float(v) for v in a.wall.split(","))
        except ValueError:
            ap.error(f"--wall takes static,rolling friction (two numbers), got {a.wall!r}")
        which = [w.strip() for w in a.which.split(",")]
        if not which or set(which) - {"both", "floor", "cylinder"}:
            ap.error(f"--which takes both, floor, cylinder (comma-separated), got {a.which!r}")
        out = {"walls = particles (default)": (BASE, num, 1.0)}
        if "both" in which:
            out[f"walls mu_s {ws:g}, mu_r {wr:g}"] = ({**BASE, "wall_static_friction": ws,
                                                      "wall_rolling_friction": wr}, num, 1.0)
        for w in ("floor", "cylinder"):  # one wall alone: the other keeps the grains' values
            if w in which:
                out[f"{w} only {ws:g} / {wr:g}"] = ({**BASE, f"{w}_static_friction": ws, f"{w}_rolling_friction": wr},
                                                    num, 1.0)
        return out
    # stiffness: the third variant keeps the stiff material's work of separation at the soft modulus:
    # W ~ g^(5/3) E^(-2/3) is constant along g ~ E^(2/5)
    soft, f = f"G {num.shear_modulus / 1e6:g} MPa", (num.shear_modulus / a.stiff) ** 0.4
    return {soft: (BASE, num, 1.0),
            f"G {a.stiff / 1e6:g} MPa": (BASE, heap_preset("default", a.stiff).numerics, 1.0),
            f"{soft}, g x {f:.3f}": (BASE, num, f)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--g", default=None, help="surface energy low,high of --design factorial [J/m2]; default 0.3,0.7")
    ap.add_argument("--g-factor", type=float, default=0.4,
                    help="factor on the paper tables' surface energies (--design pb, ascent, bbd)")
    ap.add_argument("--rig", choices=list(RIGS), default="calibration")
    ap.add_argument("--run", default="/tmp/calib-rolling-law", help="run directory (the heaps' cache)")
    ap.add_argument("--compare", choices=COMPARE, default="rolling",
                    help="the rolling law, the normal force that caps sliding friction at a JKR contact, "
                         "the shear modulus, fixed wall friction against the grains' own, or the rolling "
                         "spring against the constant torque, or the pull-off caps against SPEC 5's")
    ap.add_argument("--stiff", type=float, default=5e7, help="shear modulus of --compare stiffness [Pa]")
    ap.add_argument("--wall", default="0.5,0.1", help="static,rolling friction of the walls for --compare walls")
    ap.add_argument("--which", default="both",
                    help="with --compare walls: the walls at --wall against the grains' values, any of both, floor "
                         "(the floor alone), cylinder (the cylinder alone), comma-separated")
    ap.add_argument("--spring", action="store_true",
                    help="every variant on the rolling spring (rolling_spring = 1), e.g. with --compare walls")
    ap.add_argument("--only", default=None,
                    help="keep only the variants whose label contains this text, e.g. `spring` to add seeds to "
                         "one law of --compare spring without re-running the other")
    ap.add_argument("--modulus", type=float, default=None,
                    help="shear modulus of every variant [Pa] (not with --compare stiffness); default the preset's")
    ap.add_argument("--design", choices=("factorial", *TABLES), default="factorial",
                    help="the 2^3 factorial over Table 6's ranges, or the runs of the paper's Table 3 (pb), "
                         "Table 5 (ascent) or Table 7 (bbd)")
    a = ap.parse_args()
    LAWS = variants(a, ap)
    if a.only is not None:
        LAWS = {k: v for k, v in LAWS.items() if a.only in k}
        if not LAWS:
            ap.error(f"--only {a.only!r} matches none of the variants of --compare {a.compare}")
    names, points, coded, paper_y = design(a)
    # by point, not by coded cell: Table 3 has one run twice (its runs 5 and 8), as the paper ran it
    todo = [(law, j, s) for law in LAWS for j in range(len(points)) for s in range(a.seeds)]
    # a variant's floor_* values are the rig's (heap-test variables), the rest heap parameters
    rig = {law: replace(RIGS[a.rig], **{k: x for k, x in v[0].items() if k in FLOOR_VARIABLES})
           for law, v in LAWS.items()}
    law_params = {law: {k: x for k, x in v[0].items() if k not in FLOOR_VARIABLES} for law, v in LAWS.items()}
    reqs = [Request(params={**{k: x * (LAWS[law][2] if k == "surface_energy" else 1.0) for k, x in points[j].items()},
                            **law_params[law]},
                    condition=rig[law], numerics=LAWS[law][1], seed=derive_seed(11, 0, s), preset="default",
                    design="rolling-law", run_id=i, repeat=s) for i, (law, j, s) in enumerate(todo)]
    fixed = {k: v for k, v in points[0].items() if k not in names}
    print(f"rig {a.rig}: {condition_dict(RIGS[a.rig])}; "
          + ", ".join(f"{k} {min(p[k] for p in points):g}-{max(p[k] for p in points):g}" for k in names)
          + "".join(f", {k} {v:g}" for k, v in fixed.items()) + f"; {a.seeds} seeds a cell (the same fills for both laws); built-in kernel, "
          f"`default` numerics, {a.workers} heaps at once; primary (image) angle")
    t0 = time.perf_counter()

    def done(req, row):
        print(f"  {todo[req.run_id][0]}: " + " ".join(f"{k} {req.params[k]:g}" for k in names)
              + f" seed {req.repeat}: {row['repose_angle']:6.2f} ({row['status']}, {row['n_particles']} grains, "
              f"{row['wall_s']:.0f} s)", flush=True)

    # the same heap asked for twice (--g 0,0; the scaled variant of a cohesionless design) runs once
    uniq = list({r.hash: r for r in reqs}.values())
    df = run_campaign(uniq, a.run, workers=a.workers, on_done=done)
    df = df.set_index("run_hash").loc[[r.hash for r in reqs]].reset_index()
    print(f"\n{len(uniq)} heaps ({len(reqs)} asked for) in {time.perf_counter() - t0:.0f} s (cached ones count 0)")
    y_all = df.repose_angle.to_numpy()
    table = {"pb": "Table 3", "ascent": "Table 5", "bbd": "Table 7"}.get(a.design)
    ref = ("the paper's Eq. 7: X1 1.90, X2 5.99, X3 1.12" if paper_y is None else
           f"the paper's {table}: " + ", ".join(f"X{i + 1} {v:.2f}" for i, v in
                                                enumerate(effects(coded, paper_y[:, None])[1]))
           if coded is not None else f"the paper's {table} path: " + ", ".join(f"{v:.1f}" for v in paper_y))
    print(f"\ncoefficients per coded unit (+- 1 SE from the seed scatter); {ref}" if coded is not None else f"\n{ref}")
    print(f"{a.compare:<28}{'mean':>7}" + ("".join(f"{'X' + str(i + 1) + ' ' + k:>26}" for i, k in enumerate(names))
                                          + f"{'seed sd':>9}" if coded is not None else ""))
    for law in LAWS:
        y = np.array([[y_all[i] for i, (lw, j2, s) in enumerate(todo) if lw == law and j2 == j]
                      for j in range(len(points))])
        if coded is not None:
            m, b, sd, se = effects(coded, y)
            print(f"{law:<28}{np.nanmean(m):7.2f}" + "".join(f"{v:19.2f} +-{se:4.2f}" for v in b) + f"{sd:9.2f}")
        else:  # a point where no seed formed a heap has no mean: NaN, left out of the comparison
            m = np.array([np.nanmean(r) if np.isfinite(r).any() else np.nan for r in y])
            print(f"{law:<28}{np.nanmean(m):7.2f}")
        print(f"{'':<28}{'':>7}  point means: " + ", ".join(f"{v:.1f}" for v in m))
        drift = df.angle_drift_deg_s.to_numpy()[[i for i, t in enumerate(todo) if t[0] == law]]
        print(f"{'':<28}{'':>7}  creep at measurement: median |drift| {np.nanmedian(np.abs(drift)):.2f} deg/s, "
              f"90th percentile {np.nanpercentile(np.abs(drift), 90):.2f}")
        if paper_y is not None:
            ok = np.isfinite(m)
            print(f"{'':<28}{'':>7}  against {table}: mean difference {np.mean(m[ok] - paper_y[ok]):+.1f} deg, "
                  f"RMSE {np.sqrt(np.mean((m[ok] - paper_y[ok])**2)):.1f}, "
                  f"correlation {np.corrcoef(m[ok], paper_y[ok])[0, 1]:.2f}")


if __name__ == "__main__":
    main()
