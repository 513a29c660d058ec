"""Small HTML builders for the report: escaped text, scrollable tables, figures, the run's files."""

from __future__ import annotations

import html
import math
import re
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from .. import artifacts as art


def esc(x) -> str:
    return html.escape(str(x))


def prose(x) -> str:
    """A sentence of the library's (a ranking's reason, a note) escaped, its `backticked` commands as code, and a
    percentage spaced as the page writes them ("28 %")."""
    parts = re.split(r"(`[^`]+`)", str(x))  # a command's text stays as typed
    return "".join(f"<code>{esc(p[1:-1])}</code>" if p.startswith("`") and p.endswith("`") and len(p) > 1
                   else re.sub(r"(\d)%", r"\1 %", esc(p)) for p in parts)


def num(v, digits: int = 4) -> str:
    """A number to `digits` significant figures; blank for NaN or None."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return esc(v)
    return "" if math.isnan(f) else f"{f:.{digits}g}"


def deg(v, digits: int = 2) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return ""
    return "" if math.isnan(f) else f"{f:.{digits}f}&deg;"


def words(names) -> str:
    """'a', 'a and b', 'a, b and c', with underscores read as spaces."""
    n = [esc(str(x).replace("_", " ")) for x in names]
    return " and ".join(n) if len(n) < 3 else ", ".join(n[:-1]) + " and " + n[-1]


def scroll(inner: str) -> str:
    """A horizontally scrollable box: a wide table scrolls inside it instead of overflowing the page."""
    return f"<div class=scroll>{inner}</div>"


def _cell(v, digits: int) -> str:
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (float, np.floating)):
        return "" if np.isnan(v) else f"{v:.{digits}g}"
    return "" if v is None else prose(v)  # a reason's `command` as code, as the cards show it


def table(df: pd.DataFrame, max_rows: int = 40, digits: int = 5) -> str:
    """The first max_rows rows in a scroll box; numeric columns right-aligned, text left."""
    shown = df.head(max_rows)
    more = f"<p class=prov>{len(df) - max_rows} more rows in the Parquet file</p>" if len(df) > max_rows else ""
    numeric = [pd.api.types.is_numeric_dtype(t) and not pd.api.types.is_bool_dtype(t) for t in shown.dtypes]
    head = "".join(f"<th{' class=n' * n}>{esc(c)}</th>" for c, n in zip(shown.columns, numeric))
    body = "".join("<tr>" + "".join(f"<td{' class=n' * n}>{_cell(v, digits)}</td>" for v, n in zip(r, numeric))
                   + "</tr>" for r in shown.itertuples(index=False))
    return scroll(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>") + more


def rows_table(head: list[str], rows: list[list[str]], cls: str = "") -> str:
    """A table of already-escaped cells."""
    th = "".join(f"<th>{h}</th>" for h in head)
    tr = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return scroll(f"<table class='{cls}'><thead><tr>{th}</tr></thead><tbody>{tr}</tbody></table>")


def img(run: Path, path: Path, alt: str = "", cls: str = "") -> str:
    """An image linked by its path relative to the run directory (report.html lives there)."""
    rel = path.relative_to(run).as_posix()
    c = f" class={cls}" if cls else ""
    return f'<img src="{esc(rel)}" alt="{esc(alt or path.name)}" loading=lazy{c}>'


def figure(run: Path, path: Path, caption: str, cls: str = "") -> str:
    return f"<figure{' class=' + cls if cls else ''}>{img(run, path)}<figcaption>{caption}</figcaption></figure>"


def note(text: str, cls: str = "note") -> str:
    return f"<p class={cls}>{text}</p>"


def badge(text: str, kind: str) -> str:
    """A coloured label: kind is pass, fail, warn or info. A short one is kept on one line ("1 of 6 |z| > 2"
    broken over four reads as four labels); a sentence may wrap."""
    return f"<span class='badge {kind}{' nw' * (len(text) <= 24)}'>{esc(text)}</span>"


class RunFiles:
    """Read-only, cached access to a run directory's artefacts; a missing file reads as None."""

    def __init__(self, run: Path):
        self.run = Path(run)
        self._tables: dict[str, Optional[pd.DataFrame]] = {}

    def path(self, rel: str) -> Optional[Path]:
        p = self.run / rel
        return p if p.is_file() else None

    def table(self, rel: str) -> Optional[pd.DataFrame]:
        if rel not in self._tables:
            p = self.path(rel)
            self._tables[rel] = art.read_table(p) if p else None
        return self._tables[rel]

    def prov(self, rel: str) -> dict:
        p = self.path(rel)
        return art.read_provenance(p) if p else {}

    def has_dir(self, rel: str) -> bool:
        return (self.run / rel).is_dir()

    def pngs(self, rel_dir: str, pattern: str = "*.png") -> list[Path]:
        d = self.run / rel_dir
        return sorted(d.glob(pattern)) if d.is_dir() else []
