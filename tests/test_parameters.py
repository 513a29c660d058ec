"""Each value a user gives is declared once (calib_cli.parameters) and checked where it enters: the
likely mistake named in one line, a deliberate extreme let through by CALIB_ALLOW_EXTREME=1, the
declarations the code's own defaults follow."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, strategies as st

from calib_cli import parameters as P
from calib_cli.conditions import read_conditions_csv
from calib_cli.errors import CalibError
from calib_cli.heaps.inputs import checked_condition, parse_pairs, parse_params

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name,value,says", [
    ("particle_d_min_mm", 0.004, "are these metres (4 mm)?"),
    ("cylinder_diameter_mm", 4, "are these centimetres (40 mm)?"),
    ("lift_speed_mm_s", 0.05, "is this in m/s (50 mm/s)?"),
    ("surface_energy", 350, "is this in mJ/m2 (0.35 J/m2)?"),
    ("repose_angle", 0.56, "is this in radians (32.09 deg)?"),
    ("shear_modulus", 150, "is this in MPa (1.5e+08 Pa)?"),
    ("rolling_friction", 5, "rolling resistance coefficients of real grains lie in 0-0.5"),
])
def test_an_implausible_value_names_its_likely_mistake_in_one_line(name, value, says):
    with pytest.raises(CalibError) as e:
        P.check(name, value, "here")
    msg = str(e.value)
    assert says in msg and "(here)" in msg and P.ALLOW_EXTREME in msg and "\n" not in msg, msg


def test_an_extreme_is_let_through_on_request_but_not_past_what_the_model_accepts(monkeypatch):
    monkeypatch.setenv(P.ALLOW_EXTREME, "1")
    assert P.check("rolling_friction", 0.9) == 0.9
    assert P.check("particle_d_min_mm", 0.1) == 0.1
    for name, value in (("restitution", 0.0), ("restitution", 1.5), ("static_friction", -0.1),
                        ("shear_modulus", -5e6), ("repose_angle", math.inf), ("surface_energy", math.nan)):
        with pytest.raises(CalibError, match="is outside|must be"):
            P.check(name, value)


@given(st.sampled_from(sorted(P.QUANTITIES)), st.floats(allow_nan=True, allow_infinity=True))
def test_check_returns_the_value_or_refuses_it_in_one_line(name, value):
    try:
        v = P.check(name, value)
    except CalibError as e:
        assert "\n" not in str(e) and name in str(e)
    else:
        q = P.QUANTITIES[name]
        assert v == value and q.accepts(v) and q.plausible[0] <= v <= q.plausible[1]


def test_the_code_defaults_follow_the_declarations():
    from calib_cli.dem.heap import CONDITION_VARIABLES, PARTICLE_DEFAULTS, PRESETS, HeapCondition

    for k in ("static_friction", "rolling_friction", "surface_energy", "restitution"):
        assert PARTICLE_DEFAULTS[k] == P.PARAMETERS[k].default
    assert set(CONDITION_VARIABLES) == set(P.CONDITION_VARIABLES)
    for f in dataclasses.fields(HeapCondition):
        if f.name in P.CONDITION_VARIABLES and not f.name.startswith("floor_"):
            assert f.default == P.CONDITION_VARIABLES[f.name].default, f.name
    assert tuple(PRESETS) == P.PRESET_NAMES
    from calib_cli.dem.system import PRECISIONS
    assert PRECISIONS == P.PRECISION_NAMES
    from calib_cli.heaps.inputs import RUN_ENGINES
    assert tuple(RUN_ENGINES) == P.ENGINE_NAMES
    for pre in PRESETS.values():  # every preset's rig is plausible
        for k in P.CONDITION_VARIABLES:
            v = getattr(pre.condition, k)
            if not math.isnan(v):
                P.check(k, v)


def test_set_and_condition_values_are_checked_where_they_enter():
    with pytest.raises(CalibError, match="given twice"):
        parse_pairs(["static_friction=0.3", "static_friction=0.5"], "--set")
    with pytest.raises(CalibError, match="did you mean static_friction"):
        parse_params({"static_fricton": 0.3})
    with pytest.raises(CalibError, match="mJ/m2"):
        parse_params({"wall_surface_energy": 350})
    with pytest.raises(CalibError, match="metres"):
        checked_condition(["particle_d_max_mm=0.005"])
    assert parse_params({"static_friction": "0.4", "contact_angle": 20}) == {"static_friction": 0.4, "contact_angle": 20}
    # `--set restitution=true` read 1.0; a contact law's switch takes true as on
    with pytest.raises(CalibError, match="restitution must be a number .*got True"):
        parse_params(parse_pairs(["restitution=true"], "--set"))
    with pytest.raises(CalibError, match="restitution must be a number .*got np.True_"):
        parse_params({"restitution": np.True_})
    with pytest.raises(CalibError, match="surface_tension must be a number, got True"):
        parse_params({"surface_tension": True})
    assert parse_params(parse_pairs(["rolling_spring=true"], "--set")) == {"rolling_spring": 1.0}


def test_a_factor_of_a_contact_law_s_own_value_is_checked_when_the_settings_are_read():
    """A law's values are declared with the law (calib_cli.dem.laws); a factor range beyond what the law accepts
    is refused by `calib init`, not at the first heap of a design."""
    from calib_cli.settings import check_types

    with pytest.raises(CalibError, match=r"factors.surface_tension.low: surface_tension .* must lie in \[0, 1\] "
                                         r"N/m \(got -0.5\)"):
        check_types({"factors": {"surface_tension": {"low": -0.5, "high": 0.07}}})
    check_types({"factors": {"surface_tension": {"low": 0.0, "high": 0.07}}})


@pytest.mark.parametrize("text,says", [
    ("image,condition_id\nh.png,\n", "condition_id is empty on line(s) 2"),
    ("image;condition_id\nh.png;A\n", "separates its columns with semicolons"),
    ("image,condition_id,fill_hight_mm\nh.png,A,50\n", "did you mean fill_height_mm?"),
    ("image,condition_id,fill_height_mm\nh.png,A,50\ng.png,A,75\n", "condition A has fill_height_mm 50 and 75"),
    ("image,condition_id,lift_speed_mm_s\nh.png,A,0.05\n", "lift_speed_mm_s = 0.05 mm/s (conditions file line 2)"),
    ("image,condition_id,fill_height_mm\nh.png,A,tall\n", "non-numeric value on line 2"),
    ("image\nh.png\n", "lacks column(s) condition_id"),
])
def test_a_conditions_table_is_refused_with_what_is_wrong(tmp_path, text, says):
    (tmp_path / "c.csv").write_text(text)
    with pytest.raises(CalibError) as e:
        read_conditions_csv(tmp_path / "c.csv", need=("image", "condition_id"))
    assert says in str(e.value), str(e.value)


def test_a_good_conditions_table_reads_with_free_columns(tmp_path):
    (tmp_path / "c.csv").write_text("image,condition_id,notes,fill_height_mm,floor_static_friction\n"
                                    "h.png,A,first,50,0.3\ng.png,1,,75,0.4\n")
    df = read_conditions_csv(tmp_path / "c.csv", need=("image", "condition_id"))
    assert list(df["condition_id"]) == ["A", "1"] and list(df["fill_height_mm"]) == [50.0, 75.0]


def test_an_images_folder_with_a_folder_or_a_link_loop_named_as_a_photo_is_refused_in_one_line(tmp_path):
    import os

    from typer.testing import CliRunner

    from calib_cli.cli import app

    photo = (ROOT / "sample_data" / "photos" / "heap_01.png").read_bytes()
    for case in ("folder", "loop"):
        images = tmp_path / case
        images.mkdir()
        (images / "h.png").write_bytes(photo)
        if case == "folder":
            (images / "x.png").mkdir()
        else:
            os.symlink(images / "y.png", images / "y.png")
        r = CliRunner().invoke(app, ["measure-angle", "--run", str(tmp_path / f"run-{case}"), "--images", str(images)])
        assert r.exit_code == 2 and "is named as a photograph but is not a readable file" in r.output, r.output
        assert not (tmp_path / f"run-{case}" / "measure").exists()


def test_a_webp_photograph_is_measured(tmp_path):
    import cv2
    import numpy as np

    from calib_cli.stages.measure import measure_angle

    gray = cv2.imread(str(ROOT / "sample_data" / "photos" / "heap_01.png"), cv2.IMREAD_GRAYSCALE)
    (tmp_path / "im").mkdir()
    cv2.imwrite(str(tmp_path / "im" / "h.webp"), gray, [cv2.IMWRITE_WEBP_QUALITY, 101])  # lossless
    res = measure_angle(tmp_path / "run", images=tmp_path / "im")
    assert list(res.angles["image"]) == ["h.webp"] and np.isfinite(res.angles["repose_angle"]).all()


def test_simulate_heap_simulates_the_photographed_rigs_unless_told_otherwise(tmp_path):
    import pandas as pd

    from calib_cli.stages.simulate import plan_simulation

    run = tmp_path / "run"
    (run / "measure").mkdir(parents=True)
    pd.DataFrame({"condition_id": ["A"], "mean": [30.0], "sd": [1.0], "n": [5], "particle_d_min_mm": [4.0],
                  "particle_d_max_mm": [5.0], "cylinder_diameter_mm": [40.0], "fill_height_mm": [75.0],
                  "lift_speed_mm_s": [50.0]}).to_parquet(run / "measure" / "conditions.parquet")
    said: list[str] = []
    plan = plan_simulation(run, ["static_friction=0.3"], preset="smoke", say=said.append)
    assert [(r.condition_id, r.condition.cylinder_diameter_mm) for r in plan.requests] == [("A", 40.0)]
    assert "1 condition(s) from" in said[0] and "measure/conditions.parquet" in said[0], said
    for how in ({"conditions": "preset"}, {"condition": ["fill_height_mm=60"]}):
        said.clear()
        plan = plan_simulation(run, ["static_friction=0.3"], preset="smoke", say=said.append, **how)
        assert plan.requests[0].condition.cylinder_diameter_mm == 50.0  # the preset's rig
        assert any("measured rig(s)" in s and "--conditions preset" in s and "6-8 mm grains" in s for s in said), said
    # a measured table that does not read: the photographed rigs cannot be simulated, an error; the preset's
    # rig, as asked or as --condition changes it, needs the table for a note only
    (run / "measure" / "conditions.parquet").write_bytes(b"garbage")
    with pytest.raises(CalibError, match="measured conditions .* not a readable Parquet file"):
        plan_simulation(run, ["static_friction=0.3"], preset="smoke")
    for how in ({"conditions": "preset"}, {"condition": ["fill_height_mm=60"]}):
        assert plan_simulation(run, ["static_friction=0.3"], preset="smoke", **how).requests[0].condition.\
            cylinder_diameter_mm == 50.0


def test_simulate_heap_names_the_rig_a_condition_made_not_the_presets(tmp_path):
    from calib_cli.stages.simulate import plan_simulation

    said: list[str] = []
    plan_simulation(tmp_path / "run", ["static_friction=0.3"], preset="smoke", say=said.append,
                    condition=["particle_d_min_mm=4", "particle_d_max_mm=5", "cylinder_diameter_mm=40"])
    assert "4-5 mm grains, a 40 mm cylinder filled 50 mm" in said[0] and "seconds" not in said[0], said[0]


def test_the_documented_ranges_are_the_declared_ones():
    """docs/artefacts.md's table of plausible ranges, row by row, against the declarations."""
    text = (ROOT / "docs" / "artefacts.md").read_text()
    rows = [ln.split("|")[1:-1] for ln in text.splitlines() if ln.startswith("| `") and ln.count("|") == 5]
    seen = 0
    for name_cell, unit, plausible, _ in rows:
        name = name_cell.split("`")[1].replace("heap.", "")
        q = P.QUANTITIES.get(name) or (P.OTHER["repose_angle"] if name in ("target", "--target") else None)
        if q is None:
            continue
        lo, hi = (float(x) for x in plausible.strip().split("-", 1))
        assert (lo, hi) == q.plausible and unit.strip() == (q.unit or "-"), name
        seen += 1
    assert seen >= 9


def test_what_a_command_writes_has_the_usual_file_mode(tmp_path):
    """Atomic writes go through a 0600 temporary file; the file itself gets the umask's usual mode."""
    import os

    import pandas as pd

    from calib_cli import artifacts as art

    mask = os.umask(0o022)
    try:
        art.atomic_write_bytes(tmp_path / "settings.toml", b"target = 30\n")
        art.write_table(tmp_path / "t.parquet", pd.DataFrame({"a": [1]}))
    finally:
        os.umask(mask)
    assert {oct(p.stat().st_mode & 0o777) for p in tmp_path.iterdir()} == {"0o644"}


@pytest.mark.parametrize("code,says", [(13, "read-only or not yours"), (28, "the disk is full")])
def test_a_run_directory_that_cannot_be_written_is_a_one_line_error_and_left_as_it_was(tmp_path, monkeypatch, code,
                                                                                       says):
    """A read-only run directory or a full disk (simulated: root writes through chmod) mid-commit."""
    import hashlib
    import shutil

    from typer.testing import CliRunner

    from calib_cli import artifacts as art
    from calib_cli.cli import app

    run = tmp_path / "run"
    shutil.copytree(ROOT / "sample_runs" / "paper", run)
    (run / art.RUN_LOCK).touch()  # as every command that wrote the run leaves it: empty, unlocked
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.rglob("*") if p.is_file()}

    def full(path, *a, **k):
        raise OSError(code, "No space left on device" if code == 28 else "Permission denied", str(path))

    monkeypatch.setattr(art, "_write_parquet", full)
    r = CliRunner().invoke(app, ["pb", "design", "--run", str(run), "--force"])
    assert r.exit_code == 2 and says in r.output and r.output.count("error:") == 1, r.output
    after = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.rglob("*") if p.is_file()}
    assert after == before


def test_the_report_writes_a_pair_sign_and_says_why_photographs_are_missing(tmp_path):
    import shutil

    from calib_cli.report import build_report

    run = tmp_path / "run"
    shutil.copytree(ROOT / "sample_runs" / "smoke", run)
    shutil.rmtree(run / "measure" / "overlays")
    html = build_report(run)
    assert "&amp;times;" not in html
    assert "overlays (<code>measure/overlays/</code>) are missing" in html and "given as numbers" not in html


def test_a_deleted_settings_file_is_an_error_not_the_defaults(tmp_path):
    from typer.testing import CliRunner

    from calib_cli.cli import app

    run = tmp_path / "run"
    runner = CliRunner()
    assert runner.invoke(app, ["init", "--run", str(run), "-s", "pb.alpha=0.2"]).exit_code == 0
    (run / "settings.toml").unlink()
    r = runner.invoke(app, ["pb", "design", "--run", str(run)])
    assert r.exit_code == 2 and "settings.toml is missing (calib init wrote it)" in r.output, r.output
    assert not (run / "pb").exists()
    assert runner.invoke(app, ["init", "--run", str(run), "-s", "pb.alpha=0.2"]).exit_code == 0
    assert runner.invoke(app, ["pb", "design", "--run", str(run)]).exit_code == 0
