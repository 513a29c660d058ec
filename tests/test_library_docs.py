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
    # a second pass of the whole example (a notebook's cell run again) finds every stage up to date, and its
    # results still carry what the example reads: the surface's equation, the inversion's ranges and verdict
    again_scope = _run_in(tmp_path, monkeypatch, _code("The paper's chain"))
    assert scope["bbd"].rsm.equation() in capsys.readouterr().out
    from calib_cli.stages import doe, invert

    bbd = again_scope["bbd"]
    assert bbd.skipped and bbd.rsm.equation() == scope["bbd"].rsm.equation()
    assert bbd.coefficients.equals(scope["bbd"].coefficients)
    pb = doe.pb_analyze(scope["run"], responses=scope["data"] / "table3_pb.csv")
    assert pb.skipped and pb.analysis is not None
    # what the commands warn of is the results' own: the paper's surface fits (Table 8's lack of fit p 0.1576)
    assert bbd.warnings() == [] and doe.ascent_analyze(scope["run"], responses=scope["data"] /
                                                       "table5_ascent.csv").warnings() == []
    again = invert.invert(scope["run"])
    assert again.skipped and again.summary().equals(sol)
    for name in ("identifiable", "n_near", "tolerance", "target_source", "warning_lines", "verdict"):
        assert getattr(again, name) == getattr(scope["solution"], name), name
    # the same results read back from the files alone (stages.load), as a later notebook opens them
    from calib_cli.stages.load import load

    assert load(scope["run"], "bbd").warnings() == bbd.warnings()
    assert load(scope["run"], "pb").summary().equals(pb.summary())
    assert load(scope["run"], "invert").summary().equals(sol)
    assert load(scope["run"], "invert").warnings() == scope["solution"].warnings()


def test_the_reading_example_runs(tmp_path, monkeypatch, capsys):
    scope = _run_in(tmp_path, monkeypatch, _code("Reading a finished run"))
    assert scope["answer"].summary()["parameter"].tolist()[-1] == "surface_energy"
    out = capsys.readouterr().out
    assert "surface_energy" in out and "cohesion" in out


@pytest.mark.slow
def test_the_smoke_example_runs(tmp_path, monkeypatch):
    scope = _run_in(tmp_path, monkeypatch, _code("The smoke calibration"))
    assert scope["result"].stats["n_conditions"] == 1
    assert (tmp_path / "runs" / "smoke" / "compare" / "residuals.parquet").is_file()
