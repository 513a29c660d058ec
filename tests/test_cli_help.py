"""Every command's --help as a user sees it: no text eaten as markup, no reference to files users do
not have, commands in workflow order, lines within 100 columns."""

from __future__ import annotations

import re

import pytest
import typer
from typer.testing import CliRunner

from calib_cli.cli import app

WIDTH = 100


def _commands(group, prefix=()):
    for name, cmd in group.commands.items():
        path = (*prefix, name)
        yield path, cmd
        if hasattr(cmd, "commands"):
            yield from _commands(cmd, path)


ROOT = typer.main.get_command(app)
COMMANDS = list(_commands(ROOT))


def _help(path) -> str:
    r = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": str(WIDTH), "TERM": "dumb"})
    assert r.exit_code == 0, r.output
    return r.output


def _flat(text: str) -> str:
    """The words of a rendered help page, without box drawing and line wrapping."""
    return re.sub(r"\s+", " ", re.sub(r"[│╭╮╰╯─]", " ", text))


@pytest.mark.parametrize("path", [p for p, _ in COMMANDS], ids=lambda p: " ".join(p))
def test_help_shows_every_bracketed_word_and_cites_no_spec(path):
    cmd = dict(COMMANDS)[path]
    out = _help(path)
    assert "SPEC" not in out
    texts = [cmd.help or ""] + [getattr(p, "help", None) or "" for p in cmd.params]
    flat = _flat(out).replace(" ", "")
    for token in re.findall(r"(?<!\\)\[[^\]\[]+\]", " ".join(texts)):
        if token.startswith("[/") or re.fullmatch(r"\[(bold|dim|green|red|yellow|cyan|italic)[^\]]*\]", token):
            continue  # styling meant as markup
        assert token.replace(" ", "") in flat, f"`calib {' '.join(path)} --help` lost {token!r}"
    assert max(len(line) for line in out.splitlines()) <= WIDTH


def test_commands_are_listed_in_workflow_order():
    out = _help(())
    order = ["init", "measure-angle", "pb", "ascent", "bbd", "simulate-heap", "fit-surrogate", "invert",
             "compare", "diagnose", "report"]
    where = [re.search(rf"│ {re.escape(c)}\s", out).start() for c in order]
    assert where == sorted(where), out


def test_version():
    r = CliRunner().invoke(app, ["--version"])
    assert r.exit_code == 0 and r.output.startswith("calib ")


def test_user_docs_cite_no_spec():
    """Users have docs/, not the product specification: no page may send them to it."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    pages = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    cited = [p.name for p in pages if re.search(r"\bSPEC\b", p.read_text())]
    assert not cited, f"pages citing SPEC: {cited}"


def test_a_wide_result_table_comes_in_parts_that_fit_100_columns(tmp_path, monkeypatch):
    """measure-angle's per-condition statistics (110 columns whole, as the tutorial shows them) on a
    100-column terminal: every line fits, nothing is cut to '…', and every column is shown, in parts
    that each start with the condition the row belongs to."""
    import numpy as np

    from calib_cli import artifacts as art
    from calib_cli.cli import common

    monkeypatch.setattr(common.console, "width", WIDTH)
    rng = np.random.default_rng(0)
    conditions = ["d4-5_D40_H100", "d4-5_D40_H50", "d5-6_D40_H75"]
    rows = [(f"i{c}{k}", cond, 30 + 6 * rng.standard_normal()) for c, cond in enumerate(conditions) for k in range(10)]
    (tmp_path / "a.csv").write_text("image,repose_angle,condition_id\n" + "".join(f"{i},{a:.4f},{c}\n" for i, c, a in rows))
    r = CliRunner().invoke(app, ["measure-angle", "--run", str(tmp_path / "run"), "--angles", str(tmp_path / "a.csv")])
    assert r.exit_code == 0, r.output
    per_condition = r.output[r.output.index("Per condition"):]
    assert "(2 of" in per_condition  # whole, it would not fit
    assert max(map(len, r.output.splitlines())) <= WIDTH and "…" not in r.output
    parts = per_condition.split("(2 of")
    for column in ["n", "mean", "median", "sd", "range", "cv_percent", "se", "ci95_low", "ci95_high"]:
        assert f" {column} " in per_condition, column
    for part in parts:
        assert all(c in part for c in conditions)
    stats = art.read_table(tmp_path / "run" / "measure" / "conditions.parquet")
    assert f"{stats['ci95_high'].iloc[0]:.5g}" in per_condition


@pytest.mark.parametrize("path", [p for p, _ in COMMANDS], ids=lambda p: " ".join(p))
def test_the_description_is_wrapped_at_the_terminal_not_at_the_docstring(path):
    """In an 80-column terminal each paragraph of the description fills its lines (typer keeps the
    docstring's own line breaks after the first paragraph, which came out as ragged half-lines): every
    line of a paragraph but its last reaches past half the width."""
    r = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": "80", "TERM": "dumb"})
    head = r.output.split("╭")[0]  # the usage line and the description, before the options' boxes
    paragraphs = [p.splitlines() for p in re.split(r"\n\s*\n", head.split("Usage:", 1)[1])[1:]]
    short = [line for p in paragraphs for line in p[:-1] if len(line.rstrip()) < 40]
    assert not short, short


def test_unwrap_keeps_paragraphs_and_blocks_marked_as_written():
    from calib_cli.cli.common import unwrap_paragraphs

    assert unwrap_paragraphs("One\nline.\n\nTwo\n  lines.") == "One line.\n\nTwo lines."
    assert unwrap_paragraphs("Intro.\n\n\b\na\nb") == "Intro.\n\n\b\na\nb"
    assert unwrap_paragraphs(None) is None
    assert unwrap_paragraphs("Details.\n\f\n:param x: internal") == "Details."
