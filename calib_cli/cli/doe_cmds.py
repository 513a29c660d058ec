"""`calib pb|ascent|bbd design|analyze`: thin wrappers over calib_cli.doe."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd
import typer

from .. import artifacts as art
from .. import plots
from ..doe import ascent as ascent_mod
from ..doe import bbd as bbd_mod
from ..doe import pb as pb_mod
from ..errors import CalibError
from ..settings import factor_space
from ..space import ParameterSpace
from .common import (ForceOpt, ResponsesOpt, RunOpt, SettingOpt, SettingsOpt, check_run_dir, console,
                     df_table, handle_errors, pvalue, resolve_settings, simulated_responses, skipped,
                     space_from_design)

pb_app = typer.Typer(help="Plackett-Burman screening (paper 3.1, Tables 2-4).", no_args_is_help=True)
ascent_app = typer.Typer(help="Steepest ascent toward the target (paper 3.2, Table 5).", no_args_is_help=True)
bbd_app = typer.Typer(help="Box-Behnken response surface (paper 3.3-3.4, Eq. 7, Table 8).", no_args_is_help=True)


def _fixed_values(cfg: dict, section: str, names: list[str]) -> dict[str, float]:
    """Natural values of factors held fixed: the section's `fixed` table, else the factor's centre."""
    given = cfg[section]["fixed"]
    space = factor_space(cfg, names)
    return {n: float(given.get(n, space[n].center)) for n in names}


def _load_responses(run: Path, responses: Optional[Path], design_path: Path, factors: list[str],
                    response: str) -> tuple[pd.DataFrame, dict]:
    if responses is not None:
        return art.read_responses(responses, factors, response), {"responses": responses}
    data = simulated_responses(run, design_path, factors, response)
    return data, {"design": design_path, "results": art.Rows(Path(run) / "simulate" / "results.parquet", data)}


def _anova_table(anova: pd.DataFrame, title: str):
    return df_table(anova, title, {"p_value": lambda p: pvalue(p) if np.isfinite(p) else ""})


# ------------------------------------------------------------------ pb
@pb_app.command("design")
@handle_errors
def pb_design(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Write the 12-run PB design. Reads settings [factors], [pb]; writes RUN/pb/design.parquet."""
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    space = factor_space(cfg, cfg["pb"]["factors"])
    st = art.Stage(run, "pb", "design", settings={"space": space.to_dicts(), "runs": cfg["pb"]["runs"]})
    if st.up_to_date() and not force:
        return skipped(st)
    df, _ = pb_mod.design(space, int(cfg["pb"]["runs"]))
    with st.commit() as out:
        out.table("design.parquet", df, space=space.to_dicts())
    console.print(df_table(df, f"Plackett-Burman design ({len(df)} runs) -> {st.dir / 'design.parquet'}"))


@pb_app.command("analyze")
@handle_errors
def pb_analyze(run: RunOpt, responses: ResponsesOpt = None, settings: SettingsOpt = None,
               setting: SettingOpt = None, force: ForceOpt = False):
    """Main effects and ANOVA of the screening.

    Reads RUN/pb/design.parquet with RUN/simulate/results.parquet, or --responses FILE.
    Writes RUN/pb/effects.parquet, anova.parquet, fit.parquet, effects.png.
    """
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    names, response = list(cfg["pb"]["factors"]), cfg["response"]
    design_path = run / "pb" / "design.parquet"
    data, inputs = _load_responses(run, responses, design_path, names, response)
    space = space_from_design(design_path) or ParameterSpace.from_data(data, names, factor_space(cfg, names))
    st = art.Stage(run, "pb", "analyze", inputs=inputs,
                   settings={"space": space.to_dicts(), "alpha": cfg["pb"]["alpha"], "response": response})
    if st.up_to_date() and not force:
        return skipped(st)
    res = pb_mod.analyze(data, space, response, float(cfg["pb"]["alpha"]))
    fit = pd.DataFrame([{**{k: res.fit.stats[k] for k in ("r2", "r2_adj", "r2_pred", "adeq_precision",
                                                           "cv_percent", "std_dev", "mean", "model_F", "model_p")},
                         "intercept": float(res.fit.coef["Intercept"]), "n_runs": len(data),
                         "significant": ",".join(res.significant)}])
    with st.commit() as out:
        out.table("effects.parquet", res.effects)
        out.table("anova.parquet", res.anova)
        out.table("fit.parquet", fit)
        out.table("data.parquet", data)
        out.figure("effects.png", plots.pareto_effects(res.effects, res.alpha))
    console.print(_anova_table(res.anova, "ANOVA of the Plackett-Burman screening (cf. paper Table 4)"))
    console.print(df_table(res.effects[["factor", "effect", "sum_sq", "contribution_percent", "F", "p_value",
                                        "significant", "rank"]], "Main effects (coded: effect = 2 b)",
                           {"p_value": pvalue}))
    s = res.fit.stats
    console.print(f"R2 {s['r2']:.4f}  adj R2 {s['r2_adj']:.4f}  adequate precision {s['adeq_precision']:.4f}  "
                  f"CV {s['cv_percent']:.2f} %")
    if res.significant:
        console.print(f"[bold]Going forward[/] (p < {res.alpha:g}, by influence): {', '.join(res.significant)}")
    else:
        console.print(f"[yellow]No factor is significant at p < {res.alpha:g}[/]: check the ranges or the responses")


# ------------------------------------------------------------------ ascent
def _pb_outputs(run: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    eff = art.read_table(run / "pb" / "effects.parquet", what="screening effects (run `calib pb analyze` first)")
    fit = art.read_table(run / "pb" / "fit.parquet", what="screening fit (run `calib pb analyze` first)")
    return eff, fit


def _check_against_screening(run: Path, path: pd.DataFrame, factors: list[str], response: str) -> None:
    """Warn where an ascent step repeats screening runs in every moved factor but its angle is not
    what the screening's model expects (ascent.screening_repeats, |z| > 3)."""
    if not all((run / "pb" / f).is_file() for f in ("data.parquet", "effects.parquet", "fit.parquet")):
        return
    eff, fit = _pb_outputs(run)
    scr = art.read_table(run / "pb" / "data.parquet", what="screening data")
    if response not in scr.columns or not set(factors) <= set(scr.columns):
        return
    design = run / "ascent" / "design.parquet"
    if design.is_file():  # the levels the path held the other screened factors at
        d = art.read_table(design, what="ascent design")
        extra = [f for f in eff["factor"] if f in d.columns and f not in path.columns]
        if "step" in d.columns and extra:
            path = path.merge(d[["step", *extra]], on="step", how="left")
    sd = float(fit["std_dev"].iloc[0])
    for r in ascent_mod.screening_repeats(path, scr, eff, sd, factors, response).itertuples():
        if abs(r.z) > 3:
            runs = ", ".join(map(str, r.runs))
            console.print(f"[yellow]warning:[/] step {r.step} repeats screening run(s) {runs} in {', '.join(factors)}, "
                          f"but its angle {r.angle:.2f} differs from theirs ({r.screening_angle:.2f}) by "
                          f"{r.angle - r.screening_angle:+.2f} deg where the screening's model expects "
                          f"{r.expected:+.2f}: {r.z:+.1f} residual sd. The two stages do not agree; were they "
                          "simulated (or measured) with the same setup - floor, fill, numerics?")


def _ascent_target(run: Path, cfg: dict, explicit: Optional[float] = None) -> tuple[float, dict]:
    """The ascent's target angle: --target, else settings ascent.target, else the measured angle
    (RUN/measure/conditions.parquet; the mean over conditions where there are several), else the
    settings target. Returns it with the input file it came from, if any (for the stage lock)."""
    a = cfg["ascent"]
    if explicit is not None:
        return float(explicit), {}
    if a["target"] is not None:
        return float(a["target"]), {}
    cond = run / "measure" / "conditions.parquet"
    if cond.is_file():
        m = art.read_table(cond, columns=["mean"], what="measured conditions")["mean"].astype(float)
        if len(m) and np.isfinite(m).all():
            return float(m.mean()), {"conditions": cond}
    return float(cfg["target"]), {}


@ascent_app.command("design")
@handle_errors
def ascent_design(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Write the steepest-ascent path over the significant factors.

    Reads RUN/pb/effects.parquet, fit.parquet; settings [ascent]. Writes RUN/ascent/design.parquet.
    """
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    eff, fit = _pb_outputs(run)
    sig = list(eff.loc[eff["significant"], "factor"])
    if not sig:
        raise CalibError("the screening found no significant factor: there is no ascent direction")
    a = cfg["ascent"]
    target, tin = _ascent_target(run, cfg)
    coefs = {f: float(eff.set_index("factor").loc[f, "coefficient"]) for f in sig}
    space = ParameterSpace.from_dicts(
        [{k: r[k] for k in ("low", "high", "unit")} | {"name": r["factor"]} for _, r in eff.iterrows()
         if r["factor"] in sig])
    others = [f for f in eff["factor"] if f not in sig]
    fixed = _fixed_values(cfg, "ascent", others)
    st = art.Stage(run, "ascent", "design",
                   inputs={"effects": run / "pb" / "effects.parquet", "fit": run / "pb" / "fit.parquet", **tin},
                   settings={"method": a["method"], "steps": a["steps"], "target": target, "fixed": fixed})
    if st.up_to_date() and not force:
        return skipped(st)
    d = ascent_mod.direction(coefs, float(fit["intercept"].iloc[0]), target, a["method"])
    df = ascent_mod.design(space, d, int(a["steps"]), fixed)
    with st.commit() as out:
        out.table("design.parquet", df, space=space.to_dicts(), direction=dict(zip(sig, d.tolist())),
                  target=target)
    console.print(df_table(df, f"Steepest-ascent path ({a['method']}, direction "
                               f"{', '.join(f'{n} {v:+.3f}' for n, v in zip(sig, d))} coded)"))


@ascent_app.command("analyze")
@handle_errors
def ascent_analyze(run: RunOpt, responses: ResponsesOpt = None, target: Optional[float] = typer.Option(
        None, help="Target angle (deg); default: settings ascent.target, else the measured angle "
                   "(RUN/measure/conditions.parquet), else settings target."),
        settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Relative error to the target along the path; the best step and the bracket for the BBD.

    Reads RUN/ascent/design.parquet with simulated results, or --responses FILE (rows in step order,
    or a `step` column). Writes RUN/ascent/path.parquet, bracket.parquet, path.png. Warns where a
    step repeats screening runs in the moved factors but its angle is more than 3 residual sd from
    what the screening's model expects (docs/method.md).
    """
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    design_path = run / "ascent" / "design.parquet"
    tgt, tin = _ascent_target(run, cfg, target)
    response = cfg["response"]
    if design_path.is_file():
        factors = space_from_design(design_path).names
    elif (run / "pb" / "effects.parquet").is_file():
        eff, _ = _pb_outputs(run)
        factors = list(eff.loc[eff["significant"], "factor"])
    else:
        factors = [f for f in cfg["bbd"]["factors"] or cfg["pb"]["factors"] if f != "restitution"]
    if responses is not None:
        data = art.read_responses(responses, factors, response, optional=["step"])
        if "step" not in data.columns:
            data.insert(0, "step", np.arange(1, len(data) + 1))
        inputs = {"responses": responses}
    else:
        data = simulated_responses(run, design_path, factors, response, allow_failed=True)
        inputs = {"design": design_path, "results": art.Rows(run / "simulate" / "results.parquet", data)}
    inputs |= tin
    st = art.Stage(run, "ascent", "analyze", inputs=inputs, settings={"target": tgt, "factors": factors})
    if st.up_to_date() and not force:
        return skipped(st)
    res = ascent_mod.analyze(data, factors, response, tgt)
    for step in res.path.loc[~np.isfinite(res.path[response]), "step"]:
        console.print(f"[yellow]warning:[/] step {step} formed no heap (no angle): it cannot be the best step")
    with st.commit() as out:
        out.table("path.parquet", res.path, target=tgt)
        out.table("bracket.parquet", res.bracket, best_step=res.best_step, target=tgt)
        out.figure("path.png", plots.ascent_path(res.path, response, tgt))
    _check_against_screening(run, res.path, factors, response)
    cols = ["step", *factors, response, "relative_error_percent", "best"]
    console.print(df_table(res.path[cols], f"Steepest ascent vs target {tgt:g} deg (cf. paper Table 5)",
                           {"relative_error_percent": lambda v: f"{v:.2f} %"}))
    console.print(df_table(res.bracket, f"Bracket around step {res.best_step} (the Box-Behnken ranges)"))
    if res.at_edge:
        console.print("[yellow]warning:[/] the best step is at the end of the path; the optimum may lie outside "
                      "it. Widen the screening ranges or extend the path.")


# ------------------------------------------------------------------ bbd
@bbd_app.command("design")
@handle_errors
def bbd_design(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Write the Box-Behnken design (3 factors, 5 centre points: 17 runs).

    Ranges: settings bbd.ranges, else RUN/ascent/bracket.parquet, else the factor table.
    Factors: settings bbd.factors, else the screening's significant factors.
    Writes RUN/bbd/design.parquet.
    """
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    b = cfg["bbd"]
    inputs: dict = {}
    names = list(b["factors"])
    if not names and (run / "pb" / "effects.parquet").is_file():
        eff, _ = _pb_outputs(run)
        names = list(eff.loc[eff["significant"]].sort_values("rank")["factor"])
        names = [n for n in cfg["pb"]["factors"] if n in names]  # keep the factor-table order
        inputs["effects"] = run / "pb" / "effects.parquet"
    if not names:
        raise CalibError("no factors for the BBD: set bbd.factors or run the screening (`calib pb analyze`)")
    space = factor_space(cfg, names)
    bracket_path = run / "ascent" / "bracket.parquet"
    ranges = {n: tuple(b["ranges"][n]) for n in names if n in b["ranges"]}
    if len(ranges) < len(names) and bracket_path.is_file():
        br = art.read_table(bracket_path, columns=["factor", "low", "high"], what="ascent bracket").set_index("factor")
        for n in names:
            if n not in ranges and n in br.index:
                ranges[n] = (float(br.loc[n, "low"]), float(br.loc[n, "high"]))
        inputs["bracket"] = bracket_path
    space = ParameterSpace.of(space[n].with_range(*ranges[n]) if n in ranges else space[n] for n in names)
    others = [n for n in cfg["pb"]["factors"] if n not in names]
    fixed = _fixed_values(cfg, "bbd", others)
    st = art.Stage(run, "bbd", "design", inputs=inputs,
                   settings={"space": space.to_dicts(), "center_points": b["center_points"], "fixed": fixed})
    if st.up_to_date() and not force:
        return skipped(st)
    df = bbd_mod.design(space, int(b["center_points"]), fixed)
    with st.commit() as out:
        out.table("design.parquet", df, space=space.to_dicts())
    console.print(df_table(pd.DataFrame(space.to_dicts())[["name", "low", "high", "unit"]],
                           "Box-Behnken factor levels (cf. paper Table 6)"))
    console.print(df_table(df, f"Box-Behnken design ({len(df)} runs) -> {st.dir / 'design.parquet'}"))


@bbd_app.command("analyze")
@handle_errors
def bbd_analyze(run: RunOpt, responses: ResponsesOpt = None, settings: SettingsOpt = None,
                setting: SettingOpt = None, force: ForceOpt = False):
    """Quadratic response surface with ANOVA, lack of fit, R2/adj/pred, adequate precision.

    Reads RUN/bbd/design.parquet with simulated results, or --responses FILE.
    Writes RUN/bbd/coefficients.parquet, anova.parquet, fit.parquet, data.parquet and
    surface_<a>__<b>.png per factor pair.
    """
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    response = cfg["response"]
    design_path = run / "bbd" / "design.parquet"
    space = space_from_design(design_path)
    if space is not None:
        names = space.names
    else:
        names = list(cfg["bbd"]["factors"]) or [n for n in cfg["pb"]["factors"] if n != "restitution"]
    data, inputs = _load_responses(run, responses, design_path, names, response)
    if space is None:
        space = ParameterSpace.from_data(data, names, factor_space(cfg, names))
    st = art.Stage(run, "bbd", "analyze", inputs=inputs, settings={"space": space.to_dicts(), "response": response})
    if st.up_to_date() and not force:
        return skipped(st)
    rsm = bbd_mod.QuadraticRSM().fit(data, space, response)
    s = rsm.stats_
    fit = pd.DataFrame([{k: s[k] for k in ("r2", "r2_adj", "r2_pred", "adeq_precision", "cv_percent",
                                             "lack_of_fit_F", "lack_of_fit_p", "std_dev", "mean", "press",
                                             "model_F", "model_p")} | {"n_runs": len(data)}])
    coefs = rsm.fit_.coefficient_table()
    with st.commit() as out:
        out.table("coefficients.parquet", coefs, space=space.to_dicts())
        out.table("anova.parquet", rsm.anova_)
        out.table("fit.parquet", fit)
        out.table("data.parquet", data[[*names, response]])
        for i, a in enumerate(names):
            for bname in names[i + 1:]:
                out.figure(f"surface_{a}__{bname}.png", plots.response_surface(rsm, a, bname, response))
    console.print(_anova_table(rsm.anova_, "ANOVA of the quadratic response surface (cf. paper Table 8)"))
    console.print(df_table(coefs, "Coefficients (coded units, cf. paper Eq. 7)", {"p_value": pvalue}))
    console.print(f"[bold]{rsm.equation()}[/]")
    console.print(f"R2 {s['r2']:.4f}  adj R2 {s['r2_adj']:.4f}  pred R2 {s['r2_pred']:.4f}  "
                  f"adequate precision {s['adeq_precision']:.4f}  CV {s['cv_percent']:.2f} %  "
                  f"lack of fit F {s['lack_of_fit_F']:.2f} p {s['lack_of_fit_p']:.4f}")
    if s["lack_of_fit_p"] < float(cfg["bbd"]["alpha"]):
        console.print("[yellow]warning:[/] lack of fit is significant: the quadratic model misses structure")
    if s["r2_adj"] - s["r2_pred"] > 0.2:
        console.print("[yellow]warning:[/] adjusted and predicted R2 differ by more than 0.2")
