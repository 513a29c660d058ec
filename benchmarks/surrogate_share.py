"""What the "surrogate sure enough" bar means in the parameters' intervals: for a committed run's answer, each
parameter's 90 % width under the posterior (its likelihood carries the surrogates' covariance S) beside the same
draws resampled to the likelihood without S (the measured means' covariance alone; fitted_standin.plugin), and, for
the angle, the mean whitened variance ratio the bar reads (diag V^-1/2 S V^-1/2, V the measured means') beside the
largest eigenvalue of that matrix: the condition-space direction where the surrogate is least sure.

    .venv/bin/python benchmarks/surrogate_share.py sample_runs/hidden-effect sample_runs/control-lab
"""
from __future__ import annotations

import importlib
import sys
import warnings
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np

from fitted_standin import plugin  # this script's folder is on the path when it runs


def share(run: Path) -> None:
    from calib_cli.measurements import measured_conditions
    from calib_cli.model import load_model
    from calib_cli.posterior.calibrate import _inputs, response_variances
    from calib_cli.posterior.evidence import fit_posterior, settings_ranges
    from calib_cli.stages.common import resolve_settings

    model, conds = load_model(run), measured_conditions(run)
    fit = fit_posterior(run, model, conds, walkers=32, steps=2000, seed=0,
                        ranges=settings_ranges(resolve_settings(run, None, None)))
    s = fit.samples[[p for p in fit.samples.columns if p in fit.gp.parameters]]
    without = plugin(fit, s, conds, 0)
    for c in s.columns:
        w, w0 = (float(np.subtract(*np.quantile(d[c], [0.95, 0.05]))) for d in (s, without))
        print(f"{run} {c}: 90 % width {w:.3f}, without the surrogates' covariance {w0:.3f} ({w0 / w:.2f})")
    (_, v), *_ = response_variances(fit.gp, conds, fit.second)
    t = s.to_numpy(float)[np.random.default_rng(0).choice(len(s), min(512, len(s)), replace=False)]
    cv = {c: conds[c].to_numpy(float) for c in fit.gp.inputs_ if c not in fit.gp.parameters}
    _, S = fit.gp.predict_joint(_inputs(fit.gp, t, list(s.columns), {}, cv, len(conds)))
    M = S / np.sqrt(v)[None, :, None] / np.sqrt(v)[None, None, :]
    eig = np.linalg.eigvalsh(M)
    print(f"{run}: angle ratio {np.mean(np.diagonal(M, axis1=1, axis2=2)):.2f} (the bar's, mean diagonal), "
          f"largest eigenvalue {eig[:, -1].mean():.2f} ({np.mean(eig[:, -1] / eig.sum(1)):.2f} of the trace); "
          f"the stage's combined ratio {fit.ratios['combined']:.2f}")


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    for name in sys.argv[1:]:
        share(Path(name))
