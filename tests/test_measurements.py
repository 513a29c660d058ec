"""calib_cli.measurements: the measured conditions every analysis reads, checked where they are read (a table
whose stage lock is gone can hold anything a hand edit left)."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from calib_cli.errors import CalibError
from calib_cli.measurements import CONDITIONS, measured_conditions

GOOD = pd.DataFrame({"condition_id": ["A", "B"], "mean": [33.7, 30.4], "sd": [2.5, math.nan], "n": [10, 1]})


def _run(tmp_path, table: pd.DataFrame):
    (tmp_path / CONDITIONS).parent.mkdir(parents=True, exist_ok=True)
    table.to_parquet(tmp_path / CONDITIONS)
    return tmp_path


def test_a_good_table_reads_as_written_one_pile_without_an_sd(tmp_path):
    assert measured_conditions(_run(tmp_path, GOOD)).equals(GOOD)


@pytest.mark.parametrize("edit, words", [
    (dict(mean=[math.nan, 30.4]), "condition A has mean nan deg"),
    (dict(mean=[math.inf, 30.4]), "condition A has mean inf deg"),
    (dict(mean=[400.0, 30.4]), "a mean angle in (0, 90) deg"),
    (dict(sd=[-1.0, math.nan]), "an sd >= 0"),
    (dict(sd=[math.nan, math.nan], n=[10, 1]), "condition A"),  # ten piles need their sd
    (dict(n=[math.nan, 1]), "a whole number of piles"),
    (dict(mean=["abc", "30.4"]), "column(s) mean hold text where numbers belong"),
    (dict(condition_id=[None, None]), "every condition needs a condition_id"),
])
def test_nan_text_or_an_impossible_angle_is_one_line_naming_the_condition(tmp_path, edit, words):
    """These met the posterior as NaN ('Probability function returned NaN') or text: internal errors."""
    with pytest.raises(CalibError, match=None) as e:
        measured_conditions(_run(tmp_path, GOOD.assign(**edit)))
    assert words in str(e.value) and "\n" not in str(e.value)


def test_a_condition_whose_photographs_were_all_flagged_is_named_as_unmeasured(tmp_path):
    """measure-angle writes n 0 (mean and sd empty) for it: the message says so, not that the table is wrong."""
    with pytest.raises(CalibError, match="condition.s. B have no measured angle"):
        measured_conditions(_run(tmp_path, GOOD.assign(mean=[33.7, math.nan], n=[10, 0])))


def test_a_condition_where_every_pile_stood_is_left_to_the_column_share_and_others_without_an_angle_refused(tmp_path):
    """C's three piles (two photographs each) all stood: no angle, so the analyses leave it out and the share
    of columns weighs it (3 piles). Where its photographs are unreadable, or some formed heaps flagged as no
    cone, it is refused, as before."""
    from calib_cli import artifacts as art
    from calib_cli.measurements import standing_conditions

    table = pd.concat([GOOD, pd.DataFrame({"condition_id": ["C"], "mean": [math.nan], "sd": [math.nan], "n": [0]})],
                      ignore_index=True)
    run = _run(tmp_path, table)
    angles = pd.DataFrame({"image": ["a1", "c1", "c2", "c3", "c4", "c5", "c6"], "condition_id": ["A"] + ["C"] * 6,
                           "status": ["ok"] + ["column"] * 6, "pile": ["1", "1", "1", "2", "2", "3", "3"]})
    art.write_table(run / "measure" / "angles.parquet", angles)
    got = measured_conditions(run)
    assert got["condition_id"].tolist() == ["A", "B"]
    stood = standing_conditions(run)
    assert stood["condition_id"].tolist() == ["C"] and stood["piles"].tolist() == [3.0]
    for statuses in (["unreadable"] * 6, ["column", "column", "asymmetric", "asymmetric", "not_cone", "column"]):
        art.write_table(run / "measure" / "angles.parquet", angles.assign(status=["ok"] + statuses))
        with pytest.raises(CalibError, match="condition.s. C have no measured angle"):
            measured_conditions(run)
    art.write_table(run / "measure" / "angles.parquet", angles.assign(status="column"))
    table.iloc[[2]].to_parquet(run / CONDITIONS)  # C alone
    with pytest.raises(CalibError, match="every pile of every measured condition .* stood as a column"):
        measured_conditions(run)


@pytest.mark.parametrize("edit, words", [
    ({"fil_height_mm": [75.0]}, "fil_height_mm"),                    # a misspelt column, once ignored
    ({"fill_height_mm": [math.nan]}, "fill_height_mm"),              # once the preset's 120 mm
    ({"fill_height_mm": ["20"], "cylinder_diameter_mm": ["x"]}, "cylinder_diameter_mm"),
])
def test_a_parquet_conditions_table_is_checked_as_a_csv_one(tmp_path, edit, words):
    """simulate-heap --conditions T.parquet skipped every check a CSV table gets and ran heaps on another rig."""
    from calib_cli import artifacts as art
    from calib_cli.stages.simulate import read_conditions_table

    base = {"condition_id": ["A"], "particle_d_min_mm": [4.0], "particle_d_max_mm": [5.0],
            "cylinder_diameter_mm": [40.0], "fill_height_mm": [75.0]}
    art.write_table(tmp_path / "ok.parquet", pd.DataFrame(base))
    assert read_conditions_table(tmp_path / "ok.parquet")["fill_height_mm"].tolist() == [75.0]
    table = {k: v for k, v in base.items() if not (k == "fill_height_mm" and "fil_height_mm" in edit)}
    art.write_table(tmp_path / "bad.parquet", pd.DataFrame({**table, **edit}))
    with pytest.raises(CalibError, match=words):
        read_conditions_table(tmp_path / "bad.parquet")
