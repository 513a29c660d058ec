"""Which number of a heap's silhouette a surrogate learns best beside the angle: fullness (the area above
15 % of the height over the triangle's) against the band fullness (the area between 15 and 85 % over
the trapezoid's, which reads a flat top as straight flanks), side by side on the same heaps.

For every heap of a run directory whose side view is kept (RUN/simulate/runs/<hash>/side.png), both
responses are measured on the side view's profile by the image code the photographs go through; a
Gaussian process over the model's parameters and the conditions is scored on held-out folds (5-fold over
the design points) for each. Prints, per response: the heaps, the spread of the response over them
(sd), the GP's held-out RMSE and its white noise (a pile's own scatter), the held-out R^2 (1 - RMSE^2 /
variance), and the lab's photographs' mean and sd per condition.

    python benchmarks/profile_responses.py runs/he-cal2
"""
from __future__ import annotations

import argparse
import importlib
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

from calib_cli.heaps.inputs import COND_VARS
from calib_cli.heaps.keys import RUNS
from calib_cli.imaging.measure import measure_image, read_image
from calib_cli.model import load_model
from calib_cli.posterior.evidence import model_rows
from calib_cli.posterior.gp import holdout_rmse
from calib_cli.profile import band_fullness, fullness

RESPONSES = {"fullness": fullness, "band_fullness": band_fullness}


def side_view_responses(run: Path, rows: pd.DataFrame) -> pd.DataFrame:
    out = {k: np.full(len(rows), np.nan) for k in RESPONSES}
    for i, h in enumerate(rows["run_hash"]):
        side = run / RUNS / str(h) / "side.png"
        if not side.is_file():
            continue
        res = measure_image(read_image(side), limits=None)
        if res.status == "ok":
            for k, f in RESPONSES.items():
                out[k][i] = f(res.profile_s, res.profile_h)
    return rows.assign(**out)


def lab_responses(run: Path) -> pd.DataFrame:
    prof = pd.read_parquet(run / "measure" / "profiles.parquet")
    return pd.DataFrame([{"condition_id": g["condition_id"].iloc[0],
                          **{k: f(g["s_px"].to_numpy(), g["h_px"].to_numpy()) for k, f in RESPONSES.items()}}
                         for _, g in prof.groupby("image")])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    a = ap.parse_args()
    model = load_model(a.run)
    rows = side_view_responses(a.run, model_rows(a.run, model))
    params = model.parameters
    bounds = {p: (float(rows[p].min()), float(rows[p].max())) for p in params}
    out = []
    for k in RESPONSES:
        ok = rows[np.isfinite(rows[k])]
        conds = [c for c in COND_VARS if c in ok.columns]
        cv = holdout_rmse(ok[[*params, *conds, k]], params, conds, bounds, k, which=("gp",)).iloc[0]
        out.append({"response": k, "heaps": len(ok), "sd": ok[k].std(), "heldout_rmse": cv["rmse"],
                    "pile_noise": cv["noise_sd"], "heldout_r2": 1 - cv["rmse"] ** 2 / ok[k].var()})
    print(pd.DataFrame(out).to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    lab = lab_responses(a.run)
    print("\nthe lab's photographs, per condition (mean, sd):")
    print(lab.groupby("condition_id")[list(RESPONSES)].agg(["mean", "std"]).to_string(float_format=lambda v: f"{v:.3f}"))
    print("\ncorrelation of the two over the heaps:", f"{rows[list(RESPONSES)].corr().iloc[0, 1]:.3f}")


if __name__ == "__main__":
    main()
