"""The first screen's cards, each readable on its own and each saying what to run when its stage is missing."""

from __future__ import annotations

import math
import shlex

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..model import EFFECTS
from ..posterior.evidence import bf_text, box_cuts, cut_words, edges, effect_verdict
from ..posterior.suggest import any_ranked, best_per_effect, simulate_command, unsettled_words, unsettling
from .chart import fit_chart, legend
from .html import RunFiles, badge, deg, esc, note, num, prose, rows_table
from .summary import PINNED, Fit, favoured_off, solution_params


def card(title: str, body: str, cls: str = "") -> str:
    return f"<div class='card {cls}'><h3>{title}</h3>{body}</div>"


def _missing(cmd: str, what: str) -> str:
    return note(f"Not run yet: <code>{esc(cmd)}</code> {what}.")


def _ga_state(p: str, w: float, post, value: float = math.nan, edge: str = "") -> str:
    """The GA point's badge, as the posterior's row reads (:func:`_posterior_rows`, in its order): pinned only
    where the posterior identifies the parameter and the point lies in its 90 % interval. Without a posterior,
    a point at ``edge`` ("low"/"high") of the box the surrogate was fitted on is said first: the targets
    may want a value beyond it, and a narrow spread there is the box's, not the data's."""
    if post is not None and p in post.index:
        r = post.loc[p]
        if not bool(r.get("decided", True)):
            return badge("posterior undecided", "warn")
        if str(edges(post).loc[p]):
            return badge("posterior at its range's edge", "warn")
        if box_cuts(post).iloc[0]:
            return badge("the box cuts the posterior", "warn")
        if bool(favoured_off(post.loc[[p]])[0]):
            return badge("posterior: off", "warn")
        if not bool(r["identified"]):
            return badge("posterior wide", "warn")
        if not r["q05"] <= value <= r["q95"]:
            return badge("outside the posterior's 90 %", "warn")
        return badge("pinned", "pass")
    if edge:
        return badge(f"at {'lower' if edge == 'low' else 'upper'} edge", "fail")  # as a posterior row says it
    return badge("narrow", "info") if w <= PINNED else badge("loose", "warn")


def _breakable(name: str) -> str:
    """A parameter's name that may wrap after its underscores (wall_static_friction in a narrow card)."""
    return esc(name).replace("_", "_<wbr>")


def _unit(name: str) -> str:
    """A parameter's unit as its declaration gives it (calib_cli.parameters; a contact law's own value by its
    effect), escaped; empty where it has none."""
    from ..parameters import QUANTITIES

    q = QUANTITIES.get(name)
    unit = q.unit if q is not None else next((e.unit for e in EFFECTS.values() if e.parameter == name), "")
    return esc("" if unit == "-" else unit)


def params_card(f: RunFiles) -> str:
    """The GA's point (the surrogate's best fit) with each parameter's near-optimal range; fixed values; how
    it was validated. Called pinned only where the posterior identifies the parameter."""
    params = solution_params(f)
    if not params:
        return ""
    rng = f.table("invert/ranges.parquet")
    rng = rng.set_index("parameter") if rng is not None else pd.DataFrame()
    post = f.table("posterior/summary.parquet")
    post = post.set_index("parameter") if post is not None and len(post) else None
    at_edge = _search_edges(f, params)
    rows, outside = [], []
    for p, v in params.items():
        if p in rng.index:
            lo, hi, w = rng.loc[p, ["low", "high", "width_fraction"]]
            out = not (lo - 1e-9 * abs(lo) <= v <= hi + 1e-9 * abs(hi))
            outside += [p] if out else []
            rows.append([_breakable(p), f"<b>{num(v)}</b>", f"{num(lo, 3)}&ndash;{num(hi, 3)}{'*' if out else ''}",
                         _unit(p), f"{w:.0%}".replace("%", " %"), _ga_state(p, w, post, v, at_edge.get(p, ""))])
        else:
            rows.append([_breakable(p), f"<b>{num(v)}</b>", "", _unit(p), "", ""])
    head = ["parameter", "value", "near-optimal", "unit", "spread", ""]
    if not any(r[3] for r in rows):  # all dimensionless: the column would only widen the card past its edge
        head, rows = head[:3] + head[4:], [r[:3] + r[4:] for r in rows]
    body = rows_table(head, rows, "compact")
    tol = f.prov("invert/solution_set.parquet").get("tolerance")
    body += note(f"Near-optimal: surrogate within {num(tol, 3) if tol else 'the tolerance'}&deg; of the best fit; "
                 "spread as a share of the search range. A narrow spread is the surrogate's, not the data's: "
                 + ("the posterior says how well the data pin each parameter." if post is not None else
                    "no posterior here says how well the data pin them (<code>calib calibrate</code>)."), "prov")
    if outside:
        body += note(f"* {esc(', '.join(outside))}: the solution lies outside the surrogate's near-optimal range, "
                     "moved there by the refinement by simulation.", "prov")
    said = f.prov("invert/solution.parquet").get("warnings") or []
    body += "".join(note("invert: " + esc(str(w)), "prov") for w in said)
    return card("The surrogate's best fit (GA)", body + _held_out(f) + _fixed_and_validation(f, params))


def _search_edges(f: RunFiles, params: dict) -> dict[str, str]:
    """The GA point's parameters within 2 % of an edge of the box its surrogate was fitted on
    (surrogate/best.json's inputs, lows, highs; `invert` warns of the same)."""
    from ..discrepancy.stats import at_bounds

    best = f.path("surrogate/best.json")
    pick = art.read_json(best) if best else {}
    lists = [pick.get(k) if isinstance(pick, dict) else None for k in ("inputs", "lows", "highs")]
    if not all(isinstance(x, list) for x in lists):  # written by another version, or by hand: no box to say
        return {}
    box = {n: (lo, hi) for n, lo, hi in zip(*lists)
           if isinstance(n, str) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (lo, hi))}
    return at_bounds({p: v for p, v in params.items() if p in box}, box)


def _held_out(f: RunFiles) -> str:
    """How well the inverted surrogate predicts heaps it was not fitted to (leave-one-out): the scale a
    near-optimal tolerance of a fraction of a degree is to be read against."""
    m, sol = f.table("surrogate/metrics.parquet"), f.table("invert/solution.parquet")
    if m is None or sol is None or "model" not in sol.columns:
        return ""
    loo = m[(m["split"] == "loo") & (m["model"] == sol["model"].iloc[0])]
    if loo.empty:
        return ""
    r = loo.iloc[0]
    return note(f"The surrogate inverted ({esc(r['model'])}) predicts a heap it was not fitted to within RMSE "
                f"{deg(float(np.sqrt(r['mse'])))} (leave-one-out R&sup2; {num(r['r2'], 2)}).", "prov")


def _fixed_and_validation(f: RunFiles, params: dict) -> str:
    """Parameters the current model holds at fixed values, and the validation heaps' summary."""
    out = ""
    hist = f.table("compare/history.parquet")
    if hist is not None and len(hist):
        last = hist.iloc[-1]
        fixed = {c[6:]: last[c] for c in hist.columns if c.startswith("param_") and c[6:] not in params
                 and pd.notna(last[c])}
        if fixed:
            out += note("Held fixed: " + ", ".join(f"{esc(k)} = {num(v)}" for k, v in fixed.items()), "prov")
    val = f.table("invert/validation.parquet")
    if val is not None and len(val):
        rounds = int(val["round"].max()) + 1 if "round" in val.columns else 1
        chosen = f.prov("invert/solution.parquet").get("refine_round", 0)
        acc = f.prov("invert/refinement.parquet").get("accepted") if f.path("invert/refinement.parquet") else None
        out += note(f"Validated by {len(val)} heaps simulated at this solution over {rounds} "
                    f"round{'s' * (rounds != 1)}; "
                    f"the solution is round {esc(chosen)}'s"
                    + ("" if acc is None else (" (accepted)" if acc else " (closest; no round met the targets)"))
                    + ".", "prov")
    return out


def fit_card(f: RunFiles, fit: Fit) -> str:
    if fit.rows.empty:
        return card("Fit per condition", _missing("calib measure-angle", "measures the heaps"))
    sim = {"compare": "simulated", "validation": "simulated", "surrogate": "surrogate"}.get(fit.kind, "simulated")
    body = fit_chart(fit.rows) + legend(sim)
    rule = " Pass: |measured &minus; simulated| &le; 2 combined standard uncertainties" \
        + _uncertainty_words(f) + "." if fit.kind in ("compare", "validation") else ""
    said = f"Simulated: {fit.label}.{rule}" if fit.kind != "measured" else \
        "Measured only: no heap simulated at a calibrated point yet."
    return card("Fit per condition", body + note(said, "prov"))


def _uncertainty_words(f: RunFiles) -> str:
    """compare's combined standard uncertainty of a residual, which the pass rule uses: the whiskers are the
    piles' own sd, not it."""
    res = f.table("compare/residuals.parquet")
    if res is None or "uncertainty" not in res.columns or not np.isfinite(res["uncertainty"]).any():
        return ""
    u = res["uncertainty"].to_numpy(float)
    u = u[np.isfinite(u)]
    said = deg(float(u[0])) if np.ptp(u) < 1e-9 else f"{deg(float(u.min()))}&ndash;{deg(float(u.max()))}"
    return f" (u = {said} here, from both means' scatter; the whiskers are the piles' own sd)"


def _with_parameter(effect: str) -> str:
    """"sliding_friction (static_friction)": an effect with the parameter the posterior names, where they differ."""
    e = EFFECTS.get(effect)
    return f"{effect} ({e.parameter})" if e is not None and e.parameter != effect else effect


def history_card(f: RunFiles) -> str:
    """RMSE per model revision, each row naming the effects that revision added."""
    hist = f.table("compare/history.parquet")
    if hist is None or hist.empty:
        return card("Error across model revisions", _missing("calib compare", "measures the calibrated model's "
                                                               "error per condition"))
    rows, before = [], None
    for r in hist.itertuples(index=False):
        eff = str(r.effects).split(",")
        shown = ", ".join(map(_with_parameter, eff)) if before is None else \
            "+ " + ", ".join(_with_parameter(e) for e in eff if e not in before) if set(eff) - set(before) \
            else "(same effects)"
        before = eff
        # a count, not a verdict (the headline judges the conditions together): amber, not red
        failing = badge(f"{int(r.n_fail)} of {int(r.n_conditions)} |z| > 2", "warn" if r.n_fail else "pass")
        rows.append([str(int(r.revision)), esc(shown), deg(r.rmse), num(r.chi2_dof, 3), failing])
    return card("Error across model revisions",
                rows_table(["rev.", "effects", "RMSE", "&chi;&sup2;/dof", ""], rows, "compact"))


def ranking_card(f: RunFiles) -> str:
    rank = f.table("diagnose/ranking.parquet")
    if rank is None or rank.empty:
        return card("Missing effects, ranked", _missing("calib diagnose", "ranks candidate missing effects "
                                                         "from compare's residuals"))
    rev = f.prov("diagnose/ranking.parquet").get("model_revision", "?")
    kinds = {"significant": "fail", "unresolved": "warn", "not significant": "pass"}
    rows = []
    for r in rank.itertuples(index=False):
        v = getattr(r, "verdict", "")
        rows.append([esc(r.effect), badge(v, kinds.get(v, "info")) if v else "", num(r.p_value, 2),
                     f"{100 * r.explained_fraction:.0f} %"])
    return card("Missing effects, ranked", rows_table(["effect", "verdict", "p", "would explain"], rows, "compact")
                + note(f"Judged on model revision {esc(rev)}'s residuals; the evidence is under "
                       "<a href='#discrepancy'>Discrepancy loop</a>.", "prov"))


def _effect_badge(bf: float, upper: bool, decided: bool, cut: str = "") -> str:
    word = effect_verdict(bf, upper, decided, cut)
    # the effect called for is the finding, not a failure: not the misfit's red
    return {"on": badge("called for", "info"), "off": badge("favoured off", "pass"),
            "open": badge("not decided", "warn"),
            "undecided": badge("undecided: the surrogate is unsure", "warn"),
            "cut": badge("no verdict: the box cuts the posterior", "warn")}.get(word, "")


def _simulate_hint(f: RunFiles, ranking: pd.DataFrame) -> str:
    """The end of "Measure next"'s note where nothing is ranked: the command (the ranking's own, from its
    provenance) that simulates heaps at the two candidates with the largest unranked gains."""
    cmd = simulate_command(str(f.prov("suggest/ranking.parquet").get("command", "")), ranking,
                           f"calib suggest-conditions --run {shlex.quote(str(f.run))} --rig RIG.toml")
    return f". To rank the two largest gains, simulate heaps there: <code>{esc(cmd)}</code>." if cmd else "."


def _posterior_rows(post: pd.DataFrame) -> list[list[str]]:
    rows = []
    for r, edge, off, cut in zip(post.itertuples(index=False), edges(post), favoured_off(post), box_cuts(post)):
        decided = bool(getattr(r, "decided", True))
        at_edge = badge(f"at {'lower' if edge == 'low' else 'upper'} edge", "fail") if edge else ""
        state = (badge("undecided", "warn") + (" " + at_edge if at_edge else "") if not decided
                 else at_edge if edge
                 else badge("inside the box only", "warn") if cut
                 else badge(f"off, P(off) {r.p_off:.2f}", "pass") if off
                 else badge(f"identified, {100 * r.rel_width:.0f} % of range", "pass") if r.identified
                 else badge(f"{100 * r.rel_width:.0f} % of range", "warn"))
        rows.append([esc(r.parameter), num(r.median, 3), f"{num(r.q05, 3)} &ndash; {num(r.q95, 3)}",
                     _unit(r.parameter), state])
    return rows


def _effects_table(post: pd.DataFrame) -> str:
    """Each switchable effect the model gained: the Bayes factor of its being off, and the verdict."""
    owner = {e.parameter: e.name for e in EFFECTS.values()}
    eff = post[post["bf_off"].notna()] if "bf_off" in post.columns else post.iloc[:0]
    if eff.empty:
        return ""
    p_off = lambda r: getattr(r, "p_off", math.nan)  # noqa: E731  (a posterior averaged over it on and off)
    rows = [[esc(owner.get(r.parameter, r.parameter)), esc(bf_text(r.bf_off, bool(getattr(r, "bf_upper", False)))),
             num(p_off(r), 2) if np.isfinite(p_off(r))
             else "not averaged: the Bayes factor is a bound" if getattr(r, "bf_upper", False) else "&ndash;",
             _effect_badge(r.bf_off, bool(getattr(r, "bf_upper", False)), bool(getattr(r, "decided", True)), cut)]
            for r, cut in zip(eff.itertuples(index=False), box_cuts(eff))]
    return rows_table(["effect", "Bayes factor of off", "probability off (the intervals average it)", ""], rows,
                      "compact") + note("Bayes factor of off: how much more probable the data are with the effect "
                                        "off than with it on; below 0.1 they call for it, above 3 they favour it off "
                                        "(Jeffreys).", "prov")


_STOPS = {"budget": "its budget", "stable": "the stability rule"}  # calibrate's stop reasons, as a sentence reads them


def _rounds_note(f: RunFiles, rev) -> str:
    rounds = f.table("calibrate/rounds.parquet")
    if rounds is None or rounds.empty:
        return ""
    r = rounds[rounds["revision"] == rev] if "revision" in rounds.columns else rounds
    if r.empty:
        return ""
    last = r[r["round"] == r["round"].max()].iloc[0]
    why = str(last["stop"]).split(":")[0]
    own, learnt = int(last["calibration_heaps"]), int(last["heaps"])
    before = (f" ({learnt - own} of them simulated before this calibration and reused: an earlier revision's, "
              "compare's, diagnose's or other heaps of the model in the run)" if learnt > own else "")
    return note(f"<code>calib calibrate</code>: {int(last['round']) + 1} rounds, "
                f"{own} heaps simulated, the posterior on {learnt}{before}; "
                f"stopped by {esc(_STOPS.get(why, why))} "
                "(<a href='#posterior'>the intervals round by round</a>).", "prov")


def _point_note(f: RunFiles, rev) -> str:
    """The one parameter set to put into a DEM model: the posterior's most probable draw, which compare
    simulates (calibrate/point.parquet), where it is this revision's."""
    point = f.table("calibrate/point.parquet")
    if point is None or point.empty or f.prov("calibrate/point.parquet").get("model_revision") != rev:
        return ""
    post = f.table("posterior/summary.parquet")
    post = post.set_index("parameter") if post is not None and len(post) else pd.DataFrame()
    beyond = [p for p, v in point.iloc[0].items() if p in post.index
              and not post.loc[p, "q05"] <= float(v) <= post.loc[p, "q95"]]
    values = ", ".join(" ".join(filter(None, (esc(p), num(float(v), 3) + "*" * (p in beyond), _unit(p))))
                       for p, v in point.iloc[0].items())
    unsure = "decided" in post.columns and len(post) and not bool(post["decided"].iloc[0])
    return note(f"One set to simulate with (the posterior's most probable draw, what <code>calib compare</code> "
                f"simulates; <code>calibrate/point.parquet</code>): {values}."
                + (" The posterior is undecided, so this point may still move." if unsure else "")
                + (f" * {esc(', '.join(beyond))}: outside its own 90 % interval (the posterior's peak lies apart "
                   "from its bulk, as where it presses against an edge of its box)." if beyond else ""), "prov")


def _cut_note(cut: str, prior: str, decided: bool) -> str:
    """What the card says where the box cuts the posterior (``cut``: the summary's ``box_cut``)."""
    widen = ("Simulate heaps beyond those edges (the prior is the heaps' span) and run <code>calib calibrate</code>"
             if prior == "heaps" else "Widen each such range in settings.toml ([factors]) and run "
             "<code>calib calibrate</code> again")
    return (("No verdict: t" if decided else "T") + f"he box cuts the posterior at {esc(cut_words(cut))}, so the "
            "data may lie beyond it and the other parameters sit where they make up for the bound. " + widen
            + "; if the posterior follows the edge out to the parameter's physical bound, the model lacks an effect.")


def posterior_card(f: RunFiles) -> str:
    """The answer: each parameter's median and 90 % interval with its unit, whether identified, each added
    effect's Bayes factor, and what to measure next; or, without a posterior, the command that makes one."""
    post = f.table("posterior/summary.parquet")
    title = "Calibrated parameters: the posterior"
    if post is None or post.empty:
        return card(title, _missing("calib calibrate", "measures how well the data pin each parameter (a posterior "
                                    "given every condition) and which added effect they call for"))
    prov = f.prov("posterior/summary.parquet")
    rev = prov.get("model_revision", "?")
    used = ["each condition's mean angle"] + (["its piles' scatter"] if prov.get("scatter") else []) \
        + (["its photographs' heap profile"] if prov.get("profile") else [])
    body = rows_table(["parameter", "median", "90 % interval", "unit", ""], _posterior_rows(post), "compact")
    body += _effects_table(post)
    if "decided" in post.columns and not bool(post["decided"].iloc[0]):
        body += note(f"No verdict: where the posterior lies the surrogate's own variance is "
                     f"{num(post['surrogate_ratio'].iloc[0], 2)}x the measured means'; simulate heaps there "
                     "(<code>calib calibrate</code> with a larger budget).", "prov")
    cut = str(box_cuts(post).iloc[0])
    if cut:
        body += note(_cut_note(cut, prov.get("prior", "settings"),
                               "decided" not in post.columns or bool(post["decided"].iloc[0])), "prov")
    corner = (" Every pair of parameters: <a href='#posterior'>the posterior's corner plot</a>."
              if (f.run / "posterior" / "corner.png").is_file() else "")
    body += note(f"Model revision {esc(rev)}, {esc(prov.get('heaps', '?'))} simulated heaps, given "
                 f"{esc(', '.join(used[:-1]) + ' and ' + used[-1] if len(used) > 1 else used[0])}.{corner}", "prov")
    body += _rounds_note(f, rev) + _point_note(f, rev)
    nxt = f.table("suggest/ranking.parquet")
    if nxt is not None and not nxt.empty:
        body += "<h3>Measure next</h3>" + ("" if any_ranked(nxt) else note(
            "Not ranked yet: at each condition the rig offers, the gain and the separation are extrapolated beyond "
            "the simulated heaps and the measured conditions. Below, the first three in the rig's order, each with "
            "what to simulate first" + _simulate_hint(f, nxt), "prov")) + "".join(
            f"<p class=prov><b>{esc(r.condition_id)}</b>: {prose(r.reason)}</p>" for r in nxt.head(3).itertuples())
        open_ = unsettled_words(nxt)
        body += note(prose(open_[:1].upper() + open_[1:]) + ".", "prov") if open_ else ""
        body += "".join(f"<p class=prov>To tell {esc(e.replace('_', ' '))} apart: <b>{esc(cid)}</b> "
                        f"({sep:.2g} chi-square units, sensitivities {how}){esc(unsettling(sep))}</p>"
                        for e, cid, sep, how in best_per_effect(nxt))
    return card(title, body)
