"""Simulated sensitivities of the angle per condition: to each calibrated parameter (J) and to each
candidate effect's parameter (G, with its standard error), heaps simulated at the calibrated point and at
steps from it (docs/method.md, 'The discrepancy loop'). diagnose ranks the candidates by them,
suggest-conditions picks the conditions that tell them apart."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import pandas as pd

from ..model import EFFECTS, Model
from .point import simulate_at
from .stats import difference_se


def signatures(run: Path, model: Model, theta: dict, conds: pd.DataFrame, preset: str, repeats: int, workers: int,
               shear_modulus: Optional[float], cands: Optional[list[str]] = None, seeds: str = "table"):
    """Simulated sensitivities: J (angle per unit of each calibrated parameter, per condition), G (per
    unit of each candidate effect's parameter; every one the model lacks, or ``cands``) with its
    standard error, and each candidate's start; each step's heaps seeded as its base's (common random
    numbers), by ``seeds`` (:data:`~calib_cli.discrepancy.point.SEEDINGS`)."""
    cands = model.candidates if cands is None else cands
    base, _ = simulate_at(run, model, theta, conds, preset, repeats, workers, "compare", shear_modulus=shear_modulus,
                          seeds=seeds)
    b = base["mean"].to_numpy()
    J, G = [], {}
    for e in model.effects:
        eff = EFFECTS[e]
        h = eff.step if theta[eff.parameter] + eff.step <= eff.high else -eff.step
        sim, _ = simulate_at(run, model, {**theta, eff.parameter: theta[eff.parameter] + h}, conds, preset, repeats,
                             workers, f"sens-{e}", shear_modulus=shear_modulus, seeds=seeds)
        J.append((sim["mean"].to_numpy() - b) / h)
    starts, G_se = {}, {}
    for e in cands:
        eff = EFFECTS[e]
        down, up = eff.probe(theta)
        starts[e] = eff.start(theta)
        m2 = Model((*model.effects, e), model.revision)
        sim, _ = simulate_at(run, m2, {**theta, eff.parameter: up}, conds, preset, repeats, workers, f"cand-{e}",
                             shear_modulus=shear_modulus, seeds=seeds)
        if eff.two_sided:  # a central difference (Effect.probe): both ends simulated
            dn, _ = simulate_at(run, m2, {**theta, eff.parameter: down}, conds, preset, repeats, workers,
                                f"cand-{e}-down", shear_modulus=shear_modulus, seeds=seeds)
            G[e] = (sim["mean"].to_numpy() - dn["mean"].to_numpy()) / (up - down)
            G_se[e] = difference_se(sim, dn, up - down)
        else:  # a forward step from neutral: the model's own simulations stand there
            G[e] = (sim["mean"].to_numpy() - b) / eff.step
            G_se[e] = difference_se(sim, base, eff.step)
    return b, J, G, G_se, starts
