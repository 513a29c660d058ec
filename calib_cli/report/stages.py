"""The sections after the first screen: the paper's stages in its order, the measurement, the
discrepancy loop and the heaps, each a short summary with its figures, or a line saying it has not run."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .. import artifacts as art
from .html import RunFiles, deg, esc, figure, note, num, table


def section(sid: str, title: str, ref, body: str) -> str:
    """ref: the paper's sections; None: a stage beyond the paper; False: no reference."""
    where = "" if ref is False else \
        f" <small>({esc(f'paper {ref}' if ref else 'beyond the paper: docs/method.md')})</small>"
    return f"<section id={sid}><h2>{esc(title)}{where}</h2>{body}</section>"


def not_run(cmd: str) -> str:
    return note(f"Not run in this run directory (<code>{esc(cmd)}</code>).")


#: what each stage's figure shows, by its file's name (a surface's is named by its factor pair)
CAPTIONS = {
    "effects": "The screening's main effects, largest first (red: significant)",
    "path": "The angle along the steepest-ascent path against the target",
    "predicted_vs_actual": "Each surrogate's predicted angle against the design's, in-sample and held out",
    "fitness": "The GA's best and mean fitness (RMSE to the targets, deg) per generation",
    "history": "RMSE and &chi;&sup2;/dof per model revision",
    "residuals": "Measured &minus; simulated angle per condition against each condition variable (bars: two "
                 "combined standard uncertainties)",
}


def _caption(stem: str) -> str:
    if stem in CAPTIONS:
        return CAPTIONS[stem]
    # a surface's file is surface_<a>__<b>: the pair's sign put in after escaping, else it shows as "&times;"
    return esc(stem.replace("__", "\0").replace("_", " ")).replace("\0", " &times; ")


def figures(f: RunFiles, rel_dir: str, pattern: str = "*.png", cls: str = "figs") -> str:
    paths = f.pngs(rel_dir, pattern)
    items = "".join(figure(f.run, p, _caption(p.stem)) for p in paths)
    return f"<div class={cls}>{items}</div>" if items else ""


def fit_line(f: RunFiles, rel: str) -> str:
    """R2, adjusted and predicted R2, adequate precision and lack of fit of a fit.parquet."""
    fit = f.table(rel)
    if fit is None or fit.empty:
        return ""
    r = fit.iloc[0]
    names = {"r2": "R&sup2;", "r2_adj": "adjusted R&sup2;", "r2_pred": "predicted R&sup2;",
             "adeq_precision": "adequate precision", "cv_percent": "CV %", "lack_of_fit_p": "lack-of-fit p",
             "n_runs": "runs"}
    return note("Fit: " + ", ".join(f"{v} {num(r[k])}" for k, v in names.items() if k in r.index and pd.notna(r[k])))


def _cols(df: pd.DataFrame, cols: list[str]) -> pd.DataFrame:
    return df[[c for c in cols if c in df.columns]]


def screening(f: RunFiles) -> str:
    eff = f.table("pb/effects.parquet")
    if eff is None:
        body = not_run("calib pb design; calib pb analyze")
    else:
        body = (fit_line(f, "pb/fit.parquet") + table(_cols(eff, ["factor", "unit", "low", "high", "effect",
                "contribution_percent", "p_value", "significant", "rank"]), digits=4) + figures(f, "pb"))
    return section("screening", "Screening: Plackett-Burman effects", "3.1, Tables 3-4", body)


def ascent(f: RunFiles) -> str:
    path = f.table("ascent/path.parquet")
    if path is None:
        body = not_run("calib ascent design; calib ascent analyze")
    else:
        br = f.table("ascent/bracket.parquet")
        body = (_ascent_target(f) + table(path, digits=4)
                + (note("Bracket for the response surface (Table 6):") + table(br, digits=4) if br is not None else "")
                + figures(f, "ascent"))
    return section("ascent", "Steepest ascent path", "3.2, Tables 5-6", body)


def _ascent_target(f: RunFiles) -> str:
    """Where the path was judged against another angle than the measured one (settings ascent.target or
    --target: the paper's Table 5 needs 32.84 deg, its measurement is 32.07), a line that says so."""
    target = f.prov("ascent/path.parquet").get("target")
    cond = f.table("measure/conditions.parquet")
    if target is None or cond is None or len(cond) != 1 or abs(float(cond["mean"].iloc[0]) - float(target)) < 5e-3:
        return ""
    return note(f"The path is judged against a target of {deg(target)} (settings <code>ascent.target</code> or "
                f"<code>--target</code>), not the measured {deg(cond['mean'].iloc[0])} that the inversion aims at.")


def bbd(f: RunFiles) -> str:
    coef = f.table("bbd/coefficients.parquet")
    design = f.table("bbd/design.parquet")
    if coef is None:
        body = not_run("calib bbd analyze") if design is None else note(
            f"Design only ({len(design)} runs in <code>bbd/design.parquet</code>); the response surface was not "
            "analysed here (<code>calib bbd analyze</code>).")
    else:
        body = (fit_line(f, "bbd/fit.parquet") + "<details><summary>Coefficients (Eq. 7, coded units)</summary>"
                + table(_cols(coef, ["term", "coefficient", "std_err", "p_value"]), digits=4) + "</details>"
                + figures(f, "bbd", "surface_*.png", "figs three")
                + figures(f, "bbd", "[!s]*.png"))
    return section("bbd", "Box-Behnken design and response surfaces", "3.3-3.4, Eq. 7, Table 8, Figs. 6-8", body)


def surrogate(f: RunFiles) -> str:
    met = f.table("surrogate/metrics.parquet")
    if met is None:
        return section("surrogate", "Surrogates: RSM, BP, PSO-BP", "3.5.1-3.5.2, Table 9",
                       not_run("calib fit-surrogate"))
    r2 = met.pivot_table(index="model", columns="split", values="r2", sort=False).reset_index()
    r2.columns.name = None
    best = f.path("surrogate/best.json")
    pick = art.read_json(best) if best else {}  # a corrupt best.json: a CalibError naming it, not a traceback
    body = (note("R&sup2; by model and split (train: in-sample, as the paper's Table 9; loo: leave-one-out). "
                 + (f"Used for the inversion: <b>{esc(pick['best'])}</b> ({esc(pick.get('criterion', ''))})."
                    if "best" in pick else ""))
            + table(r2, digits=3) + figures(f, "surrogate"))
    return section("surrogate", "Surrogates: RSM, BP, PSO-BP", "3.5.1-3.5.2, Table 9", body)


def inversion(f: RunFiles) -> str:
    if not f.path("invert/solution.parquet"):
        return section("inversion", "GA inversion", "3.5.3-3.6, Eq. 11, Fig. 9", not_run("calib invert"))
    body = figures(f, "invert")
    pc = f.table("invert/predicted_conditions.parquet")
    if pc is not None:
        cond = f.table("measure/conditions.parquet")  # the targets are its means, in its order
        if (cond is not None and len(cond) == len(pc) and "condition_id" in cond.columns and "target" in pc.columns
                and np.allclose(pc["target"].to_numpy(float), cond["mean"].to_numpy(float), rtol=0, atol=1e-9)):
            pc = pc.assign(condition_id=cond["condition_id"].astype(str).to_numpy())
        pc = pc[[c for c in ("condition_id", "target", "predicted_angle") if c in pc.columns]]
        body += note("Surrogate prediction at the solution, per target (deg):") + table(
            pc.rename(columns={"target": "target [deg]", "predicted_angle": "predicted [deg]"}), digits=4)
    ref = f.table("invert/refinement.parquet")
    if ref is not None and len(ref):
        g = ref.groupby("round").agg(rms_z=("z", lambda z: float((z ** 2).mean() ** 0.5)),
                                     failing=("fails", "sum"), conditions=("fails", "size")).reset_index()
        body += note("Refinement by simulation, per round (rms z of its heaps against the targets):") + table(g)
    return section("inversion", "GA inversion", "3.5.3-3.6, Eq. 11, Fig. 9", body)
