"""One HTML page with every stage's summary tables and plots, for a user to share."""

from __future__ import annotations

import html
from pathlib import Path

import pandas as pd

from . import __version__
from . import artifacts as art

#: (stage folder, title, paper reference (None: a stage beyond the paper), tables to show, figures glob)
SECTIONS = [
    ("measure", "Measured repose angle", "2.1, Table 1", ["conditions.parquet", "angles.parquet"], "overlays/*.png"),
    ("pb", "Plackett-Burman screening", "3.1, Tables 3-4", ["anova.parquet", "effects.parquet", "fit.parquet"],
     "*.png"),
    ("ascent", "Steepest ascent", "3.2, Table 5", ["path.parquet", "bracket.parquet"], "*.png"),
    ("bbd", "Box-Behnken response surface", "3.3-3.4, Eq. 7, Table 8",
     ["anova.parquet", "coefficients.parquet", "fit.parquet"], "*.png"),
    ("surrogate", "Surrogates", "3.5.1-3.5.2, Table 9", ["metrics.parquet"], "*.png"),
    ("invert", "Inversion", "3.5.3-3.6, Eq. 11, Fig. 9", ["solution.parquet", "ranges.parquet",
                                                          "refinement.parquet", "validation.parquet"], "*.png"),
    ("compare", "Model against the measurements", None, ["history.parquet", "residuals.parquet"], "*.png"),
    ("diagnose", "Missing effects, ranked", None, ["ranking.parquet", "trends.parquet"], None),
    ("simulate", "Simulations", "2.2", ["results.parquet"], None),
]

CSS = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;font-size:13px;margin:.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 7px;
text-align:right}th{background:#f3f3f3}img{max-width:100%;border:1px solid #ddd;margin:.3em 0}
h2{border-bottom:2px solid #444;padding-bottom:.2em}.prov{color:#777;font-size:12px}"""


def _table(df: pd.DataFrame, max_rows: int = 40) -> str:
    shown = df.head(max_rows)
    more = f"<p class=prov>{len(df) - max_rows} more rows in the Parquet file</p>" if len(df) > max_rows else ""
    return shown.to_html(index=False, float_format=lambda v: f"{v:.5g}", na_rep="", border=0) + more


def _heap_setups(run: Path) -> list[str]:
    """One line per group of the run's heaps (design, validation, compare, ...): how many, and
    at which preset, shear modulus and contact laws - what its calibrated parameters hold at."""
    path = run / "simulate" / "results.parquet"
    if not path.is_file():
        return []
    from .campaign import heap_setups

    rows = art.read_table(path)
    if rows.empty:
        return []
    label = rows["design"].fillna("").replace("", "single runs") if "design" in rows.columns \
        else pd.Series("all", index=rows.index)
    items = []
    for name, grp in rows.groupby(label, sort=False):
        engines = sorted(set(grp["engine"].dropna()) - {"builtin"}) if "engine" in grp.columns else []
        items.append(f"<li>{html.escape(str(name))}: {len(grp)} heap(s), {html.escape('; '.join(heap_setups(grp)))}"
                     + (f" (engine {html.escape(', '.join(engines))})" if engines else "") + "</li>")
    return ["<p>Heaps in this run directory, by what they were simulated for: a calibration holds at the "
            "preset and shear modulus its heaps had (docs/physics.md, 'Which modulus').</p><ul>", *items, "</ul>"]


def build_report(run: Path) -> str:
    run = Path(run)
    parts = [f"<!doctype html><meta charset=utf-8><title>calib report: {html.escape(run.name)}</title>"
             f"<style>{CSS}</style><h1>calib report: {html.escape(str(run))}</h1>"
             f"<p class=prov>calib {__version__}. Every table is a Parquet artefact in the run directory; "
             f"its provenance (command, inputs, settings hash) is in its schema metadata.</p>"]
    parts.extend(_heap_setups(run))
    found = False
    for folder, title, ref, tables, figs in SECTIONS:
        d = run / folder
        if not d.is_dir():
            continue
        found = True
        where = f"paper {ref}" if ref else "beyond the paper: docs/method.md"
        parts.append(f"<h2>{html.escape(title)} <small>({where})</small></h2>")
        for t in tables:
            p = d / t
            if p.is_file():
                prov = art.read_provenance(p)
                # diagnose judges the revision compare held then; compare may since hold a later one
                rev = (f" (model revision {prov['model_revision']})" if "model_revision" in prov else "")
                parts.append(f"<h3>{t}{rev}</h3><p class=prov>{html.escape(prov.get('command', ''))}</p>")
                parts.append(_table(art.read_table(p)))
        for f in sorted(d.glob(figs)) if figs else []:
            parts.append(f'<p><img src="{html.escape(str(f.relative_to(run)))}" alt="{html.escape(f.name)}"></p>')
    if not found:
        from .errors import CalibError

        raise CalibError(f"{run} holds no stage output to report")
    return "\n".join(parts)
