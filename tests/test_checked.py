"""A library call with an argument of the wrong type fails with one line naming it, before the stage runs."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd
import pytest

from calib_cli.errors import CalibError
from calib_cli.stages.calibrate import calibrate
from calib_cli.stages.common import checked
from calib_cli.stages.compare import compare
from calib_cli.stages.load import load
from calib_cli.stages.measure import measure_angle
from calib_cli.stages.simulate import run_simulation, simulate_heap
from calib_cli.stages.suggest import suggest_conditions

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("call, message", [
    (lambda run: calibrate(run, budget="x"), r"calibrate\(budget='x'\): budget takes an integer$"),
    (lambda run: calibrate(run, budget=True), r"budget takes an integer$"),
    (lambda run: calibrate(run, shear_modulus="stiff"), r"shear_modulus takes a number or None$"),
    (lambda run: calibrate(run, shear_modulus=math.nan), r"shear modulus nan Pa .* is outside"),  # the stage's own
    (lambda run: calibrate(run, bogus=1), r"calibrate: got an unexpected keyword argument 'bogus'"),
    (lambda run: compare(run, repeats="2"), r"compare\(repeats='2'\): repeats takes an integer$"),
    (lambda run: compare(run, preset=3), r"preset takes a string or None$"),
    (lambda run: simulate_heap(run, repeats=1.5), r"plan_simulation\(repeats=1.5\): repeats takes an integer$"),
    (lambda run: calibrate(42), r"calibrate\(run=42\): run takes a path"),
    (lambda run: load(123, "posterior"), r"load\(run=123\): run takes a path"),
    (lambda run: suggest_conditions(run, ROOT / "sample_data" / "rig.toml", simulate=[1.5]),
     r"simulate takes a name or a list of names \(strings\)$"),
    (lambda run: measure_angle(run, band="x"), r"measure_angle\(band='x'\): band takes two numbers$"),
    (lambda run: measure_angle(run, band=(0.1, 0.5, 0.9)), r"band takes two numbers$"),
    (lambda run: measure_angle(run, conditions=pd.DataFrame({"a": range(30)})),
     r"^measure_angle\(conditions=<DataFrame>\): conditions takes a path \(str or Path\) or None$"),
    (lambda run: run_simulation(str(run)), r"run_simulation\(plan='.*'\): plan takes a Plan$"),
])
def test_a_wrong_type_is_one_line_and_touches_nothing(tmp_path, call, message):
    run = tmp_path / "run"
    with pytest.raises(CalibError, match=message):
        call(run)
    assert not run.exists()  # refused before the stage made its run directory or took its lock


@pytest.mark.parametrize("call, message", [
    (lambda run: simulate_heap(run, seed=-1), r"^seed -1 is out of range \(0 to 4294967295\)$"),
    (lambda run: compare(run, repeats=0), r"^repeats 0 is out of range \(1 to 1000\)$"),
    (lambda run: compare(run, repeats=10 ** 20), r"repeats 100000000000000000000 is out of range"),
    (lambda run: compare(run, workers=0), r"workers 0 is out of range"),
    (lambda run: calibrate(run, seed=2 ** 32), r"seed 4294967296 is out of range"),
])
def test_a_count_or_seed_out_of_range_is_one_line_and_touches_nothing(tmp_path, call, message):
    run = tmp_path / "run"
    with pytest.raises(CalibError, match=message):
        call(run)
    assert not run.exists()


def test_the_types_a_user_means_pass():
    @checked
    def stage(run: Path, budget: int = 1, scale: float = 1.0, seed: Optional[int] = None, on: bool = False) -> tuple:
        return run, budget, scale, seed, on

    assert stage("a/b", np.int64(3), 2, None, np.bool_(True))[1:] == (3, 2, None, True)
    assert stage(Path("a"), budget=4, scale=np.float32(0.5), seed=np.int32(7))[1:4] == (4, 0.5, 7)
    with pytest.raises(CalibError, match=r"stage\(scale='1'\): scale takes a number$"):
        stage("a", scale="1")
    with pytest.raises(CalibError, match=r"stage\(on=1\): on takes True or False$"):
        stage("a", on=1)

    @checked
    def pairs(band: tuple[float, float] = (0.1, 0.9), names: tuple[str, ...] = ()) -> tuple:
        return band, names

    # a band as numpy gives it, one name or a table's column of them
    assert pairs(np.array([0.15, 0.85]), "H50")[1] == "H50"
    assert list(pairs(names=pd.Series(["H50", "H75"]))[1]) == ["H50", "H75"]
    assert pairs((np.float32(0.2), 1), {"H50"})[0][1] == 1


def test_load_names_a_stage_by_its_name():
    with pytest.raises(CalibError, match=r"load\(stage=3\): stage takes a string$"):
        load(ROOT / "sample_runs" / "smoke", 3)


def test_a_lab_with_an_unknown_hidden_effect_is_refused_before_any_heap(tmp_path):
    from calib_cli.stages.lab import synth_lab

    with pytest.raises(CalibError, match=r"unknown hidden effect 'bogus': none or one of .*cohesion"):
        synth_lab(tmp_path / "lab", hidden="bogus")
    assert not (tmp_path / "lab").exists()


@pytest.mark.parametrize("row, words", [
    ("8,6,40,50", "0 < d_min <= d_max, got 8, 6 mm"),
    ("4,8,5,50", "cylinder diameter 5 mm must be at least 4 particle diameters"),
    ("4,5,40,6", "fill height 6 mm must be at least 2 particle diameters"),
])
def test_a_conditions_file_whose_sizes_disagree_is_one_line(tmp_path, row, words):
    """The sizes of one condition checked against each other, as a simulated heap's are."""
    from calib_cli.conditions import read_conditions_csv

    p = tmp_path / "conditions.csv"
    p.write_text("image,condition_id,particle_d_min_mm,particle_d_max_mm,cylinder_diameter_mm,fill_height_mm\n"
                 f"a.png,A,{row}\n")
    with pytest.raises(CalibError, match=re.escape(words) + r".*condition A on line 2"):
        read_conditions_csv(p)


@pytest.mark.parametrize("rtol", [-1.0, math.inf, math.nan])
def test_a_tolerance_that_compares_nothing_is_one_line(rtol):
    from calib_cli.stages.rundiff import diff_runs

    smoke = ROOT / "sample_runs" / "smoke"
    with pytest.raises(CalibError, match=r"--rtol must be a finite number of at least 0"):
        diff_runs(smoke, smoke, rtol)


def test_an_ascent_target_beyond_any_angle_is_one_line(tmp_path):
    import shutil

    from calib_cli.stages.doe import ascent_analyze

    run = tmp_path / "run"
    shutil.copytree(ROOT / "sample_runs" / "calibration", run)
    with pytest.raises(CalibError, match=r"repose_angle = 1e\+09 deg \(--target\) is outside"):
        ascent_analyze(run, target=1e9, force=True)


@pytest.mark.parametrize("text, words", [
    ('revision = 1.5\neffects = ["sliding_friction"]\n', "revision must be a whole number from 0 to 1000000, got 1.5"),
    ('revision = -3\neffects = ["sliding_friction"]\n', "revision must be a whole number from 0 to 1000000, got -3"),
    ("revision = 1\neffects = []\n", "effects must name each effect once, got []"),
    ('revision = 1\neffects = ["restitution", "restitution"]\n', "effects must name each effect once"),
    ('revision = 99999999999999999999999\neffects = ["sliding_friction"]\n', "from 0 to 1000000, got 99999"),
])
def test_a_model_file_edited_out_of_shape_is_one_line(tmp_path, text, words):
    from calib_cli.model import load_model

    (tmp_path / "model.toml").write_text(text)
    with pytest.raises(CalibError, match=re.escape(words)):
        load_model(tmp_path)


def test_the_models_last_effect_is_not_removed(tmp_path):
    from typer.testing import CliRunner

    from calib_cli.cli import app

    run = tmp_path / "run"
    assert CliRunner().invoke(app, ["init", "--run", str(run)]).exit_code == 0
    (run / "model.toml").write_text('revision = 1\neffects = ["sliding_friction"]\n')
    r = CliRunner().invoke(app, ["model", "remove", "sliding_friction", "--run", str(run)])
    assert r.exit_code == 2 and "the model's only effect" in r.output, r.output
    assert "sliding_friction" in (run / "model.toml").read_text()


def test_an_angles_file_row_without_its_condition_is_one_line(tmp_path):
    from calib_cli.stages.measure import measure_angle
    from calib_cli.stages.run_dir import init_run

    run = tmp_path / "run"
    init_run(run)
    p = tmp_path / "angles.csv"
    p.write_text("image,repose_angle,condition_id\n1,30,\n2,31,A\n")
    with pytest.raises(CalibError, match=r"condition_id is empty on line\(s\) 2: every row needs its condition"):
        measure_angle(run, angles=p)
    assert not (run / "measure").exists()


def test_a_design_over_a_factor_no_heap_takes_is_not_simulated(tmp_path):
    """A settings factor that is no simulated heap's parameter would sit at its default in every heap."""
    from calib_cli.stages.doe import pb_design
    from calib_cli.stages.run_dir import init_run

    run = tmp_path / "run"
    init_run(run, setting=["factors.bogus.low=0", "factors.bogus.high=1", 'pb.factors=["static_friction","bogus"]'])
    pb_design(run)
    with pytest.raises(CalibError, match=r"factor\(s\) bogus are not parameters a simulated heap takes"):
        simulate_heap(run, design=run / "pb" / "design.parquet", preset="smoke")
    assert not (run / "simulate").exists()


def test_an_inversions_condition_without_validation_heaps_is_one_line(tmp_path):
    import shutil

    from calib_cli.stages.invert import invert

    run = tmp_path / "run"
    shutil.copytree(ROOT / "sample_runs" / "smoke", run)
    with pytest.raises(CalibError, match=r"--condition sets the rig of the --validate heaps"):
        invert(run, condition=["fill_height_mm=80"], force=True)


def test_an_angles_files_rig_columns_are_named_as_not_read(tmp_path):
    from calib_cli.stages.measure import measure_angle
    from calib_cli.stages.run_dir import init_run

    run, said = tmp_path / "run", []
    init_run(run)
    p = tmp_path / "angles.csv"
    p.write_text("image,repose_angle,condition_id,cylinder_diameter_mm\n1,30,A,40\n2,31,A,40\n")
    measure_angle(run, angles=p, say=lambda m, err=False: said.append(m))
    assert any("rig column(s) cylinder_diameter_mm, which are not read" in m for m in said), said


def test_a_model_file_edited_against_its_kept_revision_is_refused(tmp_path):
    """model.toml given an effect by hand under revision 1, which RUN/model/ keeps without it: its calibration
    would be filed under revision 1's folders (replacing them); refused, naming both and the way back."""
    from calib_cli.model import load_model

    run = tmp_path / "run"
    shutil.copytree(ROOT / "sample_runs" / "hidden-effect" / "model", run / "model")
    shutil.copy(ROOT / "sample_runs" / "hidden-effect" / "model.toml", run / "model.toml")
    assert load_model(run).revision == 1
    (run / "model.toml").write_text('revision = 1\neffects = ["sliding_friction", "rolling_friction", "restitution", '
                                    '"cohesion", "capillary"]\n')
    with pytest.raises(CalibError, match=r"names revision 1 with effects .*capillary.* keeps that revision with .*"
                                         r"`calib model add`.* or restore it \(cp "):
        load_model(run)
    # the same effects in another order are the same model
    (run / "model.toml").write_text('revision = 1\neffects = ["cohesion", "restitution", "rolling_friction", '
                                    '"sliding_friction"]\n')
    assert load_model(run).revision == 1


def test_a_misspelt_factor_table_and_a_settings_folder_are_refused(tmp_path):
    """[factors.static_fricton] would have been a factor of its own, static friction keeping its default range
    in the prior; a settings.toml that is a folder made every command take the built-in settings."""
    from calib_cli.settings import load_settings
    from calib_cli.stages.common import resolve_settings

    bad = tmp_path / "s.toml"
    bad.write_text("[factors.static_fricton]\nlow = 0.3\nhigh = 0.6\n")
    with pytest.raises(CalibError, match=r"factors.static_fricton names no parameter: did you mean "
                                         r"factors.static_friction\?"):
        load_settings([bad])
    own = tmp_path / "own.toml"
    own.write_text('[factors.moisture]\nlow = 0.0\nhigh = 0.1\nunit = "-"\n'  # like no parameter: a factor
                   '[factors.restitution_pw]\nlow = 0.1\nhigh = 0.5\nunit = "-"\n')  # a parameter's, with a suffix
    assert {"moisture", "restitution_pw"} <= set(load_settings([own])["factors"])
    (tmp_path / "run" / "settings.toml").mkdir(parents=True)
    with pytest.raises(CalibError, match=r"settings.toml is not a file: move it aside"):
        resolve_settings(tmp_path / "run", None, None)
