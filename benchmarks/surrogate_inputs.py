"""Does the angle's Gaussian process learn more per heap when surface energy enters it as the heap's
slope stability number? Retrospective, on the committed sample runs' heaps; nothing is simulated.

docs/physics.md ("Validity", benchmarks/cohesion_scaling.py) found a heap's angle to follow surface
energy over heap size: cohesive stress g / d against the weight's rho g H. So a heap at fill height H
of d-mm grains at surface energy g should look like one at H' and d' at g H' d' / (H d). Fed that
product instead of g (``stability``: g x 75 / H x 5 / d, d the grains' mean size), the process could
share what one condition's heaps teach with the others. ``inverse`` warps the other way (g x H / 75 x
d / 5): a control, which physics says should not help.

Prints per run and warp, side by side: the process's 5-fold held-out RMSE per pile over design points
(``--seeds`` fold seeds; the library's own cross-validation, `gp.holdout_rmse`), its log marginal
likelihood on every heap (higher: the data favour the inputs), its length scales, and ``ratio``: fitted on every heap, its variance at the committed answer's
draws over the measured means' (the angle's share of the bar under which a verdict is stated; lower: the
same heaps would decide sooner).

    .venv/bin/python benchmarks/surrogate_inputs.py --runs sample_runs/hidden-effect,sample_runs/control-lab
"""
from __future__ import annotations

import argparse
import importlib
import warnings
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

from calib_cli.measurements import measured_conditions
from calib_cli.model import load_model
from calib_cli.posterior import evidence as E
from calib_cli.posterior import gp as G
from calib_cli.stages.common import resolve_settings

WARPS = ("none", "stability", "inverse")
_plain = G.GPSurrogate._scale


def warped(warp: str):
    """GPSurrogate._scale with surface energy multiplied by (75 / H)(5 / d) (``stability``) or its inverse."""
    def _scale(self, X):
        if isinstance(X, pd.DataFrame):
            X = X[self.inputs_].to_numpy(float)
        X = np.array(np.atleast_2d(np.asarray(X, float)), copy=True)
        if warp != "none" and "surface_energy" in self.inputs_:
            f = np.ones(len(X))
            if "fill_height_mm" in self.inputs_:
                f *= 75.0 / X[:, self.inputs_.index("fill_height_mm")]
            if "particle_d_min_mm" in self.inputs_:
                f *= 5.0 / (X[:, self.inputs_.index("particle_d_min_mm")] + 0.5)
            s = self.inputs_.index("surface_energy")
            X[:, s] *= f if warp == "stability" else 1.0 / f
        return (X - self.lows_) / (self.highs_ - self.lows_)
    return _scale


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", default="sample_runs/hidden-effect,sample_runs/control-lab")
    ap.add_argument("--seeds", type=int, default=3)
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    out = []
    for run in map(Path, a.runs.split(",")):
        model = load_model(run)
        rows = E.model_rows(run, model)
        bounds = E.prior_bounds(model, "settings", rows, E.settings_ranges(resolve_settings(run, None, None)))
        rows = E.in_box(rows, bounds)
        rows = rows[np.isfinite(rows["repose_angle"].to_numpy(float))].reset_index(drop=True)
        conds = [c for c in E.COND_VARS if c in rows.columns]
        measured, samples = measured_conditions(run), pd.read_parquet(run / "posterior" / "samples.parquet")
        for warp in WARPS:
            G.GPSurrogate._scale = warped(warp)
            try:
                cv = [float(G.holdout_rmse(rows, model.parameters, conds, bounds, seed=s, which=("gp",))["rmse"].iloc[0])
                      for s in range(a.seeds)]
                g = E.model_surrogate(rows, model, 0, scale=bounds)
                ratio = E.surrogate_ratios(g, None, measured, samples)[E.RESPONSE]
            finally:
                G.GPSurrogate._scale = _plain
            out.append({"run": run.name, "warp": warp, "heaps": len(rows),
                        "rmse": np.mean(cv), "rmse_seeds": " ".join(f"{c:.2f}" for c in cv), "log_ml": g.gp_.log_marginal_likelihood_value_, "ratio": ratio,
                        "length_scales": " ".join(f"{v:.2g}" for v in g.length_scales_)})
            print(out[-1], flush=True)
    df = pd.DataFrame(out)
    print(f"\nlength scales in the order {', '.join(g.inputs_)}")
    print(df.to_string(index=False, float_format=lambda v: f"{v:.3f}"))


if __name__ == "__main__":
    main()
