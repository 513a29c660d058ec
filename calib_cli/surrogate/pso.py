"""Particle-swarm optimisation (Kennedy & Eberhart), seeded and bounded.

v <- w v + c1 r1 (p_best - x) + c2 r2 (g_best - x), clamped to [-v_max, v_max];
x <- x + v, clamped to [x_min, x_max]. Paper defaults (3.5.1): swarm 10, 30 iterations,
positions in [-2, 2], velocities in [-0.5, 0.5], inertia 0.6, c1 = c2 = 2.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass
class PSOResult:
    x: np.ndarray
    f: float
    history: np.ndarray  # best value per iteration
    initial_best: float


def pso_minimize(f: Callable[[np.ndarray], float], dim: int, swarm: int = 10, iterations: int = 30,
                 x_bounds=(-2.0, 2.0), v_max: float = 0.5, inertia: float = 0.6, c1: float = 2.0, c2: float = 2.0,
                 seed: int = 0) -> PSOResult:
    rng = np.random.default_rng(seed)
    lo, hi = x_bounds
    x = rng.uniform(lo, hi, (swarm, dim))
    v = rng.uniform(-v_max, v_max, (swarm, dim))
    fx = np.array([f(xi) for xi in x])
    pbest, pf = x.copy(), fx.copy()
    g = int(np.argmin(pf))
    gbest, gf = pbest[g].copy(), float(pf[g])
    initial = gf
    hist = []
    for _ in range(iterations):
        r1, r2 = rng.random((swarm, dim)), rng.random((swarm, dim))
        v = np.clip(inertia * v + c1 * r1 * (pbest - x) + c2 * r2 * (gbest - x), -v_max, v_max)
        x = np.clip(x + v, lo, hi)
        fx = np.array([f(xi) for xi in x])
        better = fx < pf
        pbest[better], pf[better] = x[better], fx[better]
        g = int(np.argmin(pf))
        if pf[g] < gf:
            gbest, gf = pbest[g].copy(), float(pf[g])
        hist.append(gf)
    return PSOResult(gbest, gf, np.array(hist), initial)
