"""How many heaps would the "surrogate sure enough" bar need if every heap sat where the posterior lies? (issue 47:
the strict budget of 250 heaps.) For a committed sample run's answer, per measured condition c:

    n_c = mean over the posterior's draws theta of  sigma^2(theta, c) / v_c

sigma^2 the simulated piles' variance there (the angle's Gaussian process, its scatter model included), v_c the
measured mean's variance as the likelihood takes it. n_c piles at one point bring the surrogate's variance of
that mean to about sigma^2 / n_c = v_c, the bar (ratio 1) for the angle alone, with nothing shared between
conditions or parameter points. The sum over the conditions is the heaps a perfectly placed design would need;
beside it, the model's heaps in the prior's box now (the answer's and any simulated since, e.g. compare's) and
the surrogate's variance at the draws when it learns from all of them.

    .venv/bin/python benchmarks/heap_floor.py sample_runs/hidden-effect sample_runs/control-lab
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd


def floor(run: Path, draws: int = 256) -> tuple[pd.DataFrame, int]:
    from calib_cli.measurements import measured_conditions
    from calib_cli.model import load_model
    from calib_cli.posterior.calibrate import _inputs, mean_variance
    from calib_cli.posterior.evidence import in_box, model_rows, model_surrogate, prior_bounds, settings_ranges
    from calib_cli.stages.common import resolve_settings

    model, conds = load_model(run), measured_conditions(run)
    rows = model_rows(run, model)
    bounds = prior_bounds(model, "settings", rows, settings_ranges(resolve_settings(run, None, None)))
    rows = in_box(rows, bounds)
    gp = model_surrogate(rows, model, 0, scale=bounds)  # as the answer's fit: the heaps in the prior's box
    s = pd.read_parquet(run / "posterior/samples.parquet")
    names = [p for p in gp.parameters if p in s.columns]
    t = s[names].to_numpy(float)[np.random.default_rng(0).choice(len(s), min(draws, len(s)), replace=False)]
    C = len(conds)
    X = _inputs(gp, t, names, {}, {c: conds[c].to_numpy(float) for c in conds.columns if c in gp.inputs_}, C)
    X = X.reshape(-1, len(gp.inputs_))
    pile = gp.pile_sd(X).reshape(len(t), C) ** 2
    latent = gp.predict(X, return_std=True)[1].reshape(len(t), C) ** 2
    v = mean_variance(conds["sd"], conds["n"], gp.noise_sd_)
    return pd.DataFrame({"condition": conds["condition_id"], "lab sd": conds["sd"].round(2), "piles": conds["n"],
                         "v_c": v.round(2), "pile variance": pile.mean(0).round(1),
                         "surrogate variance now": latent.mean(0).round(2),
                         "n_c": (pile / v[None, :]).mean(0).round(1)}), len(rows)


def main() -> None:
    for run in map(Path, sys.argv[1:] or ["sample_runs/hidden-effect", "sample_runs/control-lab"]):
        table, learnt = floor(run)
        print(f"\n{run}: {learnt} heaps of the model in the prior's box; n_c summed: {table['n_c'].sum():.0f}")
        print(table.to_string(index=False))


if __name__ == "__main__":
    main()
