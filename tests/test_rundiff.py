"""`calib diff-runs` / stages.rundiff: a run's headline numbers beside a reference run's."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
from typer.testing import CliRunner

from calib_cli.cli import app
from calib_cli.stages.rundiff import diff_runs

ROOT = Path(__file__).resolve().parents[1]


def _copy(name: str, to: Path) -> Path:
    shutil.copytree(ROOT / "sample_runs" / name, to)
    return to


def test_a_run_agrees_with_its_copy_and_says_its_heaps_are_the_same(tmp_path):
    d = diff_runs(_copy("calibration", tmp_path / "c"), ROOT / "sample_runs" / "calibration")
    assert d.same and len(d.table) >= 10
    assert any("50 of 50 shared heaps came out bit for bit" in r for r in d.reasons)


def test_a_changed_calibration_is_flagged_and_blamed_on_the_analysis(tmp_path):
    run = _copy("paper", tmp_path / "p")
    sol = pd.read_parquet(run / "invert" / "solution.parquet")
    sol.loc[0, "static_friction"] += 0.01
    sol.to_parquet(run / "invert" / "solution.parquet")
    d = diff_runs(run, ROOT / "sample_runs" / "paper")
    assert not d.same
    assert list(d.table.loc[d.table["same"] != "yes", "quantity"]) == ["calibrated static_friction"]


def test_other_heaps_are_named_as_other_requests(tmp_path):
    d = diff_runs(ROOT / "sample_runs" / "calibration", ROOT / "sample_runs" / "calibration-spring")
    assert not d.same and any("other requests" in r for r in d.reasons)


def test_the_command_prints_the_table_and_exits_1_with_strict_when_numbers_differ(tmp_path):
    r = CliRunner().invoke(app, ["diff-runs", str(ROOT / "sample_runs" / "paper"), str(ROOT / "sample_runs" / "paper")])
    assert r.exit_code == 0 and "every number as in the reference" in r.output
    r = CliRunner().invoke(app, ["diff-runs", "--strict", str(ROOT / "sample_runs" / "calibration"),
                                 str(ROOT / "sample_runs" / "calibration-spring")])
    assert r.exit_code == 1 and "numbers differ" in r.output
    r = CliRunner().invoke(app, ["diff-runs", str(tmp_path / "nothing"), str(ROOT / "sample_runs" / "paper")])
    assert r.exit_code == 2 and "no run directory" in r.output


def test_a_best_json_edited_by_hand_leaves_its_headline_out(tmp_path):
    """surrogate/best.json's "best" an object, not a model's name, was exit 70 (a dict compared with a column)."""
    run = _copy("smoke", tmp_path / "s")
    (run / "surrogate" / "best.json").write_text('{"best": {}}')
    d = diff_runs(run, ROOT / "sample_runs" / "smoke")
    row = d.table.set_index("quantity").loc["surrogate chosen, its leave-one-out R2"]
    assert not d.same and row["same"] != "yes"
