"""Surrogates of the simulated (or given) angle: RSM, BP and PSO-BP fitted to the response-surface
data and compared in-sample, on a seeded 80/20 split and by leave-one-out (paper 3.5.1-3.5.2)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..errors import CalibError
from ..plots import plt  # the Agg backend, set in one place
from ..posterior.gp import informative_conditions
from ..heaps.inputs import COND_VARS
from ..surrogate.metrics import leave_one_out, scores, split_80_20
from ..surrogate.models import make_model
from .common import Result, Say, check_run_dir, plain, resolve_settings, space_from_design, stage, writes_run


def _simulated_training_data(run: Path, stage: str, response: str, say: Say) -> tuple[pd.DataFrame, list[str], dict]:
    """Training data from simulations of a design crossed with conditions (`simulate-heap --conditions`):
    inputs are the design's factors plus every condition variable that varies (SPEC 6)."""
    design = run / stage / "design.parquet"
    space = space_from_design(design)
    if space is None:
        raise CalibError(f"no design at {design}")
    from ..heaps.index import current_results

    res_path = run / "simulate" / "results.parquet"
    art.read_table(res_path, what="simulation results")  # validates the file
    res = current_results(run)
    from ..model import load_model

    model = load_model(run)
    mhash = model.hash if model.revision >= 1 else ""
    sel = res[(res["design"] == stage) & (res["model"].fillna("") == mhash)]
    res = sel[sel[response].notna()]
    if res.empty:
        raise CalibError(f"no finished simulations of the {stage} design for model revision {model.revision} "
                         f"in {run}")
    lost = sel[sel[response].isna()]
    if len(lost):
        why = ", ".join(f"{k} {v}" for k, v in lost["status"].value_counts().items()) if "status" in lost else "no angle"
        gone = sorted(set(sel["run_id"].astype(int)) - set(res["run_id"].astype(int)))
        if gone:  # as `bbd analyze` refuses a design with a hole: the surface would guess that corner
            raise CalibError(f"design run(s) {', '.join(map(str, gone))} of {stage} gave no angle under any condition "
                             f"({why}; see the status column of {res_path}): the surrogate cannot see that part "
                             "of the design - narrow the factor ranges")
        say(f"[yellow]warning:[/] {len(lost)} of {len(sel)} simulations of the {stage} design gave no "
            f"angle ({why}): left out of the training data")
    keys = ["run_id", "condition_id"]
    # condition variables that carry information of their own (d_max = d_min + 1, or a fill height
    # proportional to the diameter, add nothing and would make the fit singular)
    conds = informative_conditions(res, COND_VARS)
    data = res.groupby(keys, as_index=False).agg({**{n: "first" for n in space.names}, **{c: "first" for c in conds},
                                                  response: "mean"})
    return data, space.names + conds, {"design": design, "results": art.Rows(res_path, data)}


def _training_data(run: Path, responses: Optional[Path], cfg: dict, from_simulations: Optional[str], say: Say):
    response = cfg["response"]
    if from_simulations and responses is not None:
        raise CalibError(f"fit-surrogate learns from --responses FILE or from the simulations of "
                         f"--from-simulations {from_simulations}, not both: drop one")
    if from_simulations:
        return _simulated_training_data(run, from_simulations, response, say)
    space = space_from_design(run / "bbd" / "design.parquet")
    names = space.names if space is not None else (list(cfg["bbd"]["factors"]) or
                                                   [n for n in cfg["pb"]["factors"] if n != "restitution"])
    if responses is not None:
        return art.read_responses(responses, names, response, warn=say), names, {"responses": responses}
    path = run / "bbd" / "data.parquet"
    if not path.is_file():
        raise CalibError(f"no response-surface data in {run}: run `calib bbd analyze --run {run}` first, "
                         f"or pass --responses FILE")
    return art.read_table(path, columns=[*names, response], what="BBD data"), names, {"data": path}


def _fit_plot(y: np.ndarray, preds: pd.DataFrame, models: list[str]):
    """Predicted against actual angle, in-sample and held out."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    lim = [y.min() - 2, y.max() + 2]
    for ax, kind in zip(axes, ("fit", "loo")):
        for name in models:
            ax.plot(y, preds[f"{name}_{kind}"], "o", label=name, alpha=0.8)
        ax.plot(lim, lim, "k--", lw=1)
        ax.set_xlim(lim)
        ax.set_ylim(lim)
        ax.set_xlabel("actual angle [deg]")
        ax.set_ylabel("predicted angle [deg]")
        ax.set_title("in-sample" if kind == "fit" else "leave-one-out (held out)")
        ax.legend()
    return fig


@dataclass
class FitResult(Result):
    """RUN/surrogate/: ``metrics`` (model, split, r2, mse, aad) and the ``best`` model on held-out data."""

    metrics: Optional[pd.DataFrame] = None
    best: str = ""
    n_samples: int = 0

    def __post_init__(self):
        if self.metrics is None and (self.dir / "metrics.parquet").is_file():
            self.metrics = art.read_table(self.dir / "metrics.parquet")
            self.best = art.read_json(self.dir / "best.json")["best"]

    def summary(self) -> pd.DataFrame:
        """R2 by model and split."""
        return self.metrics.pivot(index="model", columns="split", values="r2").reset_index()


@writes_run
def fit_surrogate(run: Path, responses: Optional[Path] = None, from_simulations: Optional[str] = None,
                  settings: Optional[Path] = None, setting: Optional[list[str]] = None, force: bool = False,
                  say: Optional[Say] = None) -> FitResult:
    """Fit the surrogates of settings ``surrogate.models`` to RUN/bbd/data.parquet (or ``responses``, or
    the simulations of the design ``from_simulations`` with the condition variables that vary as inputs).
    Writes RUN/surrogate/metrics.parquet, predictions.parquet, models/<model>.json, best.json and
    predicted_vs_actual.png."""
    say = say or plain
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    sc = cfg["surrogate"]
    data, names, inputs = _training_data(run, responses, cfg, from_simulations, say)
    st = stage(run, "surrogate", "fit", inputs=inputs, settings={"surrogate": sc, "inputs": names})
    if st.up_to_date() and not force:  # the training rows are at hand: their count, not 0
        return FitResult(st, True, n_samples=len(data))
    X, y = data[names].to_numpy(float), data[cfg["response"]].to_numpy(float)
    if len(y) < 8:
        raise CalibError(f"{len(y)} samples are too few for the surrogates (a quadratic in 3 factors has 10 terms)")
    tr, te = split_80_20(len(y), int(sc["seed"]))
    rows, preds, states = [], pd.DataFrame({"sample": np.arange(1, len(y) + 1), "actual": y,
                                            "in_test_split": np.isin(np.arange(len(y)), te)}), {}

    def make(name):
        return lambda: make_model(name, names, int(sc["seed"]), int(sc["hidden"]), int(sc["epochs"]))

    for name in sc["models"]:
        m = make(name)().fit(X, y)
        states[name] = m.to_state()
        yin = m.predict(X)
        yloo = leave_one_out(make(name), X, y)
        msplit = make(name)().fit(X[tr], y[tr])
        rows += [{"model": name, "split": "train", **scores(y, yin)},
                 {"model": name, "split": "split_train", **scores(y[tr], msplit.predict(X[tr]))},
                 {"model": name, "split": "split_test", **scores(y[te], msplit.predict(X[te]))},
                 {"model": name, "split": "loo", **scores(y, yloo)}]
        preds[f"{name}_fit"] = yin
        preds[f"{name}_loo"] = yloo
    metrics = pd.DataFrame(rows)
    loo = metrics[metrics["split"] == "loo"].set_index("model")
    best = str(loo["mse"].idxmin())
    fig = _fit_plot(y, preds, sc["models"])
    with st.commit() as out:
        out.table("metrics.parquet", metrics)
        out.table("predictions.parquet", preds)
        for name, state in states.items():
            out.text(f"models/{name}.json", json.dumps(state))
        out.text("best.json", json.dumps({"best": best, "criterion": "leave-one-out MSE", "inputs": names,
                                          "lows": X.min(0).tolist(), "highs": X.max(0).tolist()}))
        out.figure("predicted_vs_actual.png", fig)
    return FitResult(st, False, metrics, best, len(y))
