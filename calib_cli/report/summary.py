"""The report's first screen: what was calibrated against what, the verdict, the parameters, the fit
per condition, the error history, the missing-effect ranking and a photo against a simulated heap."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import pandas as pd

from ..surrogate.inversion import IDENTIFIABLE_FRACTION, solution_parameters
from .html import RunFiles, badge, deg, esc, num, words

#: a parameter is pinned when its near-optimal values span at most this share of its search range
PINNED = IDENTIFIABLE_FRACTION
FIT_COLS = ["condition_id", "measured", "measured_sd", "simulated", "simulated_sd", "fails"]


@dataclass
class Fit:
    """Measured against simulated per condition; kind: compare, validation, surrogate, measured or none;
    label: where the simulated values come from (HTML)."""
    rows: pd.DataFrame
    kind: str
    label: str


def solution_params(f: RunFiles) -> dict[str, float]:
    sol = f.table("invert/solution.parquet")
    if sol is None or sol.empty:
        return {}
    row = sol.iloc[0]
    return {k: float(row[k]) for k in solution_parameters(sol)}


def _validation_fit(f: RunFiles, cond: pd.DataFrame) -> Optional[Fit]:
    """The validation heaps of the chosen refinement round against the measured conditions."""
    from ..discrepancy.stats import residual_table

    val = f.table("invert/validation.parquet")
    if val is None or val.empty or "condition_id" not in val.columns:
        return None
    chosen = int(f.prov("invert/solution.parquet").get("refine_round", 0) or 0)
    v = val[(val["round"] == chosen) & (val["status"] == "ok")] if "round" in val.columns else val
    sim = v.groupby("condition_id")["repose_angle"].agg(sim="mean", sim_sd="std", sim_n="count").reset_index()
    m = cond[["condition_id", "mean", "sd", "n"]].merge(sim, on="condition_id")
    if m.empty:
        return None
    res = residual_table(m["mean"], m["sd"], m["n"], m["sim"], m["sim_sd"], m["sim_n"])
    rows = pd.DataFrame({"condition_id": m["condition_id"], "measured": m["mean"], "measured_sd": m["sd"],
                         "simulated": m["sim"], "simulated_sd": m["sim_sd"], "fails": res["fails"].to_numpy()})
    return Fit(rows, "validation", f"validation heaps at the solution (refinement round {chosen})")


def fit_rows(f: RunFiles) -> Fit:
    """compare's residuals, else the validation heaps, else the surrogate's prediction, else the measurement."""
    res = f.table("compare/residuals.parquet")
    if res is not None and len(res):
        rev = f.prov("compare/residuals.parquet").get("model_revision", "?")
        return Fit(res[FIT_COLS].copy(), "compare", f"<code>calib compare</code> heaps, model revision {esc(rev)}")
    cond = f.table("measure/conditions.parquet")
    fit = _validation_fit(f, cond) if cond is not None else None
    if fit is not None:
        return fit
    pc = f.table("invert/predicted_conditions.parquet")
    if pc is not None and len(pc):
        same = cond is not None and len(cond) == len(pc)
        rows = pd.DataFrame({
            "condition_id": cond["condition_id"].to_numpy() if same else [f"target {i + 1}" for i in range(len(pc))],
            "measured": pc["target"].to_numpy(float), "measured_sd": cond["sd"].to_numpy(float) if same else np.nan,
            "simulated": pc["predicted_angle"].to_numpy(float), "simulated_sd": np.nan, "fails": None})
        return Fit(rows, "surrogate", "surrogate prediction at the solution (no heap simulated there)")
    if cond is not None and len(cond):
        rows = pd.DataFrame({"condition_id": cond["condition_id"], "measured": cond["mean"],
                             "measured_sd": cond["sd"], "simulated": np.nan, "simulated_sd": np.nan, "fails": None})
        return Fit(rows, "measured", "not calibrated yet")
    return Fit(pd.DataFrame(columns=FIT_COLS), "none", "nothing measured")


def _rmse(rows: pd.DataFrame) -> float:
    r = (rows["measured"] - rows["simulated"]).to_numpy(float)
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan")


def _against(f: RunFiles) -> str:
    """What the calibration was fitted to: the measured heaps and conditions, or a target angle."""
    prov = f.prov("invert/solution.parquet")
    cond = f.table("measure/conditions.parquet")
    if cond is not None and len(cond) and "conditions" in str(prov.get("target_source", "conditions")):
        heaps = int(cond["n"].sum())
        how = "photographed" if f.pngs("measure/overlays") else "measured"
        return (f"the repose angles of {heaps} {how} heap{'s' * (heaps != 1)} under {len(cond)} "
                f"condition{'s' * (len(cond) != 1)}")
    sol = f.table("invert/solution.parquet")
    return f"a target angle of {deg(sol['target'].iloc[0])}" if sol is not None else "nothing yet"


def _diagnosis_clause(f: RunFiles) -> str:
    """What diagnose concluded, and whether a later model revision took it up."""
    rank = f.table("diagnose/ranking.parquet")
    if rank is None or rank.empty:
        return ""
    drev = f.prov("diagnose/ranking.parquet").get("model_revision", "?")
    sig = list(rank.loc[rank["verdict"] == "significant", "effect"]) if "verdict" in rank.columns else \
        list(rank.loc[rank["p_value"] < 0.05 / len(rank), "effect"])
    text = (f" The diagnosis of model revision {esc(drev)} ranked {words(sig)} significant" if sig else
            f" The diagnosis of model revision {esc(drev)} found no significant missing effect")
    hist = f.table("compare/history.parquet")
    if hist is None or not len(hist) or int(hist["revision"].iloc[-1]) <= int(drev if str(drev).isdigit() else -1):
        return text + "."
    last = hist.iloc[-1]
    was = hist.loc[hist["revision"] == int(drev)]
    new = [e for e in str(last["effects"]).split(",") if len(was) and e not in str(was["effects"].iloc[0]).split(",")]
    added = [e for e in sig if e in str(last["effects"]).split(",")]
    other = [e for e in new if e not in added]  # added by hand, not from the ranking: say so
    if not added and not other:
        return text + "."
    # both: the RMSE weighs every condition alike, chi2/dof by its uncertainty, and they can part ways
    change = (f" (RMSE {deg(was['rmse'].iloc[0])} &rarr; {deg(last['rmse'])}, &chi;&sup2;/dof "
              f"{num(was['chi2_dof'].iloc[0], 3)} &rarr; {num(last['chi2_dof'], 3)})" if len(was) else "")
    adds = [words(added)] * bool(added) + [f"{words(other)}, which it did not rank significant"] * bool(other)
    return text + f"; revision {int(last['revision'])} adds {' and '.join(adds)}{change}."


def verdict(f: RunFiles, fit: Fit) -> tuple[str, str]:
    """(kind, one sentence) on how well the calibrated model reproduces the measurements: pass, chance (conditions
    beyond two u, as many as chance gives a right model: consistent, not confirmed), reached (as many fitted
    parameters as angles: the fit checks the solution, not the model), fail or info."""
    n = len(fit.rows)
    cs = f"condition{'s' * (n != 1)}"
    if fit.kind in ("compare", "validation"):
        sim = fit.rows["simulated"].to_numpy(float) if "simulated" in fit.rows else np.zeros(len(fit.rows))
        gone = fit.rows.loc[~np.isfinite(sim), "condition_id"].astype(str)
        nf = int(fit.rows["fails"].fillna(False).astype(bool).sum())
        hist = f.table("compare/history.parquet")
        if fit.kind == "compare" and hist is not None and len(hist):
            last = hist.iloc[-1]
            who, one, stats = f"Model revision {int(last['revision'])}", True, \
                f"RMSE {deg(last['rmse'])}, &chi;&sup2;/dof {num(last['chi2_dof'], 3)}"
        else:
            who, one, stats = "The validation heaps at the solution", False, f"RMSE {deg(_rmse(fit.rows))}"
        which = "the measured condition" if n == 1 else f"all {n} {cs}"
        if len(gone):  # no z there: not a pass, and a model that cannot form the lab's heap misses it
            return "fail", (f"{who} form{'s' * one} no heap at {len(gone)} of {n} {cs} ({esc(', '.join(gone))}), "
                            f"where the lab's piles did: not checked there, and missed; elsewhere {nf} of "
                            f"{n - len(gone)} lie beyond two combined standard uncertainties ({stats}).")
        free = _free_clause(f, n)
        if nf == 0:
            return ("reached" if free else "pass"), (f"{who} reproduce{'s' * one} {which} within two combined "
                                                     f"standard uncertainties ({stats}){free}.")
        missed = "the measured condition" if n == 1 else f"{nf} of {n} {cs}"
        chance = _within_chance(f, fit) if fit.kind == "compare" else None
        if chance:
            return "chance", (f"{who} reproduce{'s' * one} the {n} {cs} as well as chance allows: {missed} "
                              f"lie{'s' * (nf == 1)} beyond two combined standard uncertainties, {chance} ({stats}); "
                              "consistent with the measurements, not a confirmation.")
        return "fail", f"{who} miss{'es' * one} {missed} by more than two combined standard uncertainties ({stats})."
    if fit.kind == "surrogate":
        free = _free_clause(f, n, "the search can always reach", "that says nothing of the model")
        return "info", (f"Not checked by simulation: at the solution the surrogate predicts the measured "
                        f"angle{'s' * (n != 1)} within RMSE {deg(_rmse(fit.rows))}{free}, but no heap was simulated "
                        "there (<code>calib invert --validate N</code>, <code>calib compare</code>).")
    return "info", "Not checked by simulation yet: <code>calib compare</code> simulates the calibrated point."


def _free_clause(f: RunFiles, n: int, how: str = "a fit is expected to reach",
                 then: str = "that checks the solution, not the model") -> str:
    """" (with 3 parameters for 1 angle a fit is expected to reach it: that checks the solution, not the model)"
    where the calibrated point has as many parameters as there are measured angles, else ""."""
    k = len(solution_params(f))
    if k < n:
        return ""
    return f" (with {k} parameters for {n} angle{'s' * (n != 1)} {how} {'it' if n == 1 else 'them'}: {then})"


def _within_chance(f: RunFiles, fit: Fit) -> str:
    """Why compare's conditions beyond |z| = 2 are no misfit, or "" where they are one: the z of the model's
    conditions taken together, at a family-wise 5 % (every |z| within Sidak's bar for n conditions, and the
    chi-square of the z's, sum z^2 on compare's own degrees of freedom, sum z^2 / (chi2/dof), not beyond
    p 0.05). With six conditions a model that is right has one |z| > 2 about one time in four."""
    from scipy import stats

    res, hist = f.table("compare/residuals.parquet"), f.table("compare/history.parquet")
    z = res["z"].to_numpy(float) if res is not None and "z" in res.columns else np.array([])
    z = z[np.isfinite(z)]
    if len(z) < 2 or hist is None or not len(hist) or not np.isfinite(hist["chi2_dof"].iloc[-1]):
        return ""
    n, x2 = len(z), float(np.sum(z ** 2))
    bar = float(stats.norm.isf((1 - 0.95 ** (1 / n)) / 2))
    dof = x2 / float(hist["chi2_dof"].iloc[-1]) if hist["chi2_dof"].iloc[-1] > 0 else float(n)
    p = float(stats.chi2.sf(x2, dof))
    if np.abs(z).max() > bar or p < 0.05:
        return ""
    chance = 1 - (1 - 2 * float(stats.norm.sf(2.0))) ** n
    return (f"as at least one of {n} does by chance {chance:.0%} of the time (largest |z| "
            f"{np.abs(z).max():.2f}, within the {bar:.2f} that {n} conditions allow at 5%; "
            f"&chi;&sup2; of all {n}: p {p:.2f})").replace("%", " %")


def _loose_clause(f: RunFiles) -> str:
    """The GA point's near-optimal spread, said as the surrogate's (no posterior here)."""
    rng = f.table("invert/ranges.parquet")
    note = " No posterior says how well the data pin them (<code>calib calibrate</code>)."
    if rng is None or rng.empty:
        return note
    loose = list(rng.loc[rng["width_fraction"] > PINNED, "parameter"])
    if not loose:
        return f" The surrogate's near-optimal set is narrow for every parameter.{note}"
    return (f" The surrogate's near-optimal values of {words(loose)} span more than {PINNED:.0%} of the search "
            f"range.{note}").replace("%", " %")


def favoured_off(post: pd.DataFrame) -> np.ndarray:
    """Per row of a posterior summary, whether it is an effect the data favour off (P(off) at a Bayes factor of
    off above BF_OFF, as the verdict's words): its averaged interval is then the neutral value's, not an
    identification."""
    from ..posterior.evidence import BF_OFF

    if "p_off" not in post.columns:
        return np.zeros(len(post), bool)
    return post["p_off"].fillna(0.0).to_numpy(float) > BF_OFF / (1 + BF_OFF)


def _posterior_clause(post: pd.DataFrame, prior: str = "settings") -> str:
    """What the posterior says: undecided (the surrogate unsure), or which parameters it identifies and
    each added effect's verdict with its Bayes factor; ``prior``: its box's kind (what widens it)."""
    from ..model import EFFECTS
    from ..posterior.evidence import bf_text, box_cuts, edges, effect_verdict

    edge = edges(post) != ""
    cut = list(post.loc[edge, "parameter"])
    widen = "simulate heaps beyond it" if prior == "heaps" else "widen the range in settings.toml"
    pressed = (f" Pressed against an edge of its range, so cut by it: {words(cut)} ({widen}, "
               "or the model lacks an effect)." if cut else "")
    boxed = str(box_cuts(post).iloc[0]) if len(post) else ""
    if "decided" in post.columns and not bool(post["decided"].iloc[0]):
        return (" The posterior gives no verdict yet: the surrogate is unsure where it lies (its variance there "
                f"{num(post['surrogate_ratio'].iloc[0], 2)}x the measured means').{pressed}")
    off = favoured_off(post) & (boxed == "")  # a Bayes factor the box cuts favours nothing
    ident = list(post.loc[post["identified"].astype(bool) & ~off, "parameter"])
    loose = list(post.loc[~post["identified"].astype(bool) & ~edge & ~off, "parameter"])
    why = ("known inside the box only, which cuts the posterior" if boxed
           else "not identified (90 % interval over a fifth of its range)")
    text = (f" Identified by the data: {words(ident)}." if ident else "") + \
        (f" {why[0].upper() + why[1:]}: {words(loose)}." if loose else "") + pressed
    owner = {e.parameter: e.name for e in EFFECTS.values()}
    said = {"on": "the data call for it", "off": "the data favour it off", "open": "the data do not decide",
            "undecided": "undecided, the surrogate is unsure where the posterior lies",
            "cut": "no verdict while the box cuts the posterior"}
    for r in post[post["bf_off"].notna()].itertuples(index=False) if "bf_off" in post.columns else []:
        upper = bool(getattr(r, "bf_upper", False))
        word = effect_verdict(r.bf_off, upper, bool(getattr(r, "decided", True)), boxed)
        text += (f" {esc(owner.get(r.parameter, r.parameter)).capitalize()}: {said.get(word, '')} "
                 f"(Bayes factor of off {esc(bf_text(r.bf_off, upper))}).")
    return text


def headline(f: RunFiles, fit: Fit) -> str:
    post = f.table("posterior/summary.parquet")
    params = solution_params(f)
    undecided = post is not None and len(post) and "decided" in post.columns and not bool(post["decided"].iloc[0])
    if post is not None and len(post):
        # no verdict while the surrogate is unsure: not "calibrated" either
        some = "identified" not in post.columns or bool(post["identified"].astype(bool).any())
        what = (f"Calibrat{'ing' if undecided else 'ed'}" if some or undecided else "The posterior of") \
            + f" {words(list(post['parameter']))}"  # "calibrated" only where the data pin something
        extra = _posterior_clause(post, str(f.prov("posterior/summary.parquet").get("prior", "settings")))
    elif params:
        what = f"The surrogate's best fit (GA) of {words(params)}"
        extra = _loose_clause(f)
    else:
        ran = [s for s in ("measure", "pb", "ascent", "bbd", "surrogate") if f.has_dir(s)]
        return (f"<p class=lead>{badge('not calibrated', 'info')} <b>No calibration in this run directory yet</b> "
                f"(<code>calib calibrate</code> has not run); stages here: {esc(', '.join(ran) or 'none')}.</p>")
    kind, sentence = verdict(f, fit)
    if undecided and fit.kind == "compare":  # a point of a posterior that is still undecided
        sentence = ("At the most probable draw of a posterior still undecided (the surrogate is unsure there, so it "
                    "may move), " + sentence[0].lower() + sentence[1:])
    label, cls = {"pass": ("fits", "pass"), "chance": ("consistent", "info"), "reached": ("reached", "info"),
                  "fail": ("misfit", "fail"), "info": ("unchecked", "info")}[kind]
    return (f"<p class=lead><b>{what}</b> against {_against(f)}{': undecided so far' if undecided else ''}.</p>"
            f"<p class=lead>{badge(label, cls)} {sentence}{_diagnosis_clause(f)}{extra}</p>")
