"""`calib pb|ascent|bbd design|analyze`: the options of calib_cli.stages.doe and their tables."""

from __future__ import annotations

from typing import Optional

import typer

from .common import (CalibCommand, CalibGroup, ForceOpt, ResponsesOpt, RunOpt, SettingOpt, SettingsOpt, console,
                     df_table, handle_errors, pvalue, say, skipped)

pb_app = typer.Typer(cls=CalibGroup, help="Plackett-Burman screening (paper 3.1, Tables 2-4).", no_args_is_help=True)
ascent_app = typer.Typer(cls=CalibGroup, help="Steepest ascent toward the target (paper 3.2, Table 5).",
                         no_args_is_help=True)
bbd_app = typer.Typer(cls=CalibGroup, help="Box-Behnken response surface (paper 3.3-3.4, Eq. 7, Table 8).",
                      no_args_is_help=True)


def _doe():
    """calib_cli.stages.doe, imported when a command runs (it imports pandas, scipy, matplotlib)."""
    from ..stages import doe

    return doe


def _anova_table(anova, title: str):
    import numpy as np

    return df_table(anova, title, {"p_value": lambda p: pvalue(p) if np.isfinite(p) else ""})


# ------------------------------------------------------------------ pb
@pb_app.command("design", cls=CalibCommand)
@handle_errors
def pb_design(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Write the 12-run PB design. Reads the settings' factors and pb tables; writes RUN/pb/design.parquet."""
    r = _doe().pb_design(run, settings, setting, force)
    if r.skipped:
        return skipped(r.stage)
    df = r.design
    console.print(df_table(df, f"Plackett-Burman design ({len(df)} runs) -> {r.dir / 'design.parquet'}"))


@pb_app.command("analyze", cls=CalibCommand)
@handle_errors
def pb_analyze(run: RunOpt, responses: ResponsesOpt = None, settings: SettingsOpt = None,
               setting: SettingOpt = None, force: ForceOpt = False):
    """Main effects and ANOVA of the screening.

    Reads RUN/pb/design.parquet with RUN/simulate/results.parquet, or --responses FILE.
    Writes RUN/pb/effects.parquet, anova.parquet, fit.parquet, effects.png.
    """
    r = _doe().pb_analyze(run, responses, settings, setting, force, say=say)
    if r.skipped:
        return skipped(r.stage)
    res = r.analysis
    console.print(_anova_table(res.anova, "ANOVA of the Plackett-Burman screening (cf. paper Table 4)"))
    console.print(df_table(r.summary(), "Main effects (coded: effect = 2 b)",
                           {"p_value": pvalue}))
    s = res.fit.stats
    console.print(f"R2 {s['r2']:.4f}  adj R2 {s['r2_adj']:.4f}  adequate precision {s['adeq_precision']:.4f}  "
                  f"CV {s['cv_percent']:.2f} %")
    if res.significant:
        console.print(f"[bold]Going forward[/] (p < {res.alpha:g}, by influence): {', '.join(res.significant)}")
    else:
        console.print(f"[yellow]No factor is significant at p < {res.alpha:g}[/]: check the ranges or the responses")


# ------------------------------------------------------------------ ascent
@ascent_app.command("design", cls=CalibCommand)
@handle_errors
def ascent_design(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Write the steepest-ascent path over the significant factors.

    Reads RUN/pb/effects.parquet, fit.parquet and the settings' ascent table. Writes RUN/ascent/design.parquet.
    """
    r = _doe().ascent_design(run, settings, setting, force)
    if r.skipped:
        return skipped(r.stage)
    df, sig, d = r.design, list(r.direction), list(r.direction.values())
    console.print(df_table(df, f"Steepest-ascent path ({r.method}, direction "
                               f"{', '.join(f'{n} {v:+.3f}' for n, v in zip(sig, d))} coded)"))


@ascent_app.command("analyze", cls=CalibCommand)
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
    r = _doe().ascent_analyze(run, responses, target, settings, setting, force, say=say)
    if r.skipped:
        return skipped(r.stage)
    res, tgt = r.analysis, r.target
    console.print(df_table(r.summary(), f"Steepest ascent vs target {tgt:g} deg (cf. paper Table 5)",
                           {"relative_error_percent": lambda v: f"{v:.2f} %"}))
    console.print(df_table(res.bracket, f"Bracket around step {res.best_step} (the Box-Behnken ranges)"))
    for w in r.warnings():
        console.print(f"[yellow]warning:[/] {w}")


# ------------------------------------------------------------------ bbd
@bbd_app.command("design", cls=CalibCommand)
@handle_errors
def bbd_design(run: RunOpt, settings: SettingsOpt = None, setting: SettingOpt = None, force: ForceOpt = False):
    """Write the Box-Behnken design (3 factors, 5 centre points: 17 runs).

    Ranges: settings bbd.ranges, else RUN/ascent/bracket.parquet, else the factor table.

    Factors: settings bbd.factors, else the screening's significant factors.

    Writes RUN/bbd/design.parquet.
    """
    r = _doe().bbd_design(run, settings, setting, force)
    if r.skipped:
        return skipped(r.stage)
    import pandas as pd

    df, space = r.design, r.space
    console.print(df_table(pd.DataFrame(space.to_dicts())[["name", "low", "high", "unit"]],
                           "Box-Behnken factor levels (cf. paper Table 6)"))
    console.print(df_table(df, f"Box-Behnken design ({len(df)} runs) -> {r.dir / 'design.parquet'}"))


@bbd_app.command("analyze", cls=CalibCommand)
@handle_errors
def bbd_analyze(run: RunOpt, responses: ResponsesOpt = None, settings: SettingsOpt = None,
                setting: SettingOpt = None, force: ForceOpt = False):
    """Quadratic response surface with ANOVA, lack of fit, R2/adj/pred, adequate precision.

    Reads RUN/bbd/design.parquet with simulated results, or --responses FILE.
    Writes RUN/bbd/coefficients.parquet, anova.parquet, fit.parquet, data.parquet and
    surface_<a>__<b>.png per factor pair.
    """
    r = _doe().bbd_analyze(run, responses, settings, setting, force, say=say)
    if r.skipped:
        return skipped(r.stage)
    rsm, coefs = r.rsm, r.coefficients
    s = rsm.stats_
    console.print(_anova_table(rsm.anova_, "ANOVA of the quadratic response surface (cf. paper Table 8)"))
    console.print(df_table(coefs, "Coefficients (coded units, cf. paper Eq. 7)", {"p_value": pvalue}))
    console.print(f"[bold]{rsm.equation()}[/]")
    console.print(f"R2 {s['r2']:.4f}  adj R2 {s['r2_adj']:.4f}  pred R2 {s['r2_pred']:.4f}  "
                  f"adequate precision {s['adeq_precision']:.4f}  CV {s['cv_percent']:.2f} %  "
                  f"lack of fit F {s['lack_of_fit_F']:.2f} p {s['lack_of_fit_p']:.4f}")
    for w in r.warnings():
        console.print(f"[yellow]warning:[/] {w}")
