"""How far to trust `suggest-conditions`' information gains: on stand-in labs whose true response is
known, the gain the ranking reports (the surrogate's mean at the posterior's draws, "plug-in") against
the true one, the 90 % range `gain_spread` gives it over the surrogate's own uncertainty (its joint
realisations' deviations carried onto the mean's gain), the same range read from the realisations' own
gains (not centred), and how often the candidate ranked first really teaches the most, by the chance
(``p_best_gain``) the range gives it.

Two stand-ins, each fitted with the shipped Gaussian process (calib_cli.posterior.gp.GPSurrogate) on
``--heaps`` heaps at random parameters and the measured conditions, with the posterior's draws a
Gaussian blob inside the box:
  wavy: two parameters and one condition variable, a response with bends the heaps can miss;
  heap: benchmarks/acquisition_rules.py's hidden-cohesion angle (four parameters; grain size and fill
        height), its pile scatter rising with cohesion; candidates between the measured conditions.

    python benchmarks/gain_spread.py --seeds 20 --heaps 40,120
"""
from __future__ import annotations

import argparse
import importlib
import time

importlib.import_module("calib_cli")  # pins OpenBLAS's kernels before numpy loads, as the command line does
import numpy as np
import pandas as pd

from calib_cli.posterior.gp import GPSurrogate
from calib_cli.posterior.suggest import gain_spread, information_gain

K, DRAWS = 200, 100  # realisations, and draws a candidate (as stages/suggest.py draws them)


def wavy(p: pd.DataFrame, c: pd.DataFrame) -> np.ndarray:
    a, b, x = p["a"].to_numpy(), p["b"].to_numpy(), c["x"].to_numpy()
    return 30 + 8 * a + 5 * b * (1 + x) + 3 * np.sin(4 * a * (0.5 + x)) + 2 * np.cos(3 * b + 2 * x)


def heap(p: pd.DataFrame, c: pd.DataFrame) -> np.ndarray:
    se, d, h = p["surface_energy"].to_numpy(), c["d"].to_numpy(), c["h"].to_numpy()
    return (18 + 14 * p["static_friction"].to_numpy() + 38 * p["rolling_friction"].to_numpy()
            - 3 * p["restitution"].to_numpy() + 9 * se * (4.5 / d) * (75 / h) ** 0.5 - 2 * se ** 2)


LABS = {  # response, box, scatter(params), measured conditions, candidates, posterior's centre and sd (box units)
    "wavy": (wavy, {"a": (0, 1), "b": (0, 1)}, lambda p: np.full(len(p), 2.5),
             pd.DataFrame({"x": [0.0, 0.5, 1.0]}), pd.DataFrame({"x": [0.0, 0.25, 0.5, 0.75, 1.0]}),
             {"a": 0.5, "b": 0.4}, 0.12),
    "heap": (heap, {"static_friction": (0.3, 0.7), "rolling_friction": (0.1, 0.3), "restitution": (0.1, 0.5),
                    "surface_energy": (0.0, 1.6)}, lambda p: 2 + 3 * np.minimum(p["surface_energy"].to_numpy(), 1),
             pd.DataFrame({"d": [4.0, 4.0, 4.0, 5.0, 5.0, 5.0], "h": [50.0, 75.0, 100.0] * 2}),
             pd.DataFrame({"d": np.repeat([4.0, 4.5, 5.0], 3), "h": [50.0, 75.0, 100.0] * 3}),
             {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}, 0.08),
}


def one(name: str, heaps: int, seed: int) -> pd.DataFrame:
    f, box, sd, measured, cands, centre, width = LABS[name]
    rng = np.random.default_rng(seed)
    lo, hi = (np.array([box[k][i] for k in box]) for i in (0, 1))
    P = pd.DataFrame(lo + rng.uniform(size=(heaps, len(box))) * (hi - lo), columns=list(box))
    C = measured.iloc[rng.integers(0, len(measured), heaps)].reset_index(drop=True)
    y = f(P, C) + rng.normal(0, 1, heaps) * sd(P)
    gp = GPSurrogate(list(box), list(measured.columns), box, seed=seed).fit(pd.concat([P, C], axis=1), y)
    z = rng.normal(0, width, (DRAWS, len(box)))
    D = pd.DataFrame(np.clip(np.array([centre[k] for k in box]) + z * (hi - lo), lo, hi), columns=list(box))
    u2 = np.array([[float(np.mean(sd(D))) ** 2 / 10]])  # a measured mean of 10 piles
    X = pd.concat([D.assign(**row) for row in cands.to_dict("records")])[gp.inputs_].to_numpy(float)
    mean, F = gp.sample_latent(X, K, seed=seed)
    mu, F = mean.reshape(len(cands), DRAWS), F.reshape(K, len(cands), DRAWS)
    q05, q95, p_best, regret = gain_spread(mu, F, u2, np.ones(len(cands), bool))
    truth = [information_gain(f(D, pd.DataFrame([row] * DRAWS))[:, None], u2) for row in cands.to_dict("records")]
    raw = np.array([[information_gain(F[k, j][:, None], u2) for j in range(len(cands))] for k in range(K)])
    return pd.DataFrame({"lab": name, "heaps": heaps, "seed": seed, "candidate": range(len(cands)), "true": truth,
                         "plug": [information_gain(m[:, None], u2) for m in mu], "q05": q05, "q95": q95,
                         "raw_mean": raw.mean(0), "raw_q05": np.quantile(raw, 0.05, 0),
                         "raw_q95": np.quantile(raw, 0.95, 0), "p_best": p_best,
                         "regret": regret})


def report(d: pd.DataFrame) -> None:
    rows = []
    for (lab, heaps), g in d.groupby(["lab", "heaps"], sort=False):
        leads = g.loc[g.groupby("seed")["plug"].idxmax()]
        right = [g.loc[g["seed"] == s, "true"].idxmax() == i for s, i in zip(leads["seed"], leads.index)]
        settled = leads["p_best"] >= 0.9
        lost = np.array([g.loc[g["seed"] == s, "true"].max() for s in leads["seed"]]) - leads["true"].to_numpy()
        rows.append({"lab": lab, "heaps": heaps, "cases": len(g),
                     "plug rmse": np.sqrt(np.mean((g["plug"] - g["true"]) ** 2)),
                     "plug bias": np.mean(g["plug"] - g["true"]),
                     "range holds": np.mean((g["q05"] <= g["true"]) & (g["true"] <= g["q95"])),
                     "range width": np.mean(g["q95"] - g["q05"]),
                     "raw bias": np.mean(g["raw_mean"] - g["true"]),
                     "raw holds": np.mean((g["raw_q05"] <= g["true"]) & (g["true"] <= g["raw_q95"])),
                     "first is best": np.mean(right), "mean p_best of first": leads["p_best"].mean(),
                     "settled (p>=0.9)": f"{int(settled.sum())}/{len(leads)}",
                     "settled and right": f"{int(np.sum(np.array(right) & settled.to_numpy()))}/{int(settled.sum())}",
                     "first's loss": lost.mean(), "its q90 said": leads["regret"].mean(),
                     "loss within q90": np.mean(lost <= leads["regret"].to_numpy() + 1e-12)})
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.2f}"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--heaps", default="40,120", help="heaps the surrogate learns from, comma-separated")
    ap.add_argument("--labs", default="wavy,heap")
    a = ap.parse_args()
    t0 = time.perf_counter()
    d = pd.concat([one(lab, int(n), s) for lab in a.labs.split(",") for n in a.heaps.split(",")
                   for s in range(a.seeds)], ignore_index=True)
    report(d)
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
