"""`calib fit-surrogate`, `calib predict`, `calib invert`: thin wrappers over calib_cli.surrogate."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import typer  # noqa: E402

from .. import artifacts as art  # noqa: E402
from ..campaign import Request, derive_seed, run_campaign  # noqa: E402
from ..dem.heap import CONDITION_VARIABLES, PARAMETERS  # noqa: E402
from ..errors import CalibError  # noqa: E402
from ..discrepancy.stats import at_bounds, per_condition, residual_table  # noqa: E402
from ..surrogate.inversion import invert as invert_surrogate  # noqa: E402
from ..surrogate.inversion import nearest, refine as refine_by_simulation  # noqa: E402
from ..surrogate.metrics import leave_one_out, scores, split_80_20  # noqa: E402
from ..surrogate.models import make_model, model_from_state  # noqa: E402
from .common import (ForceOpt, ResponsesOpt, RunOpt, SettingOpt, SettingsOpt, ShearModulusOpt, bbd_fixed,  # noqa: E402
                     check_run_dir, console, df_table, heap_preset, heap_setup, modulus_settings, resolve_settings, skipped,
                     space_from_design, warn_other_modulus)
from .simulate_cmd import _condition, _pairs, _params, condition_from_row  # noqa: E402

MODELS_DIR = Path("surrogate") / "models"


COND_VARS = list(CONDITION_VARIABLES)


def _simulated_training_data(run: Path, stage: str, response: str) -> tuple[pd.DataFrame, list[str], dict]:
    """Training data from simulations of a design crossed with conditions (`simulate-heap --conditions`):
    inputs are the design's factors plus every condition variable that varies (SPEC 6)."""
    design = run / stage / "design.parquet"
    space = space_from_design(design)
    if space is None:
        raise CalibError(f"no design at {design}")
    from ..campaign import current_results

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
        console.print(f"[yellow]warning:[/] {len(lost)} of {len(sel)} simulations of the {stage} design gave no "
                      f"angle ({why}): left out of the training data")
    keys = ["run_id", "condition_id"]
    # condition variables that carry information of their own (d_max = d_min + 1, or a fill height
    # proportional to the diameter, add nothing and would make the fit singular)
    conds, basis = [], np.ones((len(res), 1))
    for c in COND_VARS:
        if c in res.columns and res[c].nunique() > 1:
            trial = np.column_stack([basis, res[c].to_numpy(float)])
            if np.linalg.matrix_rank(trial) > basis.shape[1]:
                conds.append(c)
                basis = trial
    data = res.groupby(keys, as_index=False).agg({**{n: "first" for n in space.names}, **{c: "first" for c in conds},
                                                  response: "mean"})
    return data, space.names + conds, {"design": design, "results": art.Rows(res_path, data)}


def _training_data(run: Path, responses: Optional[Path], cfg: dict, from_simulations: Optional[str] = None):
    response = cfg["response"]
    if from_simulations:
        return _simulated_training_data(run, from_simulations, response)
    space = space_from_design(run / "bbd" / "design.parquet")
    names = space.names if space is not None else (list(cfg["bbd"]["factors"]) or
                                                   [n for n in cfg["pb"]["factors"] if n != "restitution"])
    if responses is not None:
        return art.read_responses(responses, names, response), names, {"responses": responses}
    path = run / "bbd" / "data.parquet"
    if not path.is_file():
        raise CalibError(f"no response-surface data in {run}: run `calib bbd analyze --run {run}` first, "
                         f"or pass --responses FILE")
    return art.read_table(path, columns=[*names, response], what="BBD data"), names, {"data": path}


def fit_surrogate(run: RunOpt, responses: ResponsesOpt = None,
                  from_simulations: Annotated[Optional[str], typer.Option(
                      "--from-simulations", help="Train on the simulations of this design stage (e.g. bbd), "
                      "with the condition variables that vary as extra inputs (several conditions at once).")] = None,
                  settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Fit RSM, BP and PSO-BP surrogates; compare them in-sample, on a seeded 80/20 split and by
    leave-one-out (paper 3.5.1-3.5.2, Table 9).

    Reads RUN/bbd/data.parquet (from `bbd analyze`) or --responses FILE. Writes
    RUN/surrogate/metrics.parquet (model, split, r2, mse, aad), predictions.parquet,
    models/<model>.json, best.json and predicted_vs_actual.png.
    """
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    sc = cfg["surrogate"]
    data, names, inputs = _training_data(run, responses, cfg, from_simulations)
    st = art.Stage(run, "surrogate", "fit", inputs=inputs, settings={"surrogate": sc, "inputs": names})
    if st.up_to_date() and not force:
        return skipped(st)
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
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    lim = [y.min() - 2, y.max() + 2]
    for ax, kind in zip(axes, ("fit", "loo")):
        for name in sc["models"]:
            ax.plot(y, preds[f"{name}_{kind}"], "o", label=name, alpha=0.8)
        ax.plot(lim, lim, "k--", lw=1)
        ax.set_xlim(lim)
        ax.set_ylim(lim)
        ax.set_xlabel("actual angle [deg]")
        ax.set_ylabel("predicted angle [deg]")
        ax.set_title("in-sample" if kind == "fit" else "leave-one-out (held out)")
        ax.legend()
    with st.commit() as out:
        out.table("metrics.parquet", metrics)
        out.table("predictions.parquet", preds)
        for name, state in states.items():
            out.text(f"models/{name}.json", json.dumps(state))
        out.text("best.json", json.dumps({"best": best, "criterion": "leave-one-out MSE", "inputs": names,
                                          "lows": X.min(0).tolist(), "highs": X.max(0).tolist()}))
        out.figure("predicted_vs_actual.png", fig)
    console.print(df_table(metrics.pivot(index="model", columns="split", values="r2").reset_index(),
                           "R2 by model and split (cf. paper Table 9, which reports in-sample fits)"))
    console.print(df_table(metrics[metrics["split"].isin(["train", "loo"])],
                           "In-sample and leave-one-out metrics (Eqs. 8-10)"))
    console.print(f"[bold]Best on held-out data (leave-one-out MSE): {best}[/] "
                  f"(R2 {loo.loc[best, 'r2']:.4f}, MSE {loo.loc[best, 'mse']:.4f}). With {len(y)} samples the "
                  f"held-out comparison is the honest one; in-sample fits reward flexibility.")


def _load_models(run: Path, model: Optional[str]) -> tuple[dict, dict]:
    best_path = run / "surrogate" / "best.json"
    if not best_path.is_file():
        raise CalibError(f"no fitted surrogate in {run}: run `calib fit-surrogate --run {run}` first")
    best = art.read_json(best_path)
    names = [model] if model else [p.stem for p in sorted((run / MODELS_DIR).glob("*.json"))]
    models = {}
    for n in names:
        p = run / MODELS_DIR / f"{n}.json"
        if not p.is_file():
            raise CalibError(f"surrogate {n!r} was not fitted in {run} (have: "
                             f"{', '.join(q.stem for q in (run / MODELS_DIR).glob('*.json'))})")
        models[n] = model_from_state(art.read_json(p))
    return models, best


ModelOpt = Annotated[Optional[str], typer.Option("--model", help="rsm | bp | pso-bp (default: all for predict, "
                                                 "the best on held-out data for invert).")]


def predict(run: RunOpt, set_: Annotated[Optional[list[str]], typer.Option("--set", help="KEY=VALUE for every "
            "surrogate input (repeatable).")] = None, model: ModelOpt = None):
    """Evaluate the saved surrogate(s) at a point. Reads RUN/surrogate/models/*.json."""
    run = check_run_dir(run)
    models, best = _load_models(run, model)
    vals = _params(_pairs(set_, "--set")) if set_ else {}
    names = best["inputs"]
    missing = [n for n in names if n not in vals]
    if missing:
        raise CalibError(f"give a value for {', '.join(missing)} (--set NAME=VALUE)")
    x = np.array([[vals[n] for n in names]])
    for n, lo, hi in zip(names, best["lows"], best["highs"]):
        if not lo <= vals[n] <= hi:
            console.print(f"[yellow]warning:[/] {n} = {vals[n]:g} is outside the fitted range [{lo:g}, {hi:g}]: "
                          "extrapolating")
    for name, m in models.items():
        console.print(f"{name:7s} {float(m.predict(x)[0]):.2f} deg")


def invert(
    run: RunOpt,
    target: Annotated[Optional[float], typer.Option(help="Target angle (deg); default: the measured conditions "
                                                    "(RUN/measure/conditions.parquet), else settings target.")] = None,
    model: ModelOpt = None,
    validate: Annotated[int, typer.Option(min=0, help="Simulations at the solution, each with its own seed "
                                          "(paper 3.6: five), on the measured rig: N per measured "
                                          "condition, or the preset's rig with --condition.")] = 0,
    preset: Annotated[Optional[str], typer.Option(help="Preset of the validation simulations. Default: the run's "
                      "setting heap.preset, else default.", show_default=False)] = None,
    shear_modulus: ShearModulusOpt = None,
    condition: Annotated[Optional[list[str]], typer.Option("--condition", help="Heap-test variable of the "
                         "validation runs, KEY=VALUE (repeatable); given, the validation runs on the preset's "
                         "rig with these changes instead of the measured conditions.")] = None,
    workers: Annotated[int, typer.Option(min=1, help="Parallel validation runs.")] = 1,
    refine: Annotated[Optional[int], typer.Option(min=0, help="With --validate: at most this many corrections "
                      "when the validation misses the targets by more than invert.refine_z combined sd (rms z): its error "
                      "there is added to the surrogate, which is inverted again nearest the last point (output space "
                      "mapping). Default: settings invert.refine.")] = None,
    settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False,
):
    """GA inversion of the surrogate to the target angle within the fitted ranges (paper Eq. 11, Fig. 9),
    the set of near-optimal parameters, and optional validation simulations (paper 3.6), optionally
    refined where the validation shows the surrogate wrong. Warns when the solution sits on the edge
    of the range the surrogate was fitted on.

    Reads RUN/surrogate/. Writes RUN/invert/solution.parquet, history.parquet, solution_set.parquet,
    ranges.parquet, fitness.png and, with --validate, validation.parquet (and with --refine, refinement.parquet).
    """
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    iv = cfg["invert"]
    preset, shear_modulus = heap_setup(cfg, preset, shear_modulus)
    models, best = _load_models(run, model)
    name = model or best["best"]
    m = models[name]
    names = best["inputs"]
    cond_path = run / "measure" / "conditions.parquet"
    if target is not None:
        targets, tsource = [float(target)], "--target"
    elif cond_path.is_file():
        c = art.read_table(cond_path, columns=["condition_id", "mean"], what="measured conditions")
        targets, tsource = c["mean"].astype(float).tolist(), f"{cond_path} ({len(c)} condition(s))"
    else:
        targets, tsource = [float(cfg["target"])], "settings target"
    if not all(np.isfinite(targets)) or not all(0 < t < 90 for t in targets):
        raise CalibError(f"target angles must lie in (0, 90) deg, got {targets}")
    n_refine = int(iv["refine"] if refine is None else refine)
    if n_refine and not validate:
        raise CalibError("--refine corrects the inversion from validation heaps: give --validate N too")
    inputs = {"model": run / MODELS_DIR / f"{name}.json"}
    if cond_path.is_file() and (target is None or (validate and not condition)):
        inputs["conditions"] = cond_path  # the targets, or the rig of the validation runs
    st = art.Stage(run, "invert", "solve", inputs=inputs,
                   settings={"invert": {**iv, "refine": n_refine}, "targets": targets, "model": name, "validate": validate,
                             "preset": preset,
                             **modulus_settings(shear_modulus),
                             "condition": sorted(condition or [])})
    if st.up_to_date() and not force:
        return skipped(st)
    params = [n for n in names if n not in COND_VARS]
    cvars = [n for n in names if n in COND_VARS]
    lows = [lo for n, lo in zip(names, best["lows"]) if n in params]
    highs = [hi for n, hi in zip(names, best["highs"]) if n in params]
    if cvars:
        # a surrogate over parameters and condition variables: predict every measured condition
        if target is not None or not cond_path.is_file():
            raise CalibError("this surrogate takes condition variables: invert it against the measured conditions "
                             f"({cond_path}), not a single --target")
        ctab = art.read_table(cond_path, columns=["condition_id", "mean", *cvars], what="measured conditions")
        cx = ctab[cvars].to_numpy(float)

        def predict_all(P):
            P = np.atleast_2d(P)
            full = np.hstack([np.repeat(P, len(cx), axis=0), np.tile(cx, (len(P), 1))])
            return m.predict(full).reshape(len(P), len(cx))
    else:
        # one condition (or a surrogate without condition inputs): the same prediction for every target
        def predict_all(P):
            return np.repeat(m.predict(np.atleast_2d(P))[:, None], len(targets), axis=1)
    def solve(predict):
        return invert_surrogate(predict, params, lows, highs, targets, int(iv["generations"]), int(iv["population"]),
                                float(iv["crossover"]), float(iv["mutation"]), int(iv["seed"]),
                                float(iv["tolerance"]), int(iv["samples"]), int(iv["restarts"]))

    res = solve(predict_all)
    hist = pd.DataFrame({"generation": np.arange(1, len(res.ga.best) + 1), "best": res.ga.best, "mean": res.ga.mean})
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(hist["generation"], hist["best"], label="best")
    ax.plot(hist["generation"], hist["mean"], label="mean", alpha=0.7)
    ax.set_yscale("log")
    ax.set_xlabel("generation")
    ax.set_ylabel("fitness: RMSE to target [deg]")
    ax.set_title(f"GA inversion of the {name} surrogate (cf. paper Fig. 9)")
    ax.legend()
    best_x, validation, refinement, chosen = res.best, None, None, 0
    if validate:
        pre = heap_preset(preset, shear_modulus)
        warn_other_modulus(run, shear_modulus, "the validation's")
        vtargets: dict[str, float] = {}  # each measured condition's own target, when it is one
        vtab = None
        if condition or not cond_path.is_file():
            vconds = [("", _condition(pre.condition, _pairs(condition, "condition")))]
        else:
            # the rig the heaps were measured on, not the preset's: a validation elsewhere validates nothing
            vtab = art.read_table(cond_path, columns=["condition_id", "mean", "sd", "n"], what="measured conditions")
            vconds = [(str(row["condition_id"]), condition_from_row(pre.condition, row)) for _, row in vtab.iterrows()]
            if target is None:
                vtargets = dict(zip(vtab["condition_id"].astype(str), vtab["mean"].astype(float)))
        if n_refine and len(vconds) != len(targets):
            raise CalibError(f"--refine compares each validation condition with its own target: {len(vconds)} "
                             f"validation condition(s) but {len(targets)} target(s) (drop --target)")
        fixed = bbd_fixed(run, cfg)
        rounds: list[pd.DataFrame] = []

        def simulate_round(x, k):
            vparams = {**fixed, **{n: float(v) for n, v in zip(params, x) if n in PARAMETERS}}
            # round 0 keeps the seeds of a plain --validate (one condition keeps run index 0); each
            # correction round draws fresh ones
            reqs = [Request(vparams, c, pre.numerics, derive_seed(int(iv["seed"]), i if len(vconds) > 1 else 0,
                                                                  r + k * validate),
                            preset, "validate", i, r + k * validate, condition_id=cid)
                    for i, (cid, c) in enumerate(vconds, start=1) for r in range(validate)]
            rows = run_campaign(reqs, run, workers).copy()
            rows.insert(0, "round", k)
            rounds.append(rows)
            ids = [cid for cid, _ in vconds]
            sim = per_condition(rows, ids)
            if vtab is not None and target is None:
                m = vtab.set_index(vtab["condition_id"].astype(str)).reindex(ids)
                mm, ms, mn = m["mean"], m["sd"], m["n"]
            else:  # a bare target angle: no measured scatter to add
                mm, ms, mn = np.full(len(ids), float(np.mean(targets))), np.full(len(ids), np.nan), np.zeros(len(ids))
            rt = residual_table(mm, ms, mn, sim["mean"], sim["sd"], sim["n"])
            return pd.concat([pd.DataFrame({"condition_id": ids}), sim.reset_index(drop=True), rt], axis=1)

        def reinvert(bias, x):
            again = solve(lambda P: predict_all(P) + bias[None, :])
            return nearest(again.solution_set, params, lows, highs, x)

        # a move under 1 % of every parameter's range shifts the angles by ~0.1 deg at the BBD's steepest
        # slopes (~6 deg per half range), far inside a validation mean's scatter: re-measuring it only
        # draws again (seen: a point moved by 0.0002 simulated a third time)
        xtol = 0.01 * (np.asarray(highs, float) - np.asarray(lows, float))
        ref = refine_by_simulation(predict_all, simulate_round, reinvert, res.best, targets, params, n_refine,
                                   float(iv["refine_z"]), xtol=xtol)
        best_x, chosen = ref.best, ref.best_round
        validation = pd.concat(rounds, ignore_index=True)[["round", "condition_id", "repeat", "seed", "status",
                                                           "repose_angle", "angle_coords", "angle_image", "wall_s"]]
        if n_refine:
            refinement = ref.rounds
    preds = predict_all(best_x[None, :])[0]
    pred = float(np.mean(preds))
    fit_at = float(np.sqrt(np.mean((preds - np.asarray(targets, float)) ** 2)))
    sol = pd.DataFrame([{**dict(zip(params, best_x.tolist())), "predicted_angle": pred, "fitness": fit_at,
                         "model": name, "target": float(np.mean(targets))}])
    per_cond = pd.DataFrame({"target": targets, "predicted_angle": preds})
    with st.commit() as out:
        out.table("solution.parquet", sol, targets=targets, target_source=tsource, refine_round=chosen)
        out.table("predicted_conditions.parquet", per_cond)
        out.table("history.parquet", hist)
        out.table("solution_set.parquet", res.solution_set, tolerance=float(iv["tolerance"]))
        out.table("ranges.parquet", res.ranges)
        out.figure("fitness.png", fig)
        if validation is not None:
            out.table("validation.parquet", validation)
        if refinement is not None:
            out.table("refinement.parquet", refinement, accepted=bool(ref.accepted), chosen_round=chosen,
                      stalled=bool(ref.stalled))
    title = "GA optimum" if chosen == 0 else f"Solution of refinement round {chosen}"
    console.print(df_table(sol, f"{title} (targets from {tsource})"))
    if len(targets) > 1:
        console.print(df_table(per_cond, "per condition: measured target and predicted angle at the optimum"))
    console.print(df_table(res.ranges, f"Near-optimal set: {len(res.solution_set)} points within "
                                       f"{float(iv['tolerance']):g} deg of the best fitness"))
    if not res.identifiable:
        wide = res.ranges.loc[res.ranges["width_fraction"] > 0.2, "parameter"].tolist()
        console.print(f"[yellow]warning:[/] not identifiable from the data given: {', '.join(wide)} can vary over "
                      "more than 20 % of its range with the predicted angle within tolerance. One angle cannot pin "
                      "several parameters; add heap tests under other conditions (docs: the discrepancy loop).")
    # the search box is the design's: a solution on its edge may want a value beyond it
    box, at = dict(zip(params, zip(lows, highs))), dict(zip(params, best_x.tolist()))
    for q, side in at_bounds(at, box).items():
        lo, hi = box[q]
        console.print(f"[yellow]warning:[/] {q} = {at[q]:.4g} is at the {side} end of the range "
                      f"the surrogate was fitted on [{lo:.4g}, {hi:.4g}]: the targets may want a value beyond it. "
                      f"Widen factors.{q} and redo the design, or, if the range is physical, look for a missing "
                      "effect (calib compare, calib diagnose)")
    if refinement is not None:
        cols = ["round", *params, *(["condition_id"] if len(vconds) > 1 else []), "mean", "z", "predicted", "bias"]
        show = refinement[cols].rename(columns={"mean": "simulated"})
        console.print(df_table(show, f"Refinement by simulation: {int(refinement['round'].max())} correction(s)"))
        if ref.stalled:
            console.print(f"refinement stopped: the correction from round {int(refinement['round'].max())} returned "
                          "the point just simulated (within 1 % of each parameter's range)")
        if ref.accepted:
            console.print(f"round {chosen}'s heaps agree with the targets (rms z <= {float(iv['refine_z']):g}): its "
                          "parameters are the solution")
        else:
            console.print(f"[yellow]warning:[/] no round's heaps lie within {float(iv['refine_z']):g} combined sd "
                          "(rms z) of the targets; the "
                          f"solution is round {chosen}'s, the closest. The surrogate is wrong where the targets "
                          "lie: simulate more there (a narrower BBD around the solution) or add conditions.")
    if validation is not None:
        shown = validation[validation["round"] == chosen]
        for cid, _ in vconds:
            ok = shown.loc[shown["condition_id"].astype(str) == cid, "repose_angle"].dropna()
            where = f" ({cid})" if cid else ""
            if len(ok):
                t = vtargets.get(cid, float(np.mean(targets)))
                console.print(f"validation{where}: {len(ok)}/{validate} heaps, mean {ok.mean():.2f} deg, sd "
                              f"{ok.std(ddof=1) if len(ok) > 1 else float('nan'):.2f}, relative error "
                              f"{100 * abs(ok.mean() - t) / t:.3f} % against {t:.2f} (cf. paper 3.6: 32.31, 0.748 %)")
            else:
                console.print(f"[yellow]validation{where}: no run formed a heap[/]")
