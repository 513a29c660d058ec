"""Inline SVG charts (no JavaScript, no image file): the measured-vs-simulated fit per condition."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from .html import esc

MEASURED, SIMULATED, FAIL, PASS = "#222", "#1f6fb4", "#c0392b", "#1e8449"


def _ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    span = max(hi - lo, 1e-9)
    step = next(s for s in (0.5, 1, 2, 5, 10, 20, 50, 100) if span / s <= n) if span <= 500 else span / n
    return np.arange(math.ceil(lo / step) * step, hi + 1e-9, step)


def _range(df: pd.DataFrame) -> tuple[float, float]:
    vals = []
    for c, s in (("measured", "measured_sd"), ("simulated", "simulated_sd")):
        v, e = df[c].to_numpy(float), np.nan_to_num(df[s].to_numpy(float))
        vals += list(v - e) + list(v + e)
    vals = [v for v in vals if np.isfinite(v)]
    if not vals:
        return 0.0, 1.0
    lo, hi = min(vals), max(vals)
    pad = max(0.5, 0.05 * (hi - lo))
    return math.floor(lo - pad), math.ceil(hi + pad)


def _whisker(x, v, sd, y, colour, shape) -> str:
    if not np.isfinite(v):
        return ""
    out = ""
    if np.isfinite(sd) and sd > 0:
        out += (f"<line x1='{x(v - sd):.1f}' x2='{x(v + sd):.1f}' y1='{y}' y2='{y}' stroke='{colour}' "
                f"stroke-width='1.5'/>")
    if shape == "circle":
        return out + f"<circle cx='{x(v):.1f}' cy='{y}' r='3.6' fill='{colour}'/>"
    return out + f"<rect x='{x(v) - 3.5:.1f}' y='{y - 3.5}' width='7' height='7' fill='{colour}'/>"


def fit_chart(df: pd.DataFrame, width: int = 420) -> str:
    """One row a condition: measured (dot) and simulated (square), each +-1 sd, and pass/fail.

    df: condition_id, measured, measured_sd, simulated, simulated_sd, fails (True, False or None)."""
    lab_w, stat_w, row_h, top = 112, 40, 22, 20
    plot_w = width - lab_w - stat_w
    lo, hi = _range(df)

    def x(v):
        return lab_w + (v - lo) / (hi - lo) * plot_w

    height = top + row_h * len(df) + 4
    parts = [f"<svg class=chart viewBox='0 0 {width} {height}' width='{width}' height='{height}' "
             f"role='img' aria-label='measured and simulated repose angle per condition'>"]
    for t in _ticks(lo, hi):
        parts.append(f"<line x1='{x(t):.1f}' x2='{x(t):.1f}' y1='{top - 4}' y2='{height - 2}' stroke='#e3e3e3'/>"
                     f"<text x='{x(t):.1f}' y='{top - 8}' text-anchor='middle'>{t:g}&#176;</text>")
    for i, r in enumerate(df.itertuples(index=False)):
        y = top + i * row_h + row_h // 2
        fails = getattr(r, "fails", None)
        status = "" if fails is None or (isinstance(fails, float) and math.isnan(fails)) else \
            (f"<text x='{width - stat_w + 6}' y='{y + 4}' fill='{FAIL}' font-weight='bold'>fail</text>" if fails
             else f"<text x='{width - stat_w + 6}' y='{y + 4}' fill='{PASS}'>pass</text>")
        if fails is not None and not np.isfinite(float(r.simulated)):  # compared, but the model formed no heap
            status = f"<text x='{width - stat_w + 6}' y='{y + 4}' fill='{FAIL}' font-weight='bold'>no heap</text>"
        parts.append(f"<text x='{lab_w - 6}' y='{y + 4}' text-anchor='end'>{esc(r.condition_id)}</text>"
                     + _whisker(x, float(r.measured), float(r.measured_sd), y - 4, MEASURED, "circle")
                     + _whisker(x, float(r.simulated), float(r.simulated_sd), y + 4, SIMULATED, "square")
                     + status)
    parts.append("</svg>")
    return "".join(parts)


def legend(simulated_label: str = "simulated") -> str:
    return (f"<p class=legend><span style='color:{MEASURED}'>&#9679;</span> measured &plusmn; sd &nbsp; "
            f"<span style='color:{SIMULATED}'>&#9632;</span> {esc(simulated_label)} &plusmn; sd</p>")
