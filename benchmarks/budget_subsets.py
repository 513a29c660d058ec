"""How many heaps does revision 1's posterior need, and which? Re-fits the posterior of a committed sample run
(`make hidden-effect`, `make control-lab`) on subsets of the heaps it simulated, as a round of `calib calibrate`
fits its answer (the same surrogates, evidence and sampler, averaged over cohesion on and off; 6,000 steps,
three times a round's), and prints, side by side, how sure the
surrogate is where the posterior lies (the ratio of its variance to the measured means'; above 1 no verdict),
the Bayes factor of cohesion off and whether each parameter's 90 % interval holds the lab's truth.

A subset is the first N heaps revision 1's calibration simulated (its rounds in order: 72, then 24 a round),
beside the heaps revision 0 left at hand: ``full``, every one the pipeline made (its calibration's 72,
compare's 4 piles a condition, diagnose's 2 piles a condition and step), or ``lean``, what a leaner revision 0
would have made (its calibration's round 0 of 60, compare's 2 piles, diagnose's 1). Retrospective: the heaps
revision 1 chose were chosen beside the full set, so a lean pipeline run for real would place its own.

    .venv/bin/python benchmarks/budget_subsets.py --rev1 144,168,192 --at-hand full,lean --workers 2
"""
import argparse
import importlib
import tomllib
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

RUNS = ["sample_runs/hidden-effect", "sample_runs/control-lab"]


def subset(run: Path, at_hand: str, n1: int) -> set:
    """The run hashes of the first ``n1`` heaps of revision 1's calibration and the ``at_hand`` heaps."""
    res = pd.read_parquet(run / "simulate/results.parquet")
    cal = res[res.design == "calibrate"]
    rev1 = cal[cal.model == cal.model.iloc[-1]]
    other = res[~res.run_hash.isin(set(rev1.run_hash))]
    if at_hand == "lean":
        other = pd.concat([other[other.design == "calibrate"].iloc[:60],
                           other[(other.design == "compare") & (other.repeat < 2)],
                           other[other.design.str.startswith(("sens", "cand")) & (other.repeat < 1)]])
    return set(rev1.run_hash.iloc[:n1]) | set(other.run_hash)


def fit(run: str, at_hand: str, n1: int, steps: int) -> dict:
    from calib_cli.measurements import measured_conditions
    from calib_cli.model import load_model
    from calib_cli.posterior import evidence as E
    from calib_cli.stages.common import resolve_settings

    run = Path(run)
    model = load_model(run)
    keep = subset(run, at_hand, n1)
    rows = E.model_rows(run, model)
    judged = E.model_rows(run, model, judged=True)
    f = E.fit_posterior(run, model, measured_conditions(run), walkers=32, steps=steps, seed=0,
                        ranges=E.settings_ranges(resolve_settings(run, None, None)),
                        rows=rows[rows.run_hash.isin(keep)].reset_index(drop=True),
                        judged=judged[judged.run_hash.isin(keep)].reset_index(drop=True), held_out_by=(),
                        average=True)
    truth = tomllib.loads((run / "lab/truth.toml").read_text())["parameters"]
    t = f.table.set_index("parameter")
    se = t.loc["surface_energy"]
    return {"lab": run.name, "at hand": at_hand, "rev1 heaps": n1, "learnt from": f.heaps,
            "ratio": f.ratios["combined"], "decided": bool(t["decided"].iloc[0]),
            "BF off": ("< " if se["bf_upper"] else "") + f"{se['bf_off']:.3g}",
            "SE 90 %": f"{se['q05']:.2f}-{se['q95']:.2f}",
            "intervals hold truth": int(sum(r.q05 <= truth[p] <= r.q95 for p, r in t.iterrows())),
            "of": len(t), "missed": ", ".join(f"{p} {r.q05:.3g}-{r.q95:.3g} (truth {truth[p]:g})"
                                             for p, r in t.iterrows() if not r.q05 <= truth[p] <= r.q95) or "-"}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", default=",".join(RUNS))
    ap.add_argument("--rev1", default="120,144,168", help="revision 1's heaps, in the order it simulated them")
    ap.add_argument("--at-hand", default="full,lean")
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    jobs = [(r, h, int(n)) for r in a.runs.split(",") for h in a.at_hand.split(",") for n in a.rev1.split(",")]
    with ProcessPoolExecutor(a.workers) as ex:
        rows = list(ex.map(fit, *zip(*jobs), [a.steps] * len(jobs)))
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.2f}"))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
