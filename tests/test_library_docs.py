"""docs/library.md's examples run: the paper's chain from Python (fast), the smoke calibration (slow)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "library.md"


def _code(section: str) -> str:
    """The python blocks of the section whose heading starts with ``section``."""
    text = DOC.read_text()
    part = text.split(f"\n## {section}", 1)[1].split("\n## ", 1)[0]
    return "\n".join(re.findall(r"```python\n(.*?)```", part, re.S))


def _run_in(tmp_path: Path, monkeypatch, code: str) -> dict:
    monkeypatch.chdir(tmp_path)  # not the repository's root: the examples find its sample data themselves
    scope: dict = {}
    exec(compile(code, str(DOC), "exec"), scope)
    return scope


def test_the_paper_example_runs(tmp_path, monkeypatch, capsys):
    scope = _run_in(tmp_path, monkeypatch, _code("The paper's chain"))
    sol = scope["solution"].summary()
    assert abs(float(sol["predicted_angle"].iloc[0]) - 32.07) < 0.1, sol
    assert "32.07" in capsys.readouterr().out  # Table 1's mean, in measure's summary
    # a second pass finds every stage up to date
    from calib_cli.stages import doe, invert

    assert doe.bbd_analyze(scope["run"], responses=scope["data"] / "table7_bbd.csv").skipped
    again = invert.invert(scope["run"])
    assert again.skipped and again.summary().equals(sol)


@pytest.mark.slow
def test_the_smoke_example_runs(tmp_path, monkeypatch):
    scope = _run_in(tmp_path, monkeypatch, _code("The smoke calibration"))
    assert scope["result"].stats["n_conditions"] == 1
    assert (tmp_path / "runs" / "smoke" / "compare" / "residuals.parquet").is_file()
