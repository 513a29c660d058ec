"""Diagnose what the model lacks: rank the candidate effects by how much of compare's misfit each
would explain (a score test after projecting out what the calibrated parameters absorb), with the
evidence and whether the signature is resolved from the heaps' scatter."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..heaps.keys import CACHE_SOURCE
from ..discrepancy.point import MEASURED_SEEDINGS, check_seeding, model_and_theta, run_seeding, seeding_settings
from ..discrepancy.sensitivity import signatures
from ..discrepancy.stats import at_bounds, confound, confounded, score_effects, signature_noise, trends
from ..errors import CalibError
from ..measurements import measured_conditions
from ..model import EFFECTS, Model
from ..heaps.inputs import COND_VARS, Pairs, heap_setup, modulus_settings, run_heap_settings
from .common import (Result, Say, check_not_empty, check_run_dir, plain, resolve_settings, shown, space_from_design, stage,
                     warn_other_modulus, writes_run)


#: |weighted correlation| of a candidate's signature with a parameter's above which the evidence says
#: the two are confounded on the measured conditions
CONFOUND = 0.8


@dataclass
class DiagnoseResult(Result):
    """RUN/diagnose/: the missing effects ``ranking`` (effect, score, p_value, explained_fraction,
    signature_p, confounded_with, confound, verdict, evidence), most likely first."""

    ranking: Optional[pd.DataFrame] = None
    revision: int = 0
    bar: float = 0.05

    def __post_init__(self):
        if self.ranking is None and (self.dir / "ranking.parquet").is_file():
            self.ranking = art.read_table(self.dir / "ranking.parquet")
            self.revision = int(art.read_provenance(self.dir / "ranking.parquet").get("model_revision", 0))

    def summary(self) -> pd.DataFrame:
        return self.ranking[["effect", "score", "p_value", "explained_fraction", "signature_p"]]

    def conclusion(self, markup: bool = False) -> list[str]:
        """Each effect's evidence, and what to do when none is significant and resolved (``markup``: with the
        command line's rich markup)."""
        r = self.ranking
        out = [f"[bold]{e}[/]: {ev}" for e, ev in zip(r["effect"], r["evidence"])]
        if (r["verdict"] == "unresolved").any() and not (r["verdict"] == "significant").any():
            out.append("No missing effect is both significant and resolved: the candidates that pass the test leave "
                       "signatures within the heaps' scatter; rerun with more --repeats before adding one.")
        elif not (r["p_value"] < self.bar).any():
            out.append("No missing effect is significant: the misfit is within what the measurement noise explains.")
        return shown(out, markup)


def current_residuals(run: Path, model: Model, conds: pd.DataFrame, theta: dict | None = None) -> pd.DataFrame:
    """compare's residuals, one row per measured condition in ``conds``' order (matched by condition_id,
    not by row order), refused when another model revision, other conditions, other measured means or
    (where compare recorded it) another point ``theta`` made them: the sensitivities simulated now would
    be set against another model's, measurement's or point's misfit."""
    path = run / "compare" / "residuals.parquet"
    res = art.read_table(path, columns=["condition_id", "residual", "uncertainty"],
                         what="comparison (run `calib compare` first)")
    prov = art.read_provenance(path)
    _same_point(path, prov.get("theta"), theta, run)
    rev, effects = prov.get("model_revision"), prov.get("model")
    if rev is not None and (int(rev) != model.revision or (effects is not None and
                                                           sorted(effects) != sorted(model.effects))):
        made = f"revision {rev}" + (f" ({', '.join(effects)})" if effects else "")
        raise CalibError(f"{path} holds the residuals of model {made}, but the model is revision {model.revision} "
                         f"({', '.join(model.effects)}): run `calib compare --run {run}` first")
    ids = conds["condition_id"].astype(str).tolist()
    res = res.assign(condition_id=res["condition_id"].astype(str))
    have = res["condition_id"].tolist()
    if sorted(have) != sorted(ids):
        raise CalibError(f"{path} holds residuals of condition(s) {', '.join(have)}, but the measured conditions are "
                         f"{', '.join(ids)}: run `calib compare --run {run}` first")
    res = res.set_index("condition_id").loc[ids].reset_index()
    was = res["measured"].to_numpy(float) if "measured" in res.columns else conds["mean"].to_numpy(float)
    moved = [c for c, a, b in zip(ids, was, conds["mean"].to_numpy(float))
             if not np.isclose(a, b, rtol=1e-9, atol=1e-9)]
    if moved:  # measured again under the same names
        raise CalibError(f"{path} holds residuals against other measured means than RUN/measure's at "
                         f"{', '.join(moved)}: run `calib compare --run {run}` first")
    return res.drop(columns=["measured"], errors="ignore")


def _same_point(path: Path, made: dict | None, theta: dict | None, run: Path) -> None:
    """Refuse residuals compare made at another point than ``theta`` (another --set, or a calibration since)."""
    if made is None or theta is None:  # residuals from before compare recorded its point
        return
    other = sorted(k for k in set(made) | set(theta)
                   if k not in made or k not in theta or not np.isclose(made[k], theta[k], rtol=1e-12, atol=0))
    if other:
        said = ", ".join(f"{k} {made.get(k, '-')} against {theta.get(k, '-')}" for k in other)
        raise CalibError(f"{path} holds residuals at another point than this one ({said}): run `calib compare "
                         f"--run {run}` with the same --set first")


def _ranges(run: Path, model: Model) -> dict[str, tuple[float, float]]:
    """Each calibrated parameter's range, in the model's order: the BBD's, else the prior the posterior of
    this revision sampled (``calibrate``'s: the settings' factor table), else the effect's own."""
    # the current parameters can absorb misfit only within the ranges the calibration searched
    sp = space_from_design(run / "bbd" / "design.parquet")
    prior = _posterior_ranges(run, model)
    ranges = {}
    for e in model.effects:  # in J's column order
        q = EFFECTS[e].parameter
        ranges[q] = ((sp[q].low, sp[q].high) if sp is not None and q in sp.names else prior.get(q)
                     or (EFFECTS[e].low, EFFECTS[e].high))
    return ranges


def _posterior_ranges(run: Path, model: Model) -> dict[str, tuple[float, float]]:
    """The prior ranges of the posterior of the current model revision (RUN/posterior/summary.parquet's
    low and high), where there is one and no Box-Behnken design (the paper's chain) sets them."""
    path = run / "posterior" / "summary.parquet"
    if (run / "bbd" / "design.parquet").is_file() or not path.is_file():
        return {}
    if art.read_provenance(path).get("model_revision") != model.revision:
        return {}
    t = art.read_table(path)
    return {r.parameter: (float(r.low), float(r.high)) for r in t.itertuples()}


def _rank(run: Path, model: Model, theta: dict, res: pd.DataFrame, conds: pd.DataFrame, b, J, G, G_se, starts,
          alpha: float, say: Say):
    """The score test of every candidate on the usable conditions, with its signature's noise p-value,
    the residuals' trends against the condition variables, and the likeliest of them where it is
    significant (p below ``alpha`` over the number of variables)."""
    J = np.column_stack(J) if J else np.zeros((len(b), 0))
    r_all, u_all = res["residual"].to_numpy(float), res["uncertainty"].to_numpy(float)
    ok = np.isfinite(r_all) & np.isfinite(u_all) & np.all(np.isfinite(J), axis=1)
    for g in G.values():
        ok &= np.isfinite(g)
    if not ok.all():
        dropped = ", ".join(conds["condition_id"].astype(str)[~ok])
        say(f"[yellow]warning:[/] left out condition(s) {dropped}: a simulation formed no heap there "
            "or the uncertainty is unknown")
    if ok.sum() <= J.shape[1]:
        raise CalibError(f"only {int(ok.sum())} usable condition(s) for {J.shape[1]} parameters: cannot diagnose")
    J, G, G_se = J[ok], {k: g[ok] for k, g in G.items()}, {k: v[ok] for k, v in G_se.items()}
    ranges = _ranges(run, model)
    pars = list(ranges)
    lo = np.array([ranges[q][0] - theta[q] for q in pars])
    hi = np.array([ranges[q][1] - theta[q] for q in pars])
    cand_b = {e: (EFFECTS[e].low - starts[e], EFFECTS[e].high - starts[e]) for e in G}
    edge = at_bounds(theta, ranges)
    for q, side in edge.items():
        say(f"[yellow]note:[/] {q} = {theta[q]:.4g} is at the {side} end of its range "
            f"[{ranges[q][0]:.4g}, {ranges[q][1]:.4g}]: it cannot absorb misfit beyond it, so the test "
            "keeps each parameter inside its range (a residual it cannot reach is evidence of a "
            "missing effect, or of a range set too narrow)")
    ranking = score_effects(r_all[ok], u_all[ok], J, G, bounds=(np.minimum(lo, 0.0), np.maximum(hi, 0.0)),
                            cand_bounds=cand_b)
    # as in the ranking, a parameter stuck at the edge of its range absorbs nothing: judge the
    # candidates' signatures after projecting out only the parameters that are free to move
    free = [k for k, q in enumerate(pars) if q not in edge]
    for a, c in confounded(u_all[ok], J[:, free], G):
        say(f"[yellow]warning:[/] {a} and {c} leave the same signature across these conditions: "
            "the data cannot tell them apart; add conditions that separate them")
    # a signature within the scatter of the heaps that measured it ranks noise (discrepancy/stats.py)
    ranking["signature_p"] = [signature_noise(G[e], G_se[e])[1] for e in ranking["effect"]]
    # the parameter each candidate's signature most resembles: what it is confounded with here
    alike = [confound(J[:, free], G[e], u_all[ok], [pars[k] for k in free]) for e in ranking["effect"]]
    ranking["confounded_with"] = [a for a, _ in alike]
    ranking["confound"] = [c for _, c in alike]
    tr = trends(res[ok], res.loc[ok, [c for c in COND_VARS if c in res.columns]])
    return ranking, tr, observed_trend(tr, alpha), ok, J, G


def observed_trend(tr: pd.DataFrame, alpha: float) -> Optional[pd.Series]:
    """The likeliest of the residuals' trends (``trends``' rows), where it is significant at ``alpha`` over the
    number of variables tried (Bonferroni, as the candidates are), else None: evidence quotes only such a one."""
    if not len(tr):
        return None
    top = tr.sort_values("p_value").iloc[0]
    return top if top["p_value"] < alpha / len(tr) else None


def _verdicts(ranking: pd.DataFrame, top, alpha: float, repeats: int, say: Say) -> float:
    """Each candidate's verdict and evidence (columns added to ``ranking``); returns the corrected level."""
    # several candidates are tested at once: without the correction a lab with nothing missing would
    # flag one of three candidates 14 % of the time instead of 5 %
    bar = alpha / max(len(ranking), 1)
    words, verdicts = [], []
    for _, r in ranking.iterrows():
        eff = EFFECTS[r["effect"]]
        resolved = r["signature_p"] < alpha  # NaN (one heap a step: no scatter to judge by) counts as unresolved
        if not r["p_value"] < bar:
            verdict = "not significant"
        else:  # the test passes, but a signature within the heaps' scatter makes the pass (and the rank) noise
            verdict = "significant" if resolved else "unresolved"
        verdicts.append(verdict)
        txt = (f"{verdict} (p = {r['p_value']:.3g}); would remove {100 * r['explained_fraction']:.0f} % of the "
               f"misfit; its signature: {eff.signature}")
        if not resolved:
            say(f"[yellow]warning:[/] {r['effect']}'s signature is not resolved from the pile-to-pile "
                f"scatter with {repeats} heap(s) a step (p = {r['signature_p']:.2g} that it is zero): its "
                "rank is noise; rerun with more --repeats (cached heaps are reused)")
            txt += (f"; its signature is within the simulation noise (p = {r['signature_p']:.2g}): "
                    "the rank is unreliable")
        if r["confound"] >= CONFOUND:
            txt += (f"; on these conditions its signature is {r['confound']:.0%} alike "
                    f"{r['confounded_with']}'s, so the calibration can trade one for the other: "
                    "`calib suggest-conditions` names conditions that tell them apart")
        if top is not None and verdict == "significant":
            way = "grows" if top["slope"] > 0 else "falls"
            txt += f"; observed: the residual {way} with {top['variable']} (p = {top['p_value']:.3g})"
        words.append(txt)
    ranking["verdict"] = verdicts
    ranking["evidence"] = words
    return bar


@writes_run
def diagnose(run: Path, set_: Pairs = None, preset: Optional[str] = None, repeats: int = 3, workers: int = 1,
             shear_modulus: Optional[float] = None, alpha: float = 0.05, force: bool = False,
             say: Optional[Say] = None, seeds: Optional[str] = None) -> DiagnoseResult:
    """Rank the effects missing from the model by how much of compare's misfit each would explain.
    ``seeds``: the heaps' seeding (:data:`~calib_cli.discrepancy.point.MEASURED_SEEDINGS`); by default
    compare's (:func:`~calib_cli.discrepancy.point.run_seeding`), so the base point's heaps are compare's own.
    Writes RUN/diagnose/ranking.parquet, sensitivities.parquet and trends.parquet."""
    say = say or plain
    if not 0.0 < alpha < 1.0:
        raise CalibError(f"--alpha {alpha:g} must lie strictly between 0 and 1 (a significance level)")
    run = check_run_dir(run)
    check_not_empty(run)
    preset, shear_modulus = heap_setup(resolve_settings(run, None, None), preset, shear_modulus)
    model, theta = model_and_theta(run, set_)
    conds = measured_conditions(run)
    res = current_residuals(run, model, conds, theta)
    seeds = check_seeding(seeds or run_seeding(run))
    warn_other_modulus(run, shear_modulus, "the diagnosis's", say)
    prior = _posterior_ranges(run, model)  # in the lock only where they set the ranges: older locks stay valid
    st = stage(run, "diagnose", "rank", inputs={"residuals": run / "compare" / "residuals.parquet"},
                   settings={"theta": theta, "model": model.hash, "preset": preset, "repeats": repeats,
                             "alpha": alpha, "kernel": CACHE_SOURCE, **modulus_settings(shear_modulus),
                             **run_heap_settings(resolve_settings(run, None, None)),
                             **({"ranges": prior} if prior else {}), **seeding_settings(seeds)})
    if st.up_to_date() and not force:
        return DiagnoseResult(st, True)
    cands = model.candidates
    if len(conds) <= len(model.parameters):
        raise CalibError(f"diagnose needs more conditions ({len(conds)}) than calibrated parameters "
                         f"({len(model.parameters)}): otherwise the current parameters can absorb any pattern of "
                         "residuals and no missing effect can be told apart. Measure heaps under more conditions.")
    two_sided = [e for e in cands if EFFECTS[e].two_sided]
    n_sims = (len(model.parameters) + len(cands) + len(two_sided)) * len(conds) * repeats
    say(f"diagnose: {len(model.parameters)} sensitivities + {len(cands)} candidate effects "
        f"({len(two_sided)} stepped both ways) x {len(conds)} conditions x {repeats} repeats = {n_sims} "
        "simulations (cached runs are reused)")
    b, J, G, G_se, starts = signatures(run, model, theta, conds, preset, repeats, workers, shear_modulus,
                                       seeds=MEASURED_SEEDINGS[seeds])
    ranking, tr, top, ok, J, G = _rank(run, model, theta, res, conds, b, J, G, G_se, starts, alpha, say)
    bar = _verdicts(ranking, top, alpha, repeats, say)
    sens = pd.DataFrame({"condition_id": conds["condition_id"].astype(str)[ok].to_numpy()})
    for k, e in enumerate(model.effects):
        sens[f"d_{EFFECTS[e].parameter}"] = J[:, k]
    for e, g in G.items():
        sens[f"candidate_{e}"] = g
    with st.commit() as out:
        out.table("ranking.parquet", ranking[["effect", "score", "p_value", "explained_fraction", "signature_p",
                                              "confounded_with", "confound", "verdict", "evidence"]],
                  model_revision=model.revision)
        out.table("sensitivities.parquet", sens, theta=theta)  # suggest-conditions simulates at the same point
        out.table("trends.parquet", tr)
    return DiagnoseResult(st, False, ranking, model.revision, bar)
