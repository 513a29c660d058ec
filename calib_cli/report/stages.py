"""The sections after the first screen: the paper's stages in its order, the measurement, the
discrepancy loop and the heaps, each a short summary with its figures, or a line saying it has not run."""

from __future__ import annotations

import pandas as pd

from .. import artifacts as art
from .html import RunFiles, esc, figure, note, num, table


def section(sid: str, title: str, ref, body: str) -> str:
    """ref: the paper's sections; None: a stage beyond the paper; False: no reference."""
    where = "" if ref is False else \
        f" <small>({esc(f'paper {ref}' if ref else 'beyond the paper: docs/method.md')})</small>"
    return f"<section id={sid}><h2>{esc(title)}{where}</h2>{body}</section>"


def not_run(cmd: str) -> str:
    return note(f"Not run in this run directory (<code>{esc(cmd)}</code>).")


def figures(f: RunFiles, rel_dir: str, pattern: str = "*.png", cls: str = "figs") -> str:
    paths = f.pngs(rel_dir, pattern)
    # a surface's file is surface_<a>__<b>: the pair's sign put in after escaping, else it shows as "&times;"
    items = "".join(figure(f.run, p, esc(p.stem.replace("__", "\0").replace("_", " ")).replace("\0", " &times; "))
                    for p in paths)
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
        body = (table(path, digits=4) + (note("Bracket for the response surface (Table 6):") + table(br, digits=4)
                                         if br is not None else "") + figures(f, "ascent"))
    return section("ascent", "Steepest ascent path", "3.2, Tables 5-6", body)


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
        body += note("Surrogate prediction at the solution, per target:") + table(pc, digits=4)
    ref = f.table("invert/refinement.parquet")
    if ref is not None and len(ref):
        g = ref.groupby("round").agg(rms_z=("z", lambda z: float((z ** 2).mean() ** 0.5)),
                                     failing=("fails", "sum"), conditions=("fails", "size")).reset_index()
        body += note("Refinement by simulation, per round (rms z of its heaps against the targets):") + table(g)
    return section("inversion", "GA inversion", "3.5.3-3.6, Eq. 11, Fig. 9", body)
