"""Inverting a surrogate to the measured angle(s) (paper 3.5.3, Eq. 11) and the set of
parameters that fit equally well.

Fitness is the RMSE between the predicted and target angles over the conditions (for one
condition, |prediction - target|: the paper's fitness). One angle cannot pin three
parameters, so besides the GA optimum we return the near-optimal set: every point, from a
dense seeded sample of the box plus the final populations of repeated GA runs, whose
fitness is within ``tolerance`` degrees of the best, and the range of each parameter across it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pandas as pd
from scipy.stats import qmc

from .ga import GAResult, ga_minimize


@dataclass
class Inversion:
    best: np.ndarray
    fitness: float
    ga: GAResult
    solution_set: pd.DataFrame  # parameters + fitness, sorted
    ranges: pd.DataFrame  # parameter, low, high, width_fraction
    identifiable: bool


def invert(predict: Callable[[np.ndarray], np.ndarray], names: Sequence[str], lows, highs, targets,
           generations=50, population=10, crossover=0.4, mutation=0.2, seed=0, tolerance=0.25, samples=20000,
           restarts=10, identifiable_fraction: float = 0.2) -> Inversion:
    """``predict((n, k)) -> (n, c)`` angles for c conditions; ``targets`` has length c."""
    t = np.atleast_1d(np.asarray(targets, float))
    lo, hi = np.asarray(lows, float), np.asarray(highs, float)

    def fitness(P):
        pred = np.asarray(predict(np.atleast_2d(P)), float).reshape(len(np.atleast_2d(P)), -1)
        return np.sqrt(np.mean((pred - t[None, :]) ** 2, axis=1))

    runs = [ga_minimize(fitness, lo, hi, generations, population, crossover, mutation, seed + r)
            for r in range(max(int(restarts), 1))]
    # the reported optimum is the best of the GA runs (restarts differ only in their seed): with
    # several conditions the paper's small GA (10 x 50) lands in different places
    ga = min(runs, key=lambda g: g.f)
    # each run's best joins its final population: the set must contain the optimum it reports
    pts = [g.population for g in runs] + [np.vstack([g.x for g in runs])]
    sob = qmc.Sobol(len(lo), seed=seed).random_base2(max(1, int(np.ceil(np.log2(max(int(samples), 2))))))
    pts.append(lo + sob * (hi - lo))
    P = np.vstack(pts)
    f = fitness(P)
    # near-optimal: within `tolerance` deg of the best fitness found (the best is ~0 for one
    # condition; with several conditions the measurement scatter keeps it above 0)
    keep = f <= min(float(f.min()), ga.f) + tolerance
    sset = pd.DataFrame(P[keep], columns=list(names))
    sset["fitness"] = f[keep]
    sset = sset.sort_values("fitness").reset_index(drop=True)
    rows = []
    for j, n in enumerate(names):
        col = sset[n] if len(sset) else pd.Series([ga.x[j]])
        rows.append({"parameter": n, "low": float(col.min()), "high": float(col.max()),
                     "width_fraction": float((col.max() - col.min()) / (hi[j] - lo[j]))})
    ranges = pd.DataFrame(rows)
    return Inversion(ga.x, ga.f, ga, sset, ranges, bool((ranges["width_fraction"] <= identifiable_fraction).all()))
