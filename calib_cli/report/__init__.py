"""One HTML page per run directory that leads with the answer: the first screen says what was
calibrated against what and whether it fits; the paper's stages, the discrepancy loop and the raw
tables follow. Plain HTML and CSS (no JavaScript); images are linked by their paths in the run
directory, which the page sits in."""

from __future__ import annotations

from pathlib import Path

from .. import __version__
from ..errors import CalibError
from .cards import fit_card, history_card, params_card, posterior_card, ranking_card
from .details import RAW_STAGES, discrepancy, measurement, posterior, raw_tables, simulations
from .html import RunFiles, esc
from .photos import photos_card
from .stages import ascent, bbd, inversion, screening, surrogate
from .summary import fit_rows, headline

#: (anchor, title) of the sections after the first screen, in page order
SECTIONS = [("posterior", "Posterior"), ("screening", "Screening"), ("ascent", "Ascent"), ("bbd", "Response surface"),
            ("surrogate", "Surrogates"), ("inversion", "GA"), ("measurement", "Measurement"),
            ("discrepancy", "Discrepancy loop"), ("simulations", "Simulations"), ("raw", "Raw tables")]
RENDERERS = [posterior, screening, ascent, bbd, surrogate, inversion, measurement, discrepancy, simulations, raw_tables]

CSS = """*{box-sizing:border-box}
body{font:14px/1.4 system-ui,sans-serif;max-width:1320px;margin:0 auto;padding:10px 18px;color:#222}
h1{font-size:20px;margin:4px 0}h3{font-size:14px;margin:0 0 6px}
h2{border-bottom:2px solid #444;padding-bottom:.2em;margin-top:1.6em}
small,.prov{color:#666;font-size:12px}.prov{margin:4px 0}.lead{font-size:15px;margin:4px 0}
nav{font-size:13px;margin:6px 0 10px}nav a{margin-right:10px}code{font-size:12.5px}
.grid{display:grid;grid-template-columns:1.1fr 0.95fr 1.15fr;gap:10px;margin:8px 0}
.stack{display:flex;flex-direction:column;gap:10px;min-width:0}
.card{border:1px solid #ddd;border-radius:6px;padding:8px 10px;background:#fcfcfc;min-width:0}
.card.wide{grid-column:1/-1}.scroll{overflow-x:auto;max-width:100%}
table{border-collapse:collapse;font-size:12.5px;margin:.3em 0 .8em}table.compact{margin:0}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:left;vertical-align:top}th{background:#f0f0f0}
td.n,th.n{text-align:right}
.badge{display:inline-block;padding:0 6px;border-radius:8px;font-size:12px;font-weight:600}.nw{white-space:nowrap}
.pass{background:#d5f0dc;color:#145a32}.fail{background:#f8d4cf;color:#7b241c}
.warn{background:#fcefc7;color:#7d5a00}.info{background:#dde8f5;color:#1b4f72}
svg.chart{max-width:100%;height:auto;font-size:11px}.legend{font-size:12px;margin:2px 0}
img{max-width:100%;border:1px solid #ddd}figure{margin:0}figcaption{font-size:12px;color:#444}
.gallery{display:grid;grid-template-columns:repeat(3,minmax(0,1fr));gap:8px}
.pair{display:flex;flex-wrap:wrap;gap:4px;align-items:flex-end}.pair img{min-width:0;max-width:100%}
.pair.both img{height:150px;width:auto;max-width:58%;object-fit:contain}
.pair.both img.side{max-width:40%;border:none}.pair figcaption{flex-basis:100%}
.figs{display:grid;grid-template-columns:repeat(2,minmax(0,1fr));gap:10px;margin:6px 0}
.figs.three{grid-template-columns:repeat(3,minmax(0,1fr))}.figs.post{grid-template-columns:3fr 2fr}
details{margin:4px 0}summary{cursor:pointer}details.raw{border-bottom:1px solid #eee;padding:2px 0}
@media (max-width:1200px){.grid{grid-template-columns:1fr}.gallery,.figs.three{grid-template-columns:1fr 1fr}
.figs.post{grid-template-columns:1fr}}"""


def first_screen(f: RunFiles) -> str:
    """Headline and verdict, then the posterior, the fit, the error history, the ranking, the surrogate's
    best fit and the photographs."""
    fit = fit_rows(f)
    post, point = f.table("posterior/summary.parquet"), params_card(f)
    # the answer leads: the posterior where there is one, else the surrogate's best fit (and the posterior's
    # "not run yet" beside the history)
    lead, aside = (point, posterior_card(f)) if point and (post is None or post.empty) else (posterior_card(f), point)
    return (f"<section id=summary>{headline(f, fit)}<div class=grid>{lead}{fit_card(f, fit)}"
            f"<div class=stack>{history_card(f)}{ranking_card(f)}{aside}</div>"
            f"{photos_card(f)}</div></section>")


def build_report(run: Path) -> str:
    """The HTML page `calib report` writes to RUN/report.html."""
    f = RunFiles(Path(run))
    if not any(f.has_dir(s) for s in RAW_STAGES):
        raise CalibError(f"{f.run} holds no stage output to report")
    nav = " ".join(f"<a href='#{a}'>{t}</a>" for a, t in SECTIONS)
    head = (f"<!doctype html><html lang=en><meta charset=utf-8><meta name=viewport content='width=device-width'>"
            f"<title>calib report: {esc(f.run.name)}</title><style>{CSS}</style>"
            f"<h1>calib report: {esc(f.run)}</h1><nav>Sections: {nav} "
            f"<span class=prov>&middot; calib {esc(__version__)}</span></nav>")
    return "\n".join([head, first_screen(f), *(r(f) for r in RENDERERS)])
