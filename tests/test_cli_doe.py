"""End-to-end CLI tests of pb / ascent / bbd on the paper's data."""

import json
import shutil

import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.cli import app
from conftest import PAPER, SETTINGS_DIR

runner = CliRunner()


def calib(*args):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


def snapshot(d):
    return {p.relative_to(d): p.read_bytes() for p in d.rglob("*") if p.is_file()}


@pytest.fixture
def run(tmp_path):
    d = tmp_path / "run"
    assert calib("init", "--run", d, "--settings", SETTINGS_DIR / "paper.toml").exit_code == 0
    return d


def test_paper_chain_end_to_end(run):
    assert calib("pb", "design", "--run", run).exit_code == 0
    r = calib("pb", "analyze", "--run", run, "--responses", PAPER / "table3_pb.csv")
    assert r.exit_code == 0, r.output
    assert "Going forward" in r.output
    anova = art.read_table(run / "pb" / "anova.parquet")
    assert list(anova.columns) == ["source", "sum_sq", "df", "mean_sq", "F", "p_value"]
    assert round(anova.set_index("source").loc["rolling_friction", "sum_sq"], 2) == 228.81
    prov = art.read_provenance(run / "pb" / "anova.parquet")
    assert prov["stage"] == "pb.analyze" and prov["inputs"]["responses"]["hash"] and prov["version"]
    assert "pb analyze" in prov["command"] or prov["command"]

    assert calib("ascent", "design", "--run", run).exit_code == 0
    design = art.read_table(run / "ascent" / "design.parquet")
    assert len(design) == 5 and (design["restitution"] == 0.2).all()
    r = calib("ascent", "analyze", "--run", run, "--responses", PAPER / "table5_ascent.csv")
    assert r.exit_code == 0, r.output
    assert "4.26 %" in r.output
    # Table 5's step 5 repeats Table 3's run 6 but for restitution, 13.56 deg apart (docs/physics.md)
    out = " ".join(r.output.split())
    assert "step 5 repeats screening run(s) 6" in out and "+13.56 deg" in out and "step 1 repeats" not in out
    assert calib("bbd", "design", "--run", run).exit_code == 0
    d = art.read_table(run / "bbd" / "design.parquet")
    assert len(d) == 17
    assert sorted(d["static_friction"].round(9).unique()) == [0.112, 0.275, 0.438]  # Table 6 from the bracket
    r = calib("bbd", "analyze", "--run", run, "--responses", PAPER / "table7_bbd.csv")
    assert r.exit_code == 0, r.output
    fit = art.read_table(run / "bbd" / "fit.parquet").iloc[0]
    assert round(fit["r2_pred"], 4) == 0.7948 and round(fit["adeq_precision"], 4) == 21.2234
    coef = art.read_table(run / "bbd" / "coefficients.parquet").set_index("term")["coefficient"]
    assert round(coef["static_friction^2"], 3) == 1.541
    assert len(list((run / "bbd").glob("surface_*.png"))) == 3


def test_rerun_skips_and_force_reruns(run):
    args = ("bbd", "analyze", "--run", run, "--responses", PAPER / "table7_bbd.csv")
    assert calib(*args).exit_code == 0
    before = snapshot(run)
    r = calib(*args)
    assert r.exit_code == 0 and "nothing to do" in r.output
    assert snapshot(run) == before
    r = calib(*args, "--force")
    assert r.exit_code == 0 and "ANOVA" in r.output
    # a changed setting invalidates the stage
    r = calib(*args, "-s", "response=repose_angle", "-s", "bbd.alpha=0.01")
    assert "nothing to do" in r.output  # alpha only affects the printed warning, not the artefacts
    r = calib("pb", "analyze", "--run", run, "--responses", PAPER / "table3_pb.csv")
    r2 = calib("pb", "analyze", "--run", run, "--responses", PAPER / "table3_pb.csv", "-s", "pb.alpha=0.01")
    assert "nothing to do" not in r2.output and "Going forward" in r2.output


@pytest.mark.parametrize("make_bad,needle", [
    (lambda p: p.write_text(p.read_text().replace("repose_angle", "angle")), "lacks column"),
    (lambda p: p.write_text(p.read_text().replace("38.44", "nan")), "missing or non-numeric"),
    (lambda p: p.write_text(p.read_text().replace("0.112,", "0.275,")), None),
    (lambda p: p.write_bytes(b"\x89PNG\x00\x00garbage\xff\xfe"), None),
    (lambda p: p.unlink(), "not found"),
    # heaps that all stand at one angle (an insensitive model): nothing to fit, not a ZeroDivisionError
    (lambda p: pd.read_csv(p).assign(repose_angle=30.0).to_csv(p, index=False), "all 17 responses equal 30"),
])
def test_bad_responses_one_line_error_and_run_dir_unchanged(run, tmp_path, make_bad, needle):
    good = tmp_path / "t7.csv"
    shutil.copy(PAPER / "table7_bbd.csv", good)
    assert calib("bbd", "analyze", "--run", run, "--responses", good).exit_code == 0
    bad = tmp_path / "bad.csv"
    shutil.copy(good, bad)
    make_bad(bad)
    before = snapshot(run)
    r = calib("bbd", "analyze", "--run", run, "--responses", bad)
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), r.output
    if needle:
        assert needle in lines[0]
    assert snapshot(run) == before


def test_a_responses_table_is_checked_against_the_runs_design(run, tmp_path):
    """Rows pasted twice are refused (they would be counted as runs: a kinder predicted R2); rows
    missing from the run's design, or at none of its runs, are analysed as given but said."""
    assert calib("bbd", "design", "--run", run, "-s", "bbd.ranges.static_friction=[0.112,0.438]",
                 "-s", "bbd.ranges.rolling_friction=[0.122,0.308]", "-s",
                 "bbd.ranges.surface_energy=[0.875,1.625]").exit_code == 0
    table = pd.read_csv(PAPER / "table7_bbd.csv")
    doubled = tmp_path / "doubled.csv"
    pd.concat([table, table]).to_csv(doubled, index=False)
    before = snapshot(run)
    r = calib("bbd", "analyze", "--run", run, "--responses", doubled)
    assert r.exit_code == 2 and "row 18 repeats row 1 in every column, and every other row repeats one" in " ".join(r.output.split()), r.output
    assert snapshot(run) == before
    r = calib("bbd", "analyze", "--run", run, "--responses", PAPER / "table7_bbd.csv")
    assert r.exit_code == 0 and "warning: responses file" not in r.output, r.output  # Table 7 is the design
    short = tmp_path / "short.csv"
    table.drop(index=[1]).to_csv(short, index=False)  # the row of design run 1
    out = " ".join(calib("bbd", "analyze", "--run", run, "--responses", short).output.split())
    assert "1 design run(s) have no row (1)" in out and "no run of" not in out, out
    off = tmp_path / "off.csv"
    table.assign(static_friction=table["static_friction"].replace(0.438, 0.45)).to_csv(off, index=False)
    out = " ".join(calib("bbd", "analyze", "--run", run, "--responses", off).output.split())
    assert "4 of its 17 rows are at no run of" in out and "(row 1: static_friction 0.45," in out, out
    assert "4 design run(s) have no row (3, 4, 7, 8)" in out
    whole = tmp_path / "whole.csv"  # a paper printing whole degrees: three centre points at 34, runs all the same
    table.assign(repose_angle=table["repose_angle"].round()).to_csv(whole, index=False)
    r = calib("bbd", "analyze", "--run", run, "--responses", whole)
    out = " ".join(r.output.split())
    assert r.exit_code == 0 and "warning: responses file" in out and "row 13 repeats row 12 in every column" in out


def test_a_paper_table_of_its_own_design_is_said_to_be(run):
    assert calib("pb", "design", "--run", run).exit_code == 0
    r = calib("pb", "analyze", "--run", run, "--responses", PAPER / "table3_pb.csv")
    out = " ".join(r.output.split())
    assert r.exit_code == 0 and "3 of its 12 rows are at no run of" in out and "the table's own points" in out
    assert "1 row(s) are at a run's point that other rows already give (row 8)" in out
    again = calib("pb", "analyze", "--run", run, "--responses", PAPER / "table3_pb.csv")
    assert "nothing to do" in again.output and "warning" not in again.output  # said once, when analysed


def test_an_ascent_step_given_twice_is_an_error(run, tmp_path):
    path = pd.read_csv(PAPER / "table5_ascent.csv")
    bad = tmp_path / "steps.csv"
    path.assign(step=[1, 2, 3, 3, 5]).to_csv(bad, index=False)
    r = calib("ascent", "analyze", "--run", run, "--responses", bad)
    assert r.exit_code == 2 and "step 3 is given twice" in r.output, r.output


def test_single_level_factor_is_an_error(tmp_path):
    bad = tmp_path / "one.csv"
    df = pd.read_csv(PAPER / "table3_pb.csv")
    df["restitution"] = 0.2
    df.to_csv(bad, index=False)
    r = calib("pb", "analyze", "--run", tmp_path / "r", "--responses", bad)
    assert r.exit_code == 2 and "single level" in r.output


def test_analyze_without_responses_or_simulations_says_what_to_do(run):
    assert calib("pb", "design", "--run", run).exit_code == 0
    r = calib("pb", "analyze", "--run", run)
    assert r.exit_code == 2
    assert "simulate-heap" in r.output and "--responses" in r.output


def test_simulated_responses_are_matched_to_the_design(run):
    assert calib("pb", "design", "--run", run).exit_code == 0
    design = art.read_table(run / "pb" / "design.parquet")
    # two repeats per design point, as simulate-heap writes them
    rows = []
    for seed in (1, 2):
        res = design.copy()
        res["seed"] = seed
        res["design"] = "pb"
        res["repose_angle"] = 30 + 5 * design["rolling_friction"] / 0.4 + seed * 0.1
        rows.append(res)
    art.write_table(run / "simulate" / "results.parquet", pd.concat(rows))
    r = calib("pb", "analyze", "--run", run)
    assert r.exit_code == 0, r.output
    data = art.read_table(run / "pb" / "data.parquet")
    assert (data["n_repeats"] == 2).all()  # matched by run id: identical design points stay separate runs
    # without run ids (responses from elsewhere) results are matched by factor values
    res = pd.concat(rows).drop(columns=["design", "run_id"])
    art.write_table(run / "simulate" / "results.parquet", res)
    assert calib("pb", "analyze", "--run", run).exit_code == 0
    data = art.read_table(run / "pb" / "data.parquet")
    assert set(data["n_repeats"]) == {2, 4}  # pyDOE3's 12-run design repeats a 4-factor point, as Table 3 does


def test_an_analysis_locks_the_rows_it_read_not_the_growing_index(run):
    """Later stages append their heaps to RUN/simulate/results.parquet; the screening read none of
    them and stays up to date, so a whole chain rerun skips it. A changed row of its own re-runs it."""
    assert calib("pb", "design", "--run", run).exit_code == 0
    res = art.read_table(run / "pb" / "design.parquet").assign(seed=1, design="pb")
    res["repose_angle"] = 30 + 5 * res["rolling_friction"] / 0.4
    index = run / "simulate" / "results.parquet"
    art.write_table(index, res)
    assert calib("pb", "analyze", "--run", run).exit_code == 0
    before = snapshot(run / "pb")
    later = res.assign(design="ascent", repose_angle=res["repose_angle"] + 3)
    art.write_table(index, pd.concat([res, later]))
    r = calib("pb", "analyze", "--run", run)
    assert r.exit_code == 0 and "nothing to do" in r.output
    assert snapshot(run / "pb") == before
    lock = json.loads((run / "pb" / "analyze.lock.json").read_text())
    assert set(lock["inputs"]) == {"design", "results"}
    prov = art.read_provenance(run / "pb" / "effects.parquet")
    assert prov["inputs"]["results"]["path"].endswith("results.parquet (12 rows read)")
    res.loc[0, "repose_angle"] += 1.0
    art.write_table(index, pd.concat([res, later]))
    r = calib("pb", "analyze", "--run", run)
    assert r.exit_code == 0 and "nothing to do" not in r.output


def test_frame_hash_follows_values_names_and_types_not_the_index():
    df = pd.DataFrame({"a": [1.0, 2.0], "b": ["x", "y"]})
    h = art.frame_hash(df)
    assert art.frame_hash(df.set_axis([5, 6])) == h
    assert art.frame_hash(df.assign(a=[1.0, 2.5])) != h
    assert art.frame_hash(df.rename(columns={"a": "c"})) != h
    assert art.frame_hash(df.astype({"a": "float32"})) != h
    assert art.frame_hash(df.iloc[::-1]) != h


def test_ascent_design_needs_screening(run):
    r = calib("ascent", "design", "--run", run)
    assert r.exit_code == 2 and "calib pb analyze" in r.output


def test_help_says_what_is_read_and_written():
    r = calib("bbd", "analyze", "--help")
    assert "Reads" in r.output and "Writes" in r.output
    assert calib("--version").exit_code == 0


def test_bad_setting_on_command_line(run):
    r = calib("pb", "design", "--run", run, "-s", "pb.runs=10")
    assert r.exit_code == 2 and "no Plackett-Burman design has 10 runs" in r.output
    # 28 is a multiple of 4 that pyDOE3 has no design of (it asserted: an internal error)
    r = calib("pb", "design", "--run", run, "-s", "pb.runs=28", "--force")
    assert r.exit_code == 2 and "no Plackett-Burman design has 28 runs" in r.output and "choose one of 8, 12" in r.output


def test_pb_sizes_are_the_ones_pydoe3_builds():
    import pyDOE3

    from calib_cli.doe.sizes import sizes

    assert sizes(100) == [4, 8, 12, 16, 20, 24, 32, 40, 48, 64, 80, 96]
    assert all(pyDOE3.pbdesign(n - 1).shape[0] == n for n in sizes(100))


def test_a_fixed_value_or_a_design_range_is_checked_like_a_factor(run):
    for bad in ("bbd.fixed.restitution=nan", "ascent.fixed.restitution=-5", "bbd.ranges.static_friction=[-1, 0.2]",
                "bbd.ranges.static_friction=[0.4, 0.2]"):
        r = calib("bbd", "design", "--run", run, "-s", bad, "--force")
        assert r.exit_code == 2 and "setting " in r.output and "internal error" not in r.output, (bad, r.output)


def test_console_entry_point_exit_codes(tmp_path):
    """The real entry point (not CliRunner): usage errors and user errors exit 2 without a traceback."""
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, "-m", "calib_cli", *map(str, args)], capture_output=True, text=True)

    r = run("pb", "analyze", "--bogus")
    assert r.returncode == 2 and "No such option" in r.stderr and "Traceback" not in r.stderr
    r = run("pb", "analyze", "--run", tmp_path / "r", "--responses", tmp_path / "missing.csv")
    assert r.returncode == 2 and r.stderr.strip().startswith("error: responses file not found")
    assert "Traceback" not in r.stderr
    assert run("--version").returncode == 0
    # a value outside an option's range is one line naming the command's help, not click's box of five
    for args, word in [(("compare", "--run", tmp_path / "r", "--repeats", "0"), "--repeats"),
                       (("model", "add"), "effect"), (("nosuch",), "nosuch"),
                       # a script's unset variable (--run "$RUN"): not the current directory
                       (("init", "--run", ""), "is empty"), (("run", "stages/paper.toml", "--run", " "), "is empty")]:
        r = run(*args)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:") and word in lines[0], r.stderr
        assert "--help)" in lines[0]
    # the hint names the command, however the program was started (here python -m calib_cli)
    for args, hint in [(("diagnose", "--alpha", "2"), "(calib diagnose --help)"),
                       (("measure-angle", "--band", "0.5"), "(calib measure-angle --help)"),
                       (("model", "add", "--bogus"), "(calib model add --help)")]:
        assert hint in run(*args).stderr, args
    assert run().returncode == 2 and "Usage" in run().stdout + run().stderr  # no command: the help


def test_error_messages_keep_their_brackets(tmp_path):
    r = calib("pb", "design", "--run", tmp_path / "r", "-s", "bbd.ranges.static_friction=[0.5]")
    assert r.exit_code == 2 and "bbd.ranges.static_friction = [0.5] must be a list [low, high]" in r.output


def test_ascent_aims_at_the_measured_angle(tmp_path):
    """Without ascent.target the path is judged against the measured angle (the photographs'
    mean), not the settings' placeholder target."""
    run, toml = tmp_path / "run", tmp_path / "no_ascent_target.toml"
    toml.write_text((SETTINGS_DIR / "paper.toml").read_text().replace("target = 32.84", ""))
    assert calib("init", "--run", run, "--settings", toml).exit_code == 0
    assert calib("pb", "design", "--run", run).exit_code == 0
    assert calib("pb", "analyze", "--run", run, "--responses", PAPER / "table3_pb.csv").exit_code == 0
    (run / "measure").mkdir()
    art.write_table(run / "measure" / "conditions.parquet",
                    pd.DataFrame({"condition_id": ["A"], "mean": [36.0], "sd": [1.0], "n": [5]}))
    r = calib("ascent", "analyze", "--run", run, "--responses", PAPER / "table5_ascent.csv")
    assert r.exit_code == 0, r.output
    assert "vs target 36 deg" in r.output
    assert art.read_provenance(run / "ascent" / "path.parquet")["inputs"]["conditions"]["hash"]
    # settings ascent.target wins over the measurement, and --target over both
    r = calib("ascent", "analyze", "--run", run, "--responses", PAPER / "table5_ascent.csv", "-s", "ascent.target=33")
    assert "vs target 33 deg" in r.output
    r = calib("ascent", "analyze", "--run", run, "--responses", PAPER / "table5_ascent.csv", "--target", "30")
    assert "vs target 30 deg" in r.output


def test_init_writes_settings_overrides_and_keeps_an_existing_file(tmp_path):
    """init -s writes KEY=VALUE in front of the copied settings (its comments kept), reruns
    without change, sets a key the file sets already, and never replaces a different settings file
    without --force; bad input leaves nothing behind."""
    from calib_cli.settings import load_settings

    run = tmp_path / "run"
    r = calib("init", "--run", run, "--settings", SETTINGS_DIR / "paper.toml", "-s", "heap.shear_modulus=1.5e8",
              "-s", "heap.preset=smoke")
    assert r.exit_code == 0, r.output
    target = run / "settings.toml"
    text = target.read_text()
    assert text.endswith((SETTINGS_DIR / "paper.toml").read_text())
    s = load_settings([target])
    assert s["heap"] == {"preset": "smoke", "shear_modulus": 1.5e8, "engine": "builtin", "precision": "double"}
    assert s["ascent"]["method"] == "diagonal"  # the copied file's own settings still hold
    r = calib("init", "--run", run, "--settings", SETTINGS_DIR / "paper.toml", "-s", "heap.shear_modulus=1.5e8",
              "-s", "heap.preset=smoke")
    assert r.exit_code == 0 and "initialised" in r.output and target.read_text() == text
    r = calib("init", "--run", run, "-s", "heap.shear_modulus=1.5e8")
    assert r.exit_code == 0 and "already" in r.output and target.read_text() == text
    for args, needle in [(["--settings", SETTINGS_DIR / "smoke.toml"], "--force"),
                         (["-s", "heap.shear_modulus=stiff"], "heap.shear_modulus = 'stiff' must be a number"),
                         (["-s", "heap.presets=smoke"], "unknown setting")]:
        r = calib("init", "--run", run, *args)
        assert r.exit_code == 2 and needle in " ".join(r.output.split()), (args, r.output)
        assert target.read_text() == text
    # -s of a key the file sets already: set in it (the file written out whole, as given kept below as comments)
    r = calib("init", "--run", run, "-s", "heap.shear_modulus=5e8")
    assert r.exit_code == 0 and load_settings([target])["heap"]["shear_modulus"] == 5e8, r.output
    assert load_settings([target])["ascent"] == s["ascent"] and "# the settings file as given:" in target.read_text()
    r = calib("init", "--run", run, "--settings", SETTINGS_DIR / "smoke.toml", "--force")
    assert r.exit_code == 0 and target.read_text() == (SETTINGS_DIR / "smoke.toml").read_text()
    # -s alone on a fresh run: the defaults with the override; a missing --settings file is one line
    r = calib("init", "--run", tmp_path / "fresh", "-s", "heap.shear_modulus=5e7")
    assert r.exit_code == 0 and load_settings([tmp_path / "fresh" / "settings.toml"])["heap"]["shear_modulus"] == 5e7
    r = calib("init", "--run", tmp_path / "none", "--settings", tmp_path / "nope.toml")
    assert r.exit_code == 2 and "not found" in r.output and not (tmp_path / "none").exists()


def test_the_designs_warnings_are_the_results_own():
    """What `ascent analyze` and `bbd analyze` warn of comes from their results (docs/library.md), so a
    notebook gets the same lines: the best step at the path's end; a lack of fit, R2 adjusted and predicted apart."""
    from types import SimpleNamespace

    from calib_cli.stages.doe import AscentResult, BBDResult

    assert "end of the path" in AscentResult(None, analysis=SimpleNamespace(at_edge=True)).warnings()[0]
    assert AscentResult(None, analysis=SimpleNamespace(at_edge=False)).warnings() == []
    bad = SimpleNamespace(stats_={"lack_of_fit_p": 0.01, "r2_adj": 0.9, "r2_pred": 0.5})
    w = BBDResult(None, rsm=bad, alpha=0.05).warnings()
    assert len(w) == 2 and "lack of fit" in w[0] and "0.2" in w[1]
    assert BBDResult(None, rsm=bad, alpha=0.005).warnings() == [w[1]]


def test_a_command_that_makes_a_new_run_directory_says_so(tmp_path):
    """A mistyped --run made a whole new run on the built-in settings without a word: the command that
    makes it says so once it has run; init (which is for that), a rerun and a failure do not."""
    r = CliRunner().invoke(app, ["pb", "design", "--run", str(tmp_path / "papr")], env={"COLUMNS": "200"})
    said = " ".join(r.output.split())
    assert r.exit_code == 0 and said.startswith(f"note: {tmp_path / 'papr'} was a new run directory, on the built-in "
                                              f"settings (`calib init --run {tmp_path / 'papr'} --settings FILE` gives "
                                              "it yours)"), r.output
    r = CliRunner().invoke(app, ["pb", "design", "--run", str(tmp_path / "papr")])
    assert r.exit_code == 0 and "new run directory" not in r.output
    r = CliRunner().invoke(app, ["init", "--run", str(tmp_path / "i")])
    assert r.exit_code == 0 and "new run directory" not in r.output
    r = CliRunner().invoke(app, ["compare", "--run", str(tmp_path / "x")])
    assert r.exit_code == 2 and "new run directory" not in r.output and not (tmp_path / "x").exists()
