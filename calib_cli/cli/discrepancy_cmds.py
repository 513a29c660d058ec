"""`calib model`, `calib compare`, `calib diagnose`, `calib synth-lab`: the discrepancy loop (SPEC 6)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated, Optional

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import typer  # noqa: E402

from .. import artifacts as art  # noqa: E402
from ..campaign import CACHE_SOURCE, RUNS, Request, derive_seed, run_campaign  # noqa: E402
from ..dem.heap import CONDITION_VARIABLES, FLOOR_VARIABLES, LAWS, HeapCondition  # noqa: E402
from ..discrepancy.stats import (at_bounds, confounded, difference_se, per_condition, residual_table,  # noqa: E402
                                 score_effects, signature_noise, summary, trends)
from ..errors import CalibError  # noqa: E402
from ..model import EFFECTS, Model, load_model, save_model  # noqa: E402
from .common import (ForceOpt, RunOpt, ShearModulusOpt, bbd_fixed, check_run_dir, console, df_table, handle_errors,
                     heap_preset, heap_setup, modulus_settings, resolve_settings, skipped, space_from_design,
                     warn_other_modulus)  # noqa: E402
from .simulate_cmd import _condition, _pairs, _params, condition_from_row  # noqa: E402

model_app = typer.Typer(help="The model: a named set of physical effects (SPEC 6).", no_args_is_help=True)
COND_VARS = list(CONDITION_VARIABLES)
PresetOpt = Annotated[Optional[str], typer.Option(help="smoke | default | paper: geometry not given by the conditions "
                     "table, and numerics. Default: the run's setting heap.preset, else default.", show_default=False)]
RepeatsOpt = Annotated[int, typer.Option(min=1, help="Simulations per condition (seeds).")]
WorkersOpt = Annotated[int, typer.Option(min=1, help="Parallel simulations.")]
SetOpt = Annotated[Optional[list[str]], typer.Option("--set", help="Calibrated parameter KEY=VALUE (default: "
                                                     "RUN/invert/solution.parquet).")]


def _show(m: Model) -> None:
    rows = [{"effect": e.name, "in model": e.name in m.effects, "parameter": e.parameter, "low": e.low,
             "high": e.high, "neutral": "= particle value" if math.isnan(e.neutral) else e.neutral,
             "what": e.description} for e in EFFECTS.values()]
    console.print(df_table(pd.DataFrame(rows), f"model revision {m.revision}: {', '.join(m.effects)}"))


@model_app.command("show")
@handle_errors
def model_show(run: RunOpt):
    """Print the model's effects (RUN/model.toml; the default model if there is none)."""
    _show(load_model(check_run_dir(run)))


@model_app.command("add")
@handle_errors
def model_add(effect: str, run: RunOpt):
    """Add an effect: writes a new revision of RUN/model.toml (old ones kept in RUN/model/)."""
    run = check_run_dir(run)
    m = load_model(run)
    if effect not in EFFECTS:
        raise CalibError(f"unknown effect {effect!r}; known: {', '.join(EFFECTS)}")
    if effect in m.effects:
        raise CalibError(f"{effect} is already in the model")
    new = save_model(run, Model((*m.effects, effect), m.revision, f"added {effect}"))
    _show(new)


@model_app.command("remove")
@handle_errors
def model_remove(effect: str, run: RunOpt):
    """Remove an effect (its parameter returns to its neutral value): a new revision."""
    run = check_run_dir(run)
    m = load_model(run)
    if effect not in m.effects:
        raise CalibError(f"{effect} is not in the model ({', '.join(m.effects)})")
    new = save_model(run, Model(tuple(e for e in m.effects if e != effect), m.revision, f"removed {effect}"))
    _show(new)


def _conditions(run: Path) -> pd.DataFrame:
    p = run / "measure" / "conditions.parquet"
    c = art.read_table(p, columns=["condition_id", "mean", "sd", "n"],
                       what="measured conditions (run `calib measure-angle` first)")
    if (c["n"] < 1).any():
        raise CalibError(f"condition(s) {', '.join(c.loc[c['n'] < 1, 'condition_id'])} have no measured angle")
    return c


def _model_and_theta(run: Path, set_: Optional[list[str]]) -> tuple[Model, dict[str, float]]:
    """The model and its calibrated parameter values: the BBD's fixed values < the inversion's
    solution < --set. Without a model file (revision 0) simulate-heap pins nothing, so an effect
    the calibration switched on (a non-neutral value, e.g. surface_energy 0.5) joins the model."""
    model = load_model(run)
    given = _params(_pairs(set_, "--set")) if set_ else {}
    sol = run / "invert" / "solution.parquet"
    known = {e.parameter for e in EFFECTS.values()}
    base = {}
    if sol.is_file():
        s = art.read_table(sol).iloc[0]
        base = {k: float(s[k]) for k in s.index if k in known}
    # parameters the response surface held fixed keep their fixed values (the surrogate and
    # the inversion know nothing else about them)
    fixed = {k: v for k, v in bbd_fixed(run, resolve_settings(run, None, None)).items() if k in known or k in LAWS}
    theta = {**fixed, **base, **given}
    if model.revision == 0:
        used = [e.name for e in EFFECTS.values() if e.name not in model.effects and e.parameter in theta
                and not (e.neutral == e.neutral and theta[e.parameter] == e.neutral)]
        if used:
            model = Model((*model.effects, *used), 0, f"default model + {', '.join(used)} (set by the calibration)")
    missing = [p for p in model.parameters if p not in theta]
    if missing:
        raise CalibError(f"no calibrated value for {', '.join(missing)}: run `calib invert` or pass --set NAME=VALUE")
    # with the contact laws the BBD's heaps had (or --set gives): its surrogate learnt those
    return model, {**{p: theta[p] for p in model.parameters}, **{k: theta[k] for k in LAWS if theta.get(k)}}


def _simulate(run, model, theta, conds, preset, repeats, workers, tag, seed=0, shear_modulus=None):
    """Mean, sd, n of the simulated angle per condition at parameters theta."""
    pre = heap_preset(preset, shear_modulus)
    reqs = []
    for i, (_, row) in enumerate(conds.iterrows(), start=1):
        c = condition_from_row(pre.condition, row)
        for r in range(repeats):
            reqs.append(Request(model.pin(theta), c,
                                pre.numerics, derive_seed(seed, i, r), preset, tag, i, r, model.hash,
                                str(row["condition_id"])))
    rows = run_campaign(reqs, run, workers)
    return per_condition(rows, conds["condition_id"]), rows


def compare(run: RunOpt, set_: SetOpt = None, preset: PresetOpt = None, repeats: RepeatsOpt = 3,
            workers: WorkersOpt = 1, shear_modulus: ShearModulusOpt = None, force: ForceOpt = False):
    """Calibrated model vs measurements per condition: residuals in units of the combined
    uncertainty (pile-to-pile scatter pooled over the conditions), failing conditions (|z| > 2),
    RMSE and chi2/dof, and the error history across model revisions.

    Reads RUN/measure/conditions.parquet, RUN/invert/solution.parquet (or --set; parameters the
    BBD held fixed keep their fixed values), RUN/model.toml (without it: the default effects plus
    any the calibration switched on).
    Writes RUN/compare/residuals.parquet, adds the revision's row to RUN/compare/history.parquet
    (a rerun of the same revision replaces its row), and plots residuals.png, history.png.
    Skipped when the revision's parameters, conditions, settings and kernel are unchanged.
    """
    run = check_run_dir(run)
    preset, shear_modulus = heap_setup(resolve_settings(run, None, None), preset, shear_modulus)
    model, theta = _model_and_theta(run, set_)
    conds = _conditions(run)
    warn_other_modulus(run, shear_modulus, "the comparison's")
    # the kernel's source too: the heaps would change with it, though nothing in the run dir does
    st = art.Stage(run, "compare", f"rev{model.revision}",
                   inputs={"conditions": run / "measure" / "conditions.parquet"},
                   settings={"theta": theta, "model": model.hash, "preset": preset, "repeats": repeats,
                             "kernel": CACHE_SOURCE, **modulus_settings(shear_modulus)})
    hist_path = run / "compare" / "history.parquet"
    hist = art.read_table(hist_path) if hist_path.is_file() else pd.DataFrame()
    if st.up_to_date() and not force and len(hist) and (hist["revision"] == model.revision).any():
        return skipped(st)
    console.print(f"model revision {model.revision} ({', '.join(model.effects)}); {len(conds)} condition(s) x "
                  f"{repeats} simulations")
    sim, _ = _simulate(run, model, theta, conds, preset, repeats, workers, "compare", shear_modulus=shear_modulus)
    res = residual_table(conds["mean"], conds["sd"], conds["n"], sim["mean"].to_numpy(), sim["sd"].to_numpy(),
                         sim["n"].to_numpy())
    table = pd.DataFrame({"condition_id": conds["condition_id"].astype(str), "measured": conds["mean"],
                          "measured_sd": conds["sd"], "measured_n": conds["n"], "simulated": sim["mean"].to_numpy(),
                          "simulated_sd": sim["sd"].to_numpy(), "simulated_n": sim["n"].to_numpy(),
                          **{k: res[k].to_numpy() for k in ("residual", "uncertainty", "z", "fails")}})
    for c in COND_VARS:
        if c in conds.columns:
            table[c] = conds[c].to_numpy()
    summ = summary(res, len(model.parameters))
    if len(hist):  # one row per revision: a rerun (more repeats, a recalibration) replaces its own
        hist = hist[hist["revision"] != model.revision]
    hist = pd.concat([hist, pd.DataFrame([{"revision": model.revision, "effects": ",".join(model.effects),
                                           "rmse": summ["rmse"], "chi2_dof": summ["chi2_dof"],
                                           "n_conditions": summ["n_conditions"], "n_fail": summ["n_fail"],
                                           **{f"param_{k}": v for k, v in theta.items()}}])], ignore_index=True)
    hist = hist.sort_values("revision", kind="stable").reset_index(drop=True)
    vars_ = [c for c in COND_VARS if c in table.columns and table[c].nunique() > 1]
    fig1, axes = plt.subplots(1, max(len(vars_), 1), figsize=(4.5 * max(len(vars_), 1), 4), squeeze=False)
    for ax, v in zip(axes[0], vars_ or ["condition_id"]):
        x = table[v] if v in table.columns else np.arange(len(table))
        ax.errorbar(x, table["residual"], yerr=2 * table["uncertainty"], fmt="o", capsize=3)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xlabel(v)
        ax.set_ylabel("measured - simulated [deg] (+-2u)")
    fig1.suptitle(f"residuals, model revision {model.revision}")
    fig2, ax = plt.subplots(figsize=(6, 4))
    ax.plot(hist["revision"].astype(str) + "\n" + hist["effects"].str.replace(",", "\n"), hist["rmse"], "o-")
    ax.set_ylabel("RMSE over conditions [deg]")
    ax.set_title("error per model revision")
    with st.commit() as out:
        out.table("residuals.parquet", table, model_revision=model.revision, model=list(model.effects))
        out.figure("residuals.png", fig1)
    art.write_table(hist_path, hist, {"stage": "compare.history"})
    fig2.savefig(run / "compare" / "history.png", dpi=120, bbox_inches="tight")
    plt.close(fig2)
    console.print(df_table(table[["condition_id", "measured", "measured_sd", "simulated", "simulated_sd", "residual",
                                  "z", "fails"]], f"model vs measurements (revision {model.revision})"))
    console.print(f"RMSE {summ['rmse']:.2f} deg, chi2/dof {summ['chi2_dof']:.2f}, "
                  f"{summ['n_fail']} of {summ['n_conditions']} condition(s) fail (|z| > 2)")
    if len(hist) > 1:
        console.print(df_table(hist[["revision", "effects", "rmse", "chi2_dof", "n_fail"]], "error history"))


def diagnose(run: RunOpt, set_: SetOpt = None, preset: PresetOpt = None, repeats: RepeatsOpt = 3,
             workers: WorkersOpt = 1, shear_modulus: ShearModulusOpt = None,
             alpha: Annotated[float, typer.Option(min=0.0, max=1.0, help="Family-wise significance level: each "
                                                  "candidate is tested at alpha / the number of candidates "
                                                  "(Bonferroni).")] = 0.05, force: ForceOpt = False):
    """Rank the effects missing from the model by how much of the misfit each would explain
    (score test after projecting out what the current parameters absorb), with the evidence.

    Reads RUN/compare/residuals.parquet (run `calib compare` first), the calibrated parameters and
    RUN/model.toml. Writes RUN/diagnose/ranking.parquet (effect, score, p_value, explained_fraction,
    signature_p, verdict, evidence) and sensitivities.parquet. The verdict is "significant" when the
    test passes (p below alpha over the number of candidates) and the candidate's signature is
    resolved from the heaps' scatter, "unresolved" when the test passes but the signature is not
    (rerun with more --repeats), else "not significant".
    Runs go through the simulation cache; skipped when the comparison, parameters, settings and
    kernel are unchanged.
    """
    run = check_run_dir(run)
    preset, shear_modulus = heap_setup(resolve_settings(run, None, None), preset, shear_modulus)
    model, theta = _model_and_theta(run, set_)
    res = art.read_table(run / "compare" / "residuals.parquet", what="comparison (run `calib compare` first)")
    conds = _conditions(run)
    warn_other_modulus(run, shear_modulus, "the diagnosis's")
    st = art.Stage(run, "diagnose", "rank", inputs={"residuals": run / "compare" / "residuals.parquet"},
                   settings={"theta": theta, "model": model.hash, "preset": preset, "repeats": repeats,
                             "alpha": alpha, "kernel": CACHE_SOURCE, **modulus_settings(shear_modulus)})
    if st.up_to_date() and not force:
        return skipped(st)
    cands = model.candidates
    if len(conds) <= len(model.parameters):
        raise CalibError(f"diagnose needs more conditions ({len(conds)}) than calibrated parameters "
                         f"({len(model.parameters)}): otherwise the current parameters can absorb any pattern of "
                         "residuals and no missing effect can be told apart. Measure heaps under more conditions.")
    two_sided = [e for e in cands if EFFECTS[e].two_sided]
    n_sims = (len(model.parameters) + len(cands) + len(two_sided)) * len(conds) * repeats
    console.print(f"diagnose: {len(model.parameters)} sensitivities + {len(cands)} candidate effects "
                  f"({len(two_sided)} stepped both ways) x {len(conds)} conditions x {repeats} repeats = {n_sims} "
                  "simulations (cached runs are reused)")
    base, _ = _simulate(run, model, theta, conds, preset, repeats, workers, "compare", shear_modulus=shear_modulus)
    b = base["mean"].to_numpy()
    J, G = [], {}
    for e in model.effects:
        eff = EFFECTS[e]
        h = eff.step if theta[eff.parameter] + eff.step <= eff.high else -eff.step
        sim, _ = _simulate(run, model, {**theta, eff.parameter: theta[eff.parameter] + h}, conds, preset, repeats,
                           workers, f"sens-{e}", shear_modulus=shear_modulus)
        J.append((sim["mean"].to_numpy() - b) / h)
    starts, G_se = {}, {}
    for e in cands:
        eff = EFFECTS[e]
        down, up = eff.probe(theta)
        starts[e] = eff.start(theta)
        m2 = Model((*model.effects, e), model.revision)
        sim, _ = _simulate(run, m2, {**theta, eff.parameter: up}, conds, preset, repeats, workers, f"cand-{e}",
                           shear_modulus=shear_modulus)
        if eff.two_sided:  # a central difference (Effect.probe): both ends simulated
            dn, _ = _simulate(run, m2, {**theta, eff.parameter: down}, conds, preset, repeats, workers,
                              f"cand-{e}-down", shear_modulus=shear_modulus)
            G[e] = (sim["mean"].to_numpy() - dn["mean"].to_numpy()) / (up - down)
            G_se[e] = difference_se(sim, dn, up - down)
        else:  # a forward step from neutral: the model's own simulations stand there
            G[e] = (sim["mean"].to_numpy() - b) / eff.step
            G_se[e] = difference_se(sim, base, eff.step)
    J = np.column_stack(J) if J else np.zeros((len(b), 0))
    r_all, u_all = res["residual"].to_numpy(float), res["uncertainty"].to_numpy(float)
    ok = np.isfinite(r_all) & np.isfinite(u_all) & np.all(np.isfinite(J), axis=1)
    for g in G.values():
        ok &= np.isfinite(g)
    if not ok.all():
        dropped = ", ".join(conds["condition_id"].astype(str)[~ok])
        console.print(f"[yellow]warning:[/] left out condition(s) {dropped}: a simulation formed no heap there "
                      "or the uncertainty is unknown")
    if ok.sum() <= J.shape[1]:
        raise CalibError(f"only {int(ok.sum())} usable condition(s) for {J.shape[1]} parameters: cannot diagnose")
    J, G, G_se = J[ok], {k: g[ok] for k, g in G.items()}, {k: v[ok] for k, v in G_se.items()}
    # the current parameters can absorb misfit only within the ranges the calibration searched
    sp = space_from_design(run / "bbd" / "design.parquet")
    ranges = {}
    for e in model.effects:  # in J's column order
        q = EFFECTS[e].parameter
        ranges[q] = (sp[q].low, sp[q].high) if sp is not None and q in sp.names else (EFFECTS[e].low, EFFECTS[e].high)
    pars = list(ranges)
    lo = np.array([ranges[q][0] - theta[q] for q in pars])
    hi = np.array([ranges[q][1] - theta[q] for q in pars])
    cand_b = {e: (EFFECTS[e].low - starts[e], EFFECTS[e].high - starts[e]) for e in G}
    edge = at_bounds(theta, ranges)
    for q, side in edge.items():
        console.print(f"[yellow]note:[/] {q} = {theta[q]:.4g} is at the {side} end of its range "
                      f"[{ranges[q][0]:.4g}, {ranges[q][1]:.4g}]: it cannot absorb misfit beyond it, so the test "
                      "keeps each parameter inside its range (a residual it cannot reach is evidence of a "
                      "missing effect, or of a range set too narrow)")
    ranking = score_effects(r_all[ok], u_all[ok], J, G, bounds=(np.minimum(lo, 0.0), np.maximum(hi, 0.0)),
                            cand_bounds=cand_b)
    # as in the ranking, a parameter stuck at the edge of its range absorbs nothing: judge the
    # candidates' signatures after projecting out only the parameters that are free to move
    free = [k for k, q in enumerate(pars) if q not in edge]
    for a, c in confounded(u_all[ok], J[:, free], G):
        console.print(f"[yellow]warning:[/] {a} and {c} leave the same signature across these conditions: "
                      "the data cannot tell them apart; add conditions that separate them")
    # a signature within the scatter of the heaps that measured it ranks noise (discrepancy/stats.py)
    ranking["signature_p"] = [signature_noise(G[e], G_se[e])[1] for e in ranking["effect"]]
    tr = trends(res[ok], res.loc[ok, [c for c in COND_VARS if c in res.columns]])
    top = tr.sort_values("p_value").iloc[0] if len(tr) else None
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
            console.print(f"[yellow]warning:[/] {r['effect']}'s signature is not resolved from the pile-to-pile "
                          f"scatter with {repeats} heap(s) a step (p = {r['signature_p']:.2g} that it is zero): its "
                          "rank is noise; rerun with more --repeats (cached heaps are reused)")
            txt += (f"; its signature is within the simulation noise (p = {r['signature_p']:.2g}): "
                    "the rank is unreliable")
        if top is not None and verdict == "significant":
            way = "grows" if top["slope"] > 0 else "falls"
            txt += f"; observed: the residual {way} with {top['variable']} (p = {top['p_value']:.3g})"
        words.append(txt)
    ranking["verdict"] = verdicts
    ranking["evidence"] = words
    sens = pd.DataFrame({"condition_id": conds["condition_id"].astype(str)[ok].to_numpy()})
    for k, e in enumerate(model.effects):
        sens[f"d_{EFFECTS[e].parameter}"] = J[:, k]
    for e, g in G.items():
        sens[f"candidate_{e}"] = g
    with st.commit() as out:
        out.table("ranking.parquet", ranking[["effect", "score", "p_value", "explained_fraction", "signature_p",
                                              "verdict", "evidence"]],
                  model_revision=model.revision)
        out.table("sensitivities.parquet", sens)
        out.table("trends.parquet", tr)
    console.print(df_table(ranking[["effect", "score", "p_value", "explained_fraction", "signature_p"]],
                           f"missing effects, ranked (model revision {model.revision})"))
    for _, r in ranking.iterrows():
        console.print(f"[bold]{r['effect']}[/]: {r['evidence']}")
    if (ranking["verdict"] == "unresolved").any() and not (ranking["verdict"] == "significant").any():
        console.print("No missing effect is both significant and resolved: the candidates that pass the test leave "
                      "signatures within the heaps' scatter; rerun with more --repeats before adding one.")
    elif not (ranking["p_value"] < bar).any():
        console.print("No missing effect is significant: the misfit is within what the measurement noise explains.")


def floor_condition(base: HeapCondition, spec: str) -> HeapCondition:
    """``steel:static_friction=0.3,rolling_friction=0.05`` -> the base condition on that floor."""
    name, sep, rest = spec.partition(":")
    if not sep or not name.strip() or not rest.strip():
        raise CalibError(f"--floor {spec!r} is not NAME:KEY=VALUE,...")
    vals = {f"floor_{k}": v for k, v in _pairs(rest.split(","), f"--floor {name}:").items()}
    if set(vals) - set(FLOOR_VARIABLES):
        raise CalibError(f"--floor {spec!r}: the keys are {', '.join(k.removeprefix('floor_') for k in FLOOR_VARIABLES)}")
    return _condition(base, {"floor": name.strip(), **vals})


def synth_lab(
    out: Annotated[Path, typer.Option(help="Folder for the lab's photographs, conditions.csv and truth.toml.")],
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="True parameter KEY=VALUE (repeatable), "
                    "including the hidden effect's, e.g. --set surface_energy=0.8.")] = None,
    hidden: Annotated[str, typer.Option(help="Name of the hidden effect (recorded in truth.toml only).")] = "cohesion",
    sizes: Annotated[str, typer.Option(help="Particle size ranges d_min-d_max (mm), comma separated.")] = "5-6,6-8,8-10",
    cylinders: Annotated[str, typer.Option(help="Cylinder diameters (mm), comma separated.")] = "50",
    fill_ratio: Annotated[float, typer.Option(help="Fill height / cylinder diameter (without --fills).")] = 1.0,
    fills: Annotated[Optional[str], typer.Option(help="Fill heights (mm), comma separated, crossed with the sizes "
                     "and cylinders: heap size is where cohesion leaves a signature friction cannot mimic.")] = None,
    repeats: RepeatsOpt = 3,
    preset: Annotated[str, typer.Option(help="smoke | default | paper: geometry not given by the conditions, and "
                      "numerics.")] = "smoke",
    workers: WorkersOpt = 1,
    shear_modulus: ShearModulusOpt = None,
    floor: Annotated[Optional[list[str]], typer.Option("--floor", help="A floor material NAME:KEY=VALUE,... "
                     "(repeatable; keys static_friction, rolling_friction, surface_energy, restitution against the "
                     "grains), crossed with the other conditions, e.g. --floor steel:static_friction=0.3 --floor "
                     "rubber:static_friction=0.9. Without it the floor takes the walls' values.")] = None,
    noise: Annotated[float, typer.Option(help="Image noise sd (grey levels).")] = 6.0,
    seed: Annotated[int, typer.Option(help="Seed of the lab's heaps and noise.")] = 7,
):
    """Synthetic measurements with a hidden effect: DEM heaps under several conditions, rendered
    as photographs with image noise, a conditions.csv, and truth.toml (which no stage reads)."""
    import cv2
    import tomli_w

    from ..dem.render import render_side_view

    truth = _params(_pairs(set_, "--set")) if set_ else {}
    pre = heap_preset(preset, shear_modulus)
    floors = [floor_condition(pre.condition, f) for f in floor] if floor else [pre.condition]
    conds = []
    try:
        heights = [float(h) for h in fills.split(",")] if fills else [None]
        for s in sizes.split(","):
            lo, hi = (float(v) for v in s.split("-"))
            for d in cylinders.split(","):
                D = float(d)
                for H in heights:
                    for fc in floors:
                        cid = f"d{s}_D{D:g}" + (f"_H{H:g}" if H is not None else "") + (f"_{fc.floor}" if floor else "")
                        conds.append((cid, dataclasses.replace(fc, particle_d_min_mm=lo, particle_d_max_mm=hi,
                                                               cylinder_diameter_mm=D,
                                                               fill_height_mm=D * fill_ratio if H is None else H)))
    except ValueError as e:
        raise CalibError(f"--sizes, --cylinders, --fills: expected numbers like 5-6,6-7 / 40,48 / 50,100 ({e})")
    reqs = [Request(truth, c, pre.numerics, derive_seed(seed, i, r), preset, "lab", i, r, "truth", cid)
            for i, (cid, c) in enumerate(conds, start=1) for r in range(repeats)]
    for _, c in conds:
        c.validate()
    work = out / ".runs"
    rows = run_campaign(reqs, work, workers)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    # the floor's label and values only where the lab has floors: an empty cell is no condition value
    cvars = [k for k in COND_VARS if k not in FLOOR_VARIABLES or any(k in c.floor_values() for _, c in conds)]
    cvars += ["floor"] if floor else []
    lines = ["image," + "condition_id," + ",".join(cvars)]
    for (_, row), req in zip(rows.iterrows(), reqs):
        st = art.read_table(work / RUNS / row["run_hash"] / "state.parquet")
        img = render_side_view(st[["x", "y", "z"]].to_numpy(), st["radius"].to_numpy(), px_per_m=6000).image
        img = np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
        name = f"{req.condition_id}_r{req.repeat + 1}.png"
        cv2.imwrite(str(out / name), img)
        c = req.condition
        lines.append(f"{name},{req.condition_id}," + ",".join(str(getattr(c, k)) for k in cvars))
    (out / "conditions.csv").write_text("\n".join(lines) + "\n")
    (out / "truth.toml").write_text("# the truth of this synthetic lab: no stage reads this file\n" + tomli_w.dumps(
        {"hidden_effect": hidden, "parameters": truth, "preset": preset, "seed": seed,
         **modulus_settings(shear_modulus),
         "angles": {f"{r.condition_id}_r{r.repeat + 1}": float(a) for r, a in zip(reqs, rows["repose_angle"])}}))
    ok = rows["status"].eq("ok").sum()
    console.print(f"[green]✓[/] {len(rows)} heaps ({ok} formed) in {len(conds)} conditions -> {out}")
