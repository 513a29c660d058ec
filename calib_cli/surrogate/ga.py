"""A real-coded genetic algorithm for the inversion (paper 3.5.3, Eq. 11, Fig. 9).

Tournament selection, blend (arithmetic) crossover with probability ``crossover``, Gaussian
mutation (10 % of the range) with probability ``mutation`` per gene, elitism (the best
individual survives), bounds enforced by clipping. Paper defaults: 50 generations,
population 10, crossover 0.4, mutation 0.2. Deterministic for a given seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass
class GAResult:
    x: np.ndarray
    f: float
    best: np.ndarray  # best fitness per generation
    mean: np.ndarray  # mean fitness per generation
    population: np.ndarray  # final population
    fitness: np.ndarray


def ga_minimize(f: Callable[[np.ndarray], np.ndarray], lows, highs, generations: int = 50, population: int = 10,
                crossover: float = 0.4, mutation: float = 0.2, seed: int = 0, elite: int = 1) -> GAResult:
    """Minimise a vectorised fitness f((n, k) array) -> (n,) within [lows, highs]."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lows, float), np.asarray(highs, float)
    k = len(lo)
    pop = lo + rng.random((population, k)) * (hi - lo)
    fit = np.asarray(f(pop), float)
    best, mean = [], []
    for _ in range(generations):
        order = np.argsort(fit)
        elites = pop[order[:elite]].copy()

        def tournament():
            i, j = rng.integers(0, population, 2)
            return pop[i] if fit[i] <= fit[j] else pop[j]

        children = []
        while len(children) < population - elite:
            a, b = tournament(), tournament()
            if rng.random() < crossover:
                alpha = rng.random(k)
                c1, c2 = alpha * a + (1 - alpha) * b, alpha * b + (1 - alpha) * a
            else:
                c1, c2 = a.copy(), b.copy()
            for c in (c1, c2):
                m = rng.random(k) < mutation
                c[m] += rng.normal(0, 0.1, m.sum()) * (hi - lo)[m]
                children.append(np.clip(c, lo, hi))
        pop = np.vstack([elites, children[: population - elite]])
        fit = np.asarray(f(pop), float)
        best.append(float(fit.min()))
        mean.append(float(fit.mean()))
    i = int(np.argmin(fit))
    return GAResult(pop[i].copy(), float(fit[i]), np.array(best), np.array(mean), pop, fit)
