"""Invert the surrogate to the measured angles (GA, paper Eq. 11, Fig. 9), with the set of
parameters that fit equally well; optionally validate the solution with heaps on the measured rig
(paper 3.6) and correct the surrogate where they miss (output space mapping)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..conditions import outside_range
from ..heaps.runner import run_campaign
from ..dem.heap import PARAMETERS
from ..discrepancy.stats import at_bounds, per_condition, residual_table
from ..errors import CalibError
from ..parameters import check
from ..plots import plt  # the Agg backend, set in one place
from ..heaps.inputs import (COND_VARS, Pairs, build_requests, checked_condition, heap_engine, heap_precision,
                            heap_preset, heap_setup, make_condition, modulus_settings, run_heap_settings,
                            table_conditions)
from ..surrogate.inversion import IDENTIFIABLE_FRACTION, solution_parameters
from ..surrogate.inversion import invert as invert_surrogate
from ..surrogate.inversion import nearest, refine as refine_by_simulation
from ..surrogate.store import MODELS_DIR, load_models
from .common import (Result, Say, bbd_fixed, check_run_dir, plain, resolve_settings, stage,
                     warn_other_modulus, writes_run)


@dataclass
class Problem:
    """What the GA inverts: the surrogate's parameters and their box, and every target's prediction."""

    params: list[str]
    lows: list[float]
    highs: list[float]
    targets: list[float]
    predict: Callable[[np.ndarray], np.ndarray]  # (points, parameters) -> (points, targets)
    iv: dict

    def solve(self, predict: Optional[Callable] = None):
        iv = self.iv
        return invert_surrogate(predict or self.predict, self.params, self.lows, self.highs, self.targets,
                                int(iv["generations"]), int(iv["population"]), float(iv["crossover"]),
                                float(iv["mutation"]), int(iv["seed"]), float(iv["tolerance"]), int(iv["samples"]),
                                int(iv["restarts"]))


@dataclass
class Validation:
    """The validation heaps of every round (``rounds``), the refinement's table, and the chosen round."""

    best: np.ndarray
    chosen: int
    rows: pd.DataFrame
    conditions: list[tuple[str, object]]
    targets: dict[str, float]
    per_condition: int
    refinement: Optional[pd.DataFrame] = None
    accepted: bool = False
    stalled: bool = False


@dataclass
class InvertResult(Result):
    """RUN/invert/: the ``solution`` (one row: parameters, predicted angle, fitness, model, target), the
    near-optimal ``ranges``, and with validation its heaps and refinement."""

    solution: Optional[pd.DataFrame] = None
    per_condition: Optional[pd.DataFrame] = None
    ranges: Optional[pd.DataFrame] = None
    n_near: int = 0
    tolerance: float = 0.0
    target_source: str = ""
    identifiable: bool = True
    validation: Optional[Validation] = None
    #: what the result warns of (:meth:`warnings`)
    warning_lines: list[str] = field(default_factory=list)
    verdict: list[str] = field(default_factory=list)

    def __post_init__(self):
        if self.solution is None and (self.dir / "solution.parquet").is_file():
            # read back (the stage was up to date): what the files hold, and the words the run that wrote them
            # said (a solution written before 2026-11-29 kept none: force=True says them again)
            self.solution = art.read_table(self.dir / "solution.parquet")
            self.ranges = art.read_table(self.dir / "ranges.parquet")
            self.per_condition = art.read_table(self.dir / "predicted_conditions.parquet")
            self.identifiable = bool((self.ranges["width_fraction"] <= IDENTIFIABLE_FRACTION).all())
            said = art.read_provenance(self.dir / "solution.parquet")
            self.target_source = str(said.get("target_source", ""))
            self.warning_lines, self.verdict = list(said.get("warnings", [])), list(said.get("verdict", []))
            if (self.dir / "solution_set.parquet").is_file():
                self.n_near = len(art.read_table(self.dir / "solution_set.parquet"))
                self.tolerance = float(art.read_provenance(self.dir / "solution_set.parquet").get("tolerance", 0.0))

    def summary(self) -> pd.DataFrame:
        """The solution: the parameters and the predicted angle there."""
        return self.solution

    def refinement(self) -> Optional[pd.DataFrame]:
        """The refinement's rounds (parameters, simulated mean, z, prediction, bias), if it ran."""
        v = self.validation
        if v is not None and v.refinement is not None:
            table, several = v.refinement, len(v.conditions) > 1
        elif v is None and (self.dir / "refinement.parquet").is_file():  # read back: the table it wrote
            table = art.read_table(self.dir / "refinement.parquet")
            several = "condition_id" in table.columns and table["condition_id"].nunique() > 1
        else:
            return None
        params = solution_parameters(self.solution)
        cols = ["round", *params, *(["condition_id"] if several else []), "mean", "z", "predicted", "bias"]
        return table[cols].rename(columns={"mean": "simulated"})

    def warnings(self) -> list[str]:
        """What the solution warns of: parameters not identifiable from the data, a solution at the edge of
        the surrogate's range, a validation that misses (the lines the command prints)."""
        return list(self.warning_lines)


def _targets(run: Path, cfg: dict, target: Optional[float]) -> tuple[list[float], str]:
    """The target angles: --target, else each measured condition's mean, else settings target."""
    cond_path = run / "measure" / "conditions.parquet"
    if target is not None:
        targets, tsource = [check("repose_angle", target, "--target")], "--target"
    elif cond_path.is_file():
        c = art.read_table(cond_path, columns=["condition_id", "mean"], what="measured conditions")
        targets, tsource = c["mean"].astype(float).tolist(), f"{cond_path} ({len(c)} condition(s))"
    else:
        targets, tsource = [float(cfg["target"])], "settings target"
    if not all(np.isfinite(targets)) or not all(0 < t < 90 for t in targets):
        raise CalibError(f"target angles must lie in (0, 90) deg, got {targets}")
    return targets, tsource


def _problem(run: Path, m, best: dict, targets: list[float], target: Optional[float], iv: dict) -> Problem:
    """The inversion problem of surrogate ``m``; one over condition variables too predicts every
    measured condition at its own variables."""
    names = best["inputs"]
    cond_path = run / "measure" / "conditions.parquet"
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
    return Problem(params, lows, highs, targets, predict_all, iv)


def _fitness_plot(hist: pd.DataFrame, name: str):
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(hist["generation"], hist["best"], label="best")
    ax.plot(hist["generation"], hist["mean"], label="mean", alpha=0.7)
    ax.set_yscale("log")
    ax.set_xlabel("generation")
    ax.set_ylabel("fitness: RMSE to target [deg]")
    ax.set_title(f"GA inversion of the {name} surrogate (cf. paper Fig. 9)")
    ax.legend()
    return fig


def _validation_rig(run: Path, pre, condition: Pairs, target: Optional[float]):
    """The validation's conditions and their measured targets: the measured rig, or the preset's with
    ``condition``'s changes."""
    cond_path = run / "measure" / "conditions.parquet"
    if condition or not cond_path.is_file():
        return [("", make_condition(pre.condition, checked_condition(condition)))], {}, None
    # the rig the heaps were measured on, not the preset's: a validation elsewhere validates nothing
    vtab = art.read_table(cond_path, columns=["condition_id", "mean", "sd", "n"], what="measured conditions")
    vconds = table_conditions(pre.condition, vtab)
    vtargets = dict(zip(vtab["condition_id"].astype(str), vtab["mean"].astype(float))) if target is None else {}
    return vconds, vtargets, (vtab if target is None else None)


def _validate(run: Path, cfg: dict, prob: Problem, start: np.ndarray, validate: int, n_refine: int, preset: str,
              shear_modulus: Optional[float], condition: Pairs, target: Optional[float], workers: int,
              say: Say) -> Validation:
    """Simulate ``validate`` heaps a condition at the solution; with ``n_refine``, correct the surrogate by
    their misses and invert again, at most that many times (surrogate.inversion.refine)."""
    iv, targets = cfg["invert"], prob.targets
    pre = heap_preset(preset, shear_modulus, heap_precision(cfg, heap_engine(cfg)))
    warn_other_modulus(run, shear_modulus, "the validation's", say)
    vconds, vtargets, vtab = _validation_rig(run, pre, condition, target)
    if n_refine and len(vconds) != len(targets):
        raise CalibError(f"--refine compares each validation condition with its own target: {len(vconds)} "
                         f"validation condition(s) but {len(targets)} target(s) (drop --target)")
    fixed = bbd_fixed(run, cfg)
    rounds: list[pd.DataFrame] = []
    ids = [cid for cid, _ in vconds]

    def simulate_round(x, k):
        vparams = {**fixed, **{n: float(v) for n, v in zip(prob.params, x) if n in PARAMETERS}}
        # round 0 keeps the seeds of a plain --validate (one condition keeps run index 0); each
        # correction round draws fresh ones
        reqs = build_requests([(0, vparams)], vconds, pre.numerics, seed=int(iv["seed"]), repeats=validate,
                              first_repeat=k * validate, from_table=len(vconds) > 1, preset=preset,
                              design="validate", label_by_condition=True, engine=heap_engine(cfg))
        rows = run_campaign(reqs, run, workers).copy()
        rows.insert(0, "round", k)
        rounds.append(rows)
        sim = per_condition(rows, ids)
        if vtab is not None:
            m = vtab.set_index(vtab["condition_id"].astype(str)).reindex(ids)
            mm, ms, mn = m["mean"], m["sd"], m["n"]
        else:  # a bare target angle: no measured scatter to add
            mm, ms, mn = np.full(len(ids), float(np.mean(targets))), np.full(len(ids), np.nan), np.zeros(len(ids))
        rt = residual_table(mm, ms, mn, sim["mean"], sim["sd"], sim["n"])[["residual", "uncertainty", "z", "fails"]]
        return pd.concat([pd.DataFrame({"condition_id": ids}), sim.reset_index(drop=True), rt], axis=1)

    def reinvert(bias, x):
        again = prob.solve(lambda P: prob.predict(P) + bias[None, :])
        return nearest(again.solution_set, prob.params, prob.lows, prob.highs, x)

    # a move under 1 % of every parameter's range shifts the angles by ~0.1 deg at the BBD's steepest
    # slopes (~6 deg per half range), far inside a validation mean's scatter: re-measuring it only
    # draws again (seen: a point moved by 0.0002 simulated a third time)
    xtol = 0.01 * (np.asarray(prob.highs, float) - np.asarray(prob.lows, float))
    ref = refine_by_simulation(prob.predict, simulate_round, reinvert, start, targets, prob.params, n_refine,
                               float(iv["refine_z"]), xtol=xtol)
    rows = pd.concat(rounds, ignore_index=True)[["round", "condition_id", "repeat", "seed", "status", "repose_angle",
                                                 "angle_coords", "angle_image", "wall_s"]]
    return Validation(ref.best, ref.best_round, rows, vconds, vtargets, validate,
                      ref.rounds if n_refine else None, bool(ref.accepted), bool(ref.stalled))


@writes_run
def invert(run: Path, target: Optional[float] = None, model: Optional[str] = None, validate: int = 0,
           preset: Optional[str] = None, shear_modulus: Optional[float] = None, condition: Pairs = None,
           workers: int = 1, refine: Optional[int] = None, settings: Optional[Path] = None,
           setting: Optional[list[str]] = None, force: bool = False, say: Optional[Say] = None) -> InvertResult:
    """Invert the surrogate (``model``, else the best on held-out data) to the targets (``target``, else
    the measured conditions, else settings target); with ``validate`` N, simulate N heaps a condition at
    the solution, and with ``refine`` (default settings invert.refine) correct it where they miss.
    Writes RUN/invert/solution.parquet, predicted_conditions.parquet, history.parquet,
    solution_set.parquet, ranges.parquet, fitness.png [, validation.parquet, refinement.parquet]."""
    say = say or plain
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    iv = cfg["invert"]
    preset, shear_modulus = heap_setup(cfg, preset, shear_modulus)
    models, best = load_models(run, model)
    name = model or best["best"]
    cond_path = run / "measure" / "conditions.parquet"
    targets, tsource = _targets(run, cfg, target)
    n_refine = int(iv["refine"] if refine is None else refine)
    if condition and not validate:  # the rig of heaps it would not simulate: ignored, it read as taken
        raise CalibError("--condition sets the rig of the --validate heaps: give --validate N too, or leave it out")
    if n_refine and not validate:
        given = "--refine" if refine is not None else f"the settings' invert.refine = {n_refine}"
        raise CalibError(f"{given} corrects the inversion from validation heaps: give --validate N too, or "
                         "--refine 0")
    inputs = {"model": run / MODELS_DIR / f"{name}.json"}
    if cond_path.is_file() and (target is None or (validate and not condition)):
        inputs["conditions"] = cond_path  # the targets, or the rig of the validation runs
    condition_items = sorted(condition or []) if not isinstance(condition, dict) else \
        sorted(f"{k}={v}" for k, v in condition.items())
    st = stage(run, "invert", "solve", inputs=inputs,
                   settings={"invert": {**iv, "refine": n_refine}, "targets": targets, "model": name, "validate": validate,
                             "preset": preset,
                             **modulus_settings(shear_modulus), **(run_heap_settings(cfg) if validate else {}),
                             "condition": condition_items})
    if st.up_to_date() and not force:
        return InvertResult(st, True)
    prob = _problem(run, models[name], best, targets, target, iv)
    res = prob.solve()
    hist = pd.DataFrame({"generation": np.arange(1, len(res.ga.best) + 1), "best": res.ga.best, "mean": res.ga.mean})
    fig = _fitness_plot(hist, name)
    val = _validate(run, cfg, prob, res.best, validate, n_refine, preset, shear_modulus, condition, target, workers,
                    say) if validate else None
    best_x, chosen = (val.best, val.chosen) if val is not None else (res.best, 0)
    preds = prob.predict(best_x[None, :])[0]
    fit_at = float(np.sqrt(np.mean((preds - np.asarray(targets, float)) ** 2)))
    sol = pd.DataFrame([{**dict(zip(prob.params, best_x.tolist())), "predicted_angle": float(np.mean(preds)),
                         "fitness": fit_at, "model": name, "target": float(np.mean(targets))}])
    per_cond = pd.DataFrame({"target": targets, "predicted_angle": preds})
    result = InvertResult(st, False, sol, per_cond, res.ranges, len(res.solution_set), float(iv["tolerance"]), tsource,
                          res.identifiable, val)
    result.warning_lines = _warnings(result, prob, best_x) + _beyond_learnt(run, best)
    result.verdict = _verdict(result, prob, float(iv["refine_z"]))
    with st.commit() as out:
        # the words kept with the solution: a rerun that finds the stage up to date reads them back
        out.table("solution.parquet", sol, targets=targets, target_source=tsource, refine_round=chosen,
                  warnings=result.warning_lines, verdict=result.verdict)
        out.table("predicted_conditions.parquet", per_cond)
        out.table("history.parquet", hist)
        out.table("solution_set.parquet", res.solution_set, tolerance=float(iv["tolerance"]))
        out.table("ranges.parquet", res.ranges)
        out.figure("fitness.png", fig)
        if val is not None:
            out.table("validation.parquet", val.rows)
        if val is not None and val.refinement is not None:
            out.table("refinement.parquet", val.refinement, accepted=val.accepted, chosen_round=chosen,
                      stalled=val.stalled)
    return result


def _beyond_learnt(run: Path, best: dict) -> list[str]:
    """The measured conditions that set a condition variable beyond the range the surrogate learnt it over
    (its ``lows``/``highs``, the training inputs' range): its predictions there, and so the fit, extrapolate."""
    names = best["inputs"]
    cvars = [(n, lo, hi) for n, lo, hi in zip(names, best["lows"], best["highs"]) if n in COND_VARS]
    path = run / "measure" / "conditions.parquet"
    if not cvars or not path.is_file():
        return []
    ctab = art.read_table(path, columns=["condition_id", *(n for n, _, _ in cvars)], what="measured conditions")
    out = []
    for n, lo, hi in cvars:
        far = ctab.loc[outside_range(ctab[n], lo, hi), "condition_id"].astype(str).tolist()
        if far:
            out.append(f"condition(s) {', '.join(far)} set {n} beyond the {lo:g} to {hi:g} the surrogate learnt it "
                       "over: its predictions there extrapolate, and so does the solution; simulate heaps there "
                       "(a design crossed with those conditions) before trusting it")
    return out


def _warnings(r: InvertResult, prob: Problem, best_x: np.ndarray) -> list[str]:
    """An unidentifiable solution, and parameters at the edge of the surrogate's box (plain text: the command
    prints each as a warning)."""
    out = []
    if not r.identifiable:
        wide = r.ranges.loc[r.ranges["width_fraction"] > IDENTIFIABLE_FRACTION, "parameter"].tolist()
        out.append(f"not identifiable from the data given: {', '.join(wide)} can vary over "
                   f"more than {IDENTIFIABLE_FRACTION * 100:.0f} % of its range with the predicted angle within "
                   "tolerance. One angle cannot pin "
                   "several parameters; add heap tests under other conditions (docs: the discrepancy loop).")
    # the search box is the design's: a solution on its edge may want a value beyond it
    box, at = dict(zip(prob.params, zip(prob.lows, prob.highs))), dict(zip(prob.params, best_x.tolist()))
    for q, side in at_bounds(at, box).items():
        lo, hi = box[q]
        out.append(f"{q} = {at[q]:.4g} is at the {side} end of the range "
                   f"the surrogate was fitted on [{lo:.4g}, {hi:.4g}]: the targets may want a value beyond it. "
                   f"Widen factors.{q} and redo the design, or, if the range is physical, look for a missing "
                   "effect (calib compare, calib diagnose)")
    return out


def _verdict(r: InvertResult, prob: Problem, refine_z: float) -> list[str]:
    """What the refinement concluded, and each validation condition's heaps against its target."""
    v, out = r.validation, []
    if v is None:
        return out
    if v.refinement is not None:
        if v.stalled:
            out.append(f"refinement stopped: the correction from round {int(v.refinement['round'].max())} returned "
                       "the point just simulated (within 1 % of each parameter's range)")
        if v.accepted:
            out.append(f"round {v.chosen}'s heaps agree with the targets (rms z <= {refine_z:g}): its "
                       "parameters are the solution")
        else:
            out.append(f"warning: no round's heaps lie within {refine_z:g} combined sd "
                       "(rms z) of the targets; the "
                       f"solution is round {v.chosen}'s, the closest. The surrogate is wrong where the targets "
                       "lie: simulate more there (a narrower BBD around the solution) or add conditions.")
    shown = v.rows[v.rows["round"] == v.chosen]
    for cid, _ in v.conditions:
        ok = shown.loc[shown["condition_id"].astype(str) == cid, "repose_angle"].dropna()
        where = f" ({cid})" if cid else ""
        if len(ok):
            t = v.targets.get(cid, float(np.mean(prob.targets)))
            out.append(f"validation{where}: {len(ok)}/{v.per_condition} heaps, mean {ok.mean():.2f} deg, sd "
                       f"{ok.std(ddof=1) if len(ok) > 1 else float('nan'):.2f}, relative error "
                       f"{100 * abs(ok.mean() - t) / t:.3f} % against {t:.2f} (cf. paper 3.6: 32.31, 0.748 %)")
        else:
            out.append(f"warning: validation{where}: no run formed a heap")
    return out
