"""suggest-conditions' pure functions against closed forms (calib_cli.posterior.suggest)."""

import math

import numpy as np
import pandas as pd
import pytest

from calib_cli.errors import CalibError
from calib_cli.discrepancy.stats import confound
from calib_cli.posterior.suggest import extrapolate, parameter_gain, parse_rig, separation

VARS = ["particle_d_min_mm", "cylinder_diameter_mm", "fill_height_mm"]


def test_the_preposterior_of_a_linear_gaussian_model_is_the_kalman_update():
    """theta ~ N(0, s2), y = j theta + N(0, u2): the posterior sd after y is known in closed form;
    the reweighted draws' interval and the information gain match it."""
    s2, j, u2 = 0.04, 30.0, 2.0
    draws = np.random.default_rng(1).normal(0, math.sqrt(s2), (20000, 1))
    gain, shrink = parameter_gain(j * draws[:, 0], draws, u2, outcomes=200)
    post = 1.0 / (1.0 / s2 + j * j / u2)
    assert gain == pytest.approx(0.5 * math.log(1 + j * j * s2 / u2), rel=0.05)
    assert shrink[0] == pytest.approx(1 - math.sqrt(post / s2), abs=0.04)


def test_a_condition_that_tells_two_modes_apart_gains_and_one_that_cannot_does_not():
    """A posterior with two modes (theta near 0.2 or near 0.8): a condition whose angle differs
    between them halves the interval; one where both predict the same angle teaches nothing."""
    rng = np.random.default_rng(2)
    draws = np.concatenate([rng.normal(0.2, 0.02, 2000), rng.normal(0.8, 0.02, 2000)])[:, None]
    tells, shrink = parameter_gain(40.0 * draws[:, 0], draws, 1.0)
    blind, none = parameter_gain(np.full(len(draws), 30.0), draws, 1.0)
    assert tells > 1.0 and shrink[0] > 0.8
    assert blind == pytest.approx(0.0) and none[0] == pytest.approx(0.0, abs=0.02)


def test_two_responses_gain_as_the_linear_gaussian_model_of_both_and_a_blind_one_adds_nothing():
    """y = J theta + N(0, U) with two responses (an angle and a profile's fullness, correlated within a
    pile): the gain is 1/2 log det(I + U^-1 J s2 J') and the interval shrinks to the Kalman update's;
    a second response that sees nothing leaves the first's gain as it was."""
    s2, J = 0.04, np.array([30.0, 3.0])
    U = np.array([[2.0, 0.3 * math.sqrt(2.0 * 0.01)], [0.3 * math.sqrt(2.0 * 0.01), 0.01]])
    draws = np.random.default_rng(1).normal(0, math.sqrt(s2), (20000, 1))
    gain, shrink = parameter_gain(draws * J, draws, U, outcomes=200)
    post = 1.0 / (1.0 / s2 + J @ np.linalg.solve(U, J))
    assert gain == pytest.approx(0.5 * np.linalg.slogdet(np.eye(2) + np.linalg.solve(U, np.outer(J, J)) * s2)[1],
                                 rel=0.05)
    assert shrink[0] == pytest.approx(1 - math.sqrt(post / s2), abs=0.04)
    angle, _ = parameter_gain(30.0 * draws[:, 0], draws, 2.0)
    blind, _ = parameter_gain(np.column_stack([30.0 * draws[:, 0], np.full(len(draws), 1.1)]), draws,
                              np.diag([2.0, 0.01]))
    assert blind == pytest.approx(angle, rel=1e-9) and gain > angle + 0.3


def test_unknown_sensitivities_give_no_gain_rather_than_a_guess():
    gain, shrink = parameter_gain(np.array([np.nan, 1.0]), np.zeros((2, 2)), 1.0)
    assert np.isnan(gain) and np.isnan(shrink).all()


def test_separation_without_parameters_is_the_signature_in_noise_units():
    g, u = np.array([1.0, 2.0, 3.0]), np.array([0.5, 1.0, 2.0])
    assert separation(np.zeros((3, 0)), g, u, 0.5) == pytest.approx(0.25 * (4 + 4 + 9 / 4))


def test_an_effect_a_parameter_can_absorb_has_no_separation():
    J = np.array([[1.0], [2.0], [3.0]])
    assert separation(J, 4.0 * J[:, 0], np.ones(3), 1.0) == pytest.approx(0.0, abs=1e-20)
    assert separation(J, np.array([1.0, -1.0, 0.0]), np.ones(3), 1.0) > 1.0  # not in J's span
    assert confound(J, 4.0 * J[:, 0], np.ones(3), ["mu"]) == ("mu", pytest.approx(1.0))


def test_extrapolation_is_exact_for_a_linear_sensitivity_and_flags_what_it_cannot_know():
    measured = pd.DataFrame({"particle_d_min_mm": [4, 4, 5, 5], "cylinder_diameter_mm": [40] * 4,
                             "fill_height_mm": [50, 100, 50, 100]})
    sens = pd.DataFrame({"g": 3 - 0.5 * measured["particle_d_min_mm"] + 0.02 * measured["fill_height_mm"]})
    cand = pd.DataFrame({"particle_d_min_mm": [4.5, 3.0, 4.0], "cylinder_diameter_mm": [40, 40, 60],
                         "fill_height_mm": [75, 150, 75]})
    val, known, extrapolated = extrapolate(measured, sens, cand, VARS)
    assert val["g"].tolist() == pytest.approx([3 - 2.25 + 1.5, 3 - 1.5 + 3.0, 3 - 2 + 1.5])
    assert known.tolist() == [True, True, False]  # the cylinder never varied
    assert extrapolated.tolist() == [False, True, False]


def test_a_rig_lists_every_combination_in_the_labs_naming():
    rig = parse_rig({"rig": {"particle_sizes_mm": [[4, 5], [2, 3]], "cylinder_diameter_mm": [40, 60],
                             "fill_height_mm": [100], "piles": 8}})
    c = rig.conditions()
    assert len(c) == 4 and rig.piles == 8
    assert "d4-5_D40_H100" in c["condition_id"].tolist() and "d2-3_D60_H100" in c["condition_id"].tolist()


def test_two_conditions_one_name_would_give_are_refused():
    rig = parse_rig({"rig": {"particle_sizes_mm": [[4, 5]], "fill_height_mm": [100, 100.0001]}})
    with pytest.raises(CalibError, match="d4-5_H100 are two that its name rounds alike"):
        rig.conditions()


def _measured(**kw):
    """Two measured conditions as a conditions table of whole numbers gives them (integers)."""
    return pd.DataFrame({"condition_id": ["d4-5_D40_H50", "d4-5_D40_H100"], "particle_d_min_mm": [4, 4],
                         "particle_d_max_mm": [5, 5], "cylinder_diameter_mm": [40, 40], "fill_height_mm": [50, 100],
                         "lift_speed_mm_s": [50, 50], **kw})


def test_a_measured_condition_is_left_out_whether_its_table_holds_integers_or_floats():
    from calib_cli.stages.suggest import _candidates

    rig = parse_rig({"rig": {"particle_sizes_mm": [[4, 5]], "cylinder_diameter_mm": [40],
                             "fill_height_mm": [50, 75, 100], "lift_speed_mm_s": [50]}})
    for measured in (_measured(), _measured().astype({"fill_height_mm": float, "cylinder_diameter_mm": float})):
        assert _candidates(rig, measured)["condition_id"].tolist() == ["d4-5_D40_H75"]
    # the rig holds the lift speed at 30, which its names leave out: d4-5_D40_H50 there is not the measured one
    slow = parse_rig({"rig": {"particle_sizes_mm": [[4, 5]], "cylinder_diameter_mm": [40], "fill_height_mm": [50],
                              "lift_speed_mm_s": [30]}})
    with pytest.raises(CalibError, match="measured condition has that name with other values"):
        _candidates(slow, _measured())


def test_a_condition_variable_the_heaps_vary_and_a_rig_cannot_set_comes_from_the_measured_conditions():
    from calib_cli.stages.suggest import _complete

    cand = pd.DataFrame({"condition_id": ["x"], "fill_height_mm": [75.0]})
    done = _complete(cand, _measured(floor_static_friction=[0.4, 0.4]), ["fill_height_mm", "floor_static_friction"])
    assert done["floor_static_friction"].tolist() == [0.4]
    with pytest.raises(CalibError, match="vary floor_static_friction, which a rig file does not set, and the "
                                         "measured conditions differ in it"):
        _complete(cand, _measured(floor_static_friction=[0.4, 0.6]), ["floor_static_friction"])
    with pytest.raises(CalibError, match="do not give it"):
        _complete(cand, _measured(), ["floor_static_friction"])


def test_a_rig_of_more_candidates_than_one_covariance_holds_gets_no_spread(monkeypatch):
    from calib_cli.stages import suggest as st

    monkeypatch.setattr(st, "SPREAD_POINTS", 40)  # 5 candidates x 8 draws < SPREAD_FEWEST draws each
    draws = pd.DataFrame({"a": np.linspace(0, 1, 50)})
    F = st._realisations([None], draws, pd.DataFrame({"condition_id": list("abcde")}), np.ones(5, bool))
    assert F.shape[1] == 5 and np.isnan(F).all()


@pytest.mark.parametrize("bad, words", [
    ({"particle_sizes_mm": [[5, 4]]}, "d_min <= d_max"),
    ({"particle_sizes_mm": [4, 5]}, "pair [d_min, d_max]"),
    ({"particle_sizes_mm": [[4, 5]], "fill_height_mm": []}, "at least one value"),
    ({"particle_sizes_mm": [[4, 5]], "fill_height_mm": ["tall"]}, "fill_height_mm must be a number"),
    ({"particle_sizes_mm": [[4, 5]], "fill_height_mm": [0.05, 0.075]}, "are these metres"),  # each value checked
    ({"particle_sizes_mm": [[0.004, 0.005]]}, "are these metres"),
    ({"particle_sizes_mm": [[4, 5]], "floor": ["steel"]}, "unknown key(s) floor"),
    ({"particle_sizes_mm": [[4, 5]], "piles": 0}, "piles must be a whole number from 1 to 10000"),
    ({"particle_sizes_mm": [[4, 5]], "piles": 2.7}, "piles must be a whole number"),  # not cut to 2
    ({"particle_sizes_mm": [[4, 5]], "fill_height_mm": [50, 50]}, "fill_height_mm lists a value twice"),
    ({"particle_sizes_mm": [[4, 5], [4, 5]]}, "particle_sizes_mm lists a pair twice"),
])
def test_a_bad_rig_file_is_a_one_line_error(bad, words):
    with pytest.raises(CalibError) as e:
        parse_rig({"rig": bad})
    assert words in str(e.value) and "\n" not in str(e.value)


def test_a_rig_that_is_not_a_table_is_a_one_line_error():
    with pytest.raises(CalibError, match=r"'rig' must be a table .*got 5$"):
        parse_rig({"rig": 5})


# ------------------------------------------------------------------ the stage and the command
def _run_with_posterior(tmp_path_factory):
    """test_posterior's tiny run (fills 50 and 100 mm measured), its posterior, and diagnose's
    sensitivities there: cohesion's signature falls with the fill, rolling friction's does not."""
    from test_posterior import QUIET, _tiny_run

    from calib_cli import artifacts as art
    from calib_cli.stages.posterior import posterior

    run = _tiny_run(tmp_path_factory.mktemp("suggest") / "run")
    posterior(run, walkers=8, steps=60, **QUIET)
    sens = pd.DataFrame({"condition_id": ["H50", "H100"], "d_static_friction": [20.0, 20.0],
                         "d_rolling_friction": [32.5, 35.0], "d_restitution": [-2.0, -2.0],
                         "candidate_cohesion": [12.0, 3.0]})
    art.write_table(run / "diagnose" / "sensitivities.parquet", sens)
    return run


@pytest.fixture(scope="module")
def ranked(tmp_path_factory):
    from calib_cli.stages.suggest import suggest_conditions

    run = _run_with_posterior(tmp_path_factory)
    rig = run.parent / "rig.toml"
    rig.write_text("[rig]\nparticle_sizes_mm = [[4, 5]]\ncylinder_diameter_mm = [40, 60]\n"
                   "fill_height_mm = [50, 75, 100]\nlift_speed_mm_s = [50]\npiles = 4\n")
    return run, rig, suggest_conditions(run, rig, top=2, say=lambda *a, **k: None)


def test_the_ranking_leaves_out_what_is_measured_and_what_no_heap_knows(ranked):
    run, rig, r = ranked
    t = r.table.set_index("condition_id")
    assert "d4-5_D40_H50" not in t.index and "d4-5_D40_H100" not in t.index  # measured already
    assert t.loc["d4-5_D40_H75", "info_gain_nats"] > 0 and t.loc["d4-5_D40_H75", "known"]
    assert t.loc["d4-5_D60_H75", ["info_gain_nats", "separation_cohesion"]].isna().all()  # no 60 mm heap
    assert "simulate heaps there first" in t.loc["d4-5_D60_H75", "reason"]
    assert r.table["condition_id"].iloc[0] == "d4-5_D40_H75"


def test_its_conditions_file_is_what_measure_angle_reads(ranked, tmp_path):
    run, rig, r = ranked
    c = pd.read_csv(run / "suggest" / "conditions.csv")
    assert list(c.columns[:2]) == ["image", "condition_id"] and len(c) == 2 * 4  # top 2, 4 piles each
    assert c["image"].iloc[0] == "d4-5_D40_H75_r1.png"
    lock = (run / "suggest" / "rank.lock.json")
    assert lock.is_file()


def test_the_command_prints_the_ranking_and_refuses_bad_input(ranked, tmp_path):
    import shutil

    from typer.testing import CliRunner

    from calib_cli import artifacts as art
    from calib_cli.cli import app

    run, rig, _ = ranked
    mine = tmp_path / "run"
    shutil.copytree(run, mine)
    r = CliRunner().invoke(app, ["suggest-conditions", "--run", str(mine), "--rig", str(rig), "--force"],
                           env={"COLUMNS": "160"})
    assert r.exit_code == 0, r.output
    assert "d4-5_D40_H75" in r.output and "conditions.csv" in r.output
    bad = tmp_path / "bad.toml"
    bad.write_text("[rig]\nparticle_sizes_mm = [[4, 5]]\nfill_height_mm = [50, 100]\ncylinder_diameter_mm = [40]\n"
                   "lift_speed_mm_s = [50]\n")
    r = CliRunner().invoke(app, ["suggest-conditions", "--run", str(mine), "--rig", str(bad)])
    assert r.exit_code == 2 and "measured already" in r.output
    for opt in (["--set", "static_friction=abc"], ["--preset", "bogus"]):  # options of heaps it would not make
        r = CliRunner().invoke(app, ["suggest-conditions", "--run", str(mine), "--rig", str(rig), "--force", *opt])
        assert r.exit_code == 2 and "choose the heaps --simulate makes" in " ".join(r.output.split()), r.output
    r = CliRunner().invoke(app, ["suggest-conditions", "--run", str(mine), "--rig", str(rig), "--simulate",
                                 "d4-5_D40_H75", "--repeats", "1"])
    assert r.exit_code == 2 and "--repeats must be at least 2 with --simulate" in " ".join(r.output.split())
    conds = mine / "measure" / "conditions.parquet"
    kept = art.read_table(conds)
    for sd in (0.0, np.nan):  # piles of one angle, or one pile a condition: a gain has no unit
        art.write_table(conds, kept.assign(sd=sd, n=1 if np.isnan(sd) else kept["n"]))
        r = CliRunner().invoke(app, ["suggest-conditions", "--run", str(mine), "--rig", str(rig), "--force"])
        assert r.exit_code == 2 and "scatter is unknown or zero" in " ".join(r.output.split()), r.output
    art.write_table(conds, kept)
    shutil.rmtree(mine / "posterior")
    r = CliRunner().invoke(app, ["suggest-conditions", "--run", str(mine), "--rig", str(rig)])
    assert r.exit_code == 2 and "calibrate-posterior" in r.output


def test_simulate_takes_ids_comma_separated_or_repeated(monkeypatch, tmp_path):
    """`--simulate A,B` and `--simulate A --simulate B` name the same two candidates (a repeated option once
    kept only its last value, silently)."""
    from typer.testing import CliRunner

    from calib_cli.cli import app
    from calib_cli.stages import suggest as st

    asked = []
    monkeypatch.setattr(st, "suggest_conditions", lambda *a, simulate=(), **k: asked.append(simulate) or 1 / 0)
    for opt in (["--simulate", "A,B"], ["--simulate", "A", "--simulate", " B"]):
        CliRunner().invoke(app, ["suggest-conditions", "--run", str(tmp_path), "--rig", "r.toml", *opt])
    assert asked == [["A", "B"], ["A", "B"]]


def test_after_a_posterior_that_weighed_the_profile_the_ranking_counts_it_too(tmp_path):
    """The profile's fullness sees rolling friction here: a new condition's expected information counts
    its profile as the posterior did (the angle's alone in its own column), and the lock reads it."""
    import json

    from test_posterior import QUIET, _tiny_run, _with_profiles

    from calib_cli import artifacts as art
    from calib_cli.stages.posterior import posterior
    from calib_cli.stages.suggest import suggest_conditions

    run = _with_profiles(_tiny_run(tmp_path / "run"))
    posterior(run, walkers=8, steps=60, profile=True, **QUIET)
    rig = tmp_path / "rig.toml"
    rig.write_text("[rig]\nparticle_sizes_mm = [[4, 5]]\ncylinder_diameter_mm = [40]\nfill_height_mm = [50, 75, 100]\n"
                   "lift_speed_mm_s = [50]\n")
    said = []
    r = suggest_conditions(run, rig, top=1, say=lambda m, **k: said.append(m))
    t = r.table.set_index("condition_id")
    assert t.loc["d4-5_D40_H75", "info_gain_nats"] > t.loc["d4-5_D40_H75", "info_gain_angle_nats"] > 0
    # the gain's range over both processes' realisations holds the gain of both responses
    assert t.loc["d4-5_D40_H75", "info_gain_q05"] <= t.loc["d4-5_D40_H75", "info_gain_nats"] \
        <= t.loc["d4-5_D40_H75", "info_gain_q95"]
    assert art.read_provenance(run / "suggest" / "ranking.parquet")["profile"] is True
    assert "profiles" in json.loads((run / "suggest" / "rank.lock.json").read_text())["inputs"]
    assert "angle and profile" in " ".join(said)
    from calib_cli.report import build_report

    assert "mean angle and its photographs&#x27; heap profile" in build_report(run)


def test_the_report_shows_the_posterior_and_what_to_measure_next(ranked):
    from calib_cli.report import build_report

    run, _, r = ranked
    page = build_report(run)
    assert "<h3>Calibrated parameters: the posterior</h3>" in page
    assert "90 % interval" in page and "Measure next" in page and "To tell cohesion apart" in page
    assert r.table["condition_id"].iloc[0] in page
    assert "given each condition&#x27;s mean angle" in page
    with pytest.MonkeyPatch.context() as mp:  # a reason's commands are set as code
        from calib_cli.report.html import RunFiles
        read = RunFiles.table
        odd = r.table.assign(reason="simulate heaps there (`--simulate x --heaps 12`)")
        mp.setattr(RunFiles, "table", lambda self, rel, *a, **k: odd if rel == "suggest/ranking.parquet"
                   else read(self, rel, *a, **k))
        shown = build_report(run).split("Measure next")[1].split("</div>")[0]
    assert "<code>--simulate x --heaps 12</code>" in shown and "`" not in shown
    # where the largest gain is open, the report names the candidates in contention, as the command's note does
    from calib_cli.posterior.suggest import unsettled_words
    from calib_cli.report.html import RunFiles

    t = r.table.assign(p_best_gain=[0.6, 0.4] + [np.nan] * (len(r.table) - 2),
                       gain_regret_q90=[0.3, 0.5] + [np.nan] * (len(r.table) - 2))
    read = RunFiles.table
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(RunFiles, "table", lambda self, rel, *a, **k: t if rel == "suggest/ranking.parquet"
                   else read(self, rel, *a, **k))
        assert unsettled_words(t) and "The surrogate&#x27;s own uncertainty leaves open" in build_report(run)


def _evidence_for_ranking():
    """Two measured fills; cohesion's signature falls with the fill, rolling friction's does not."""
    from calib_cli.posterior.suggest import Evidence

    measured = pd.DataFrame({"condition_id": ["H50", "H100"], "particle_d_min_mm": 4.0, "cylinder_diameter_mm": 40.0,
                             "fill_height_mm": [50.0, 100.0]})
    J = pd.DataFrame({"rolling_friction": [30.0, 30.0]})
    G = pd.DataFrame({"cohesion": [12.0, 6.0]})
    draws = np.random.default_rng(0).random((200, 1))
    return Evidence(measured, J, G, np.array([0.5, 0.5]), 1.5, ["rolling_friction"], draws, {"cohesion": 0.5})


def test_a_separation_carried_beyond_the_measured_range_is_shown_but_not_ranked_until_simulated():
    """H150 lies beyond the measured fills: its straight-line separation is large but a guess, so the
    interpolated H75 ranks first; simulated at H150 (the effect vanishing there), its own numbers rank."""
    from calib_cli.posterior.suggest import explain, rank_conditions

    ev = _evidence_for_ranking()
    cand = pd.DataFrame({"condition_id": ["H75", "H150"], "particle_d_min_mm": 4.0, "cylinder_diameter_mm": 40.0,
                         "fill_height_mm": [75.0, 150.0]})
    mu = np.tile(30.0 + 10.0 * ev.draws[:, 0], (2, 1))  # equal information at both
    t = rank_conditions(ev, cand, mu, np.ones(2), 10, VARS).set_index("condition_id")
    assert t.loc["H150", "extrapolated"] and not t.loc["H150", "simulated"]
    assert t.loc["H150", "separation_cohesion"] > t.loc["H75", "separation_cohesion"]  # the line goes on falling
    assert t.index[0] == "H75"  # ranked on what is not a guess
    assert t.loc["H150", "candidate_cohesion"] == pytest.approx(0.0)  # 12 - 6 per 50 mm, carried to 150
    sims = pd.DataFrame({"d_rolling_friction": [np.nan, 30.0], "candidate_cohesion": [np.nan, 24.0]})
    s = rank_conditions(ev, cand, mu, np.ones(2), 10, VARS, sims).set_index("condition_id")
    assert s.loc["H150", "simulated"] and not s.loc["H150", "extrapolated"]
    assert s.loc["H150", "candidate_cohesion"] == 24.0 and s.index[0] == "H150"
    assert s.loc["H75", "separation_cohesion"] == pytest.approx(t.loc["H75", "separation_cohesion"])
    why = explain(ev, s.loc["H150"], "cohesion", VARS)
    assert "2.7x its mean" in why and "rolling friction's 1x" in why and "simulated there" in why


def test_an_information_gain_beyond_the_simulated_heaps_is_shown_but_not_ranked():
    """The draws disagree most at H150 (the larger gain), but no heap had a fill that high: its gain is
    the surrogate's extrapolation, so H75, inside the heaps' range, ranks first; the gain is still there."""
    from calib_cli.posterior.suggest import rank_conditions

    ev = _evidence_for_ranking()
    ev.G = ev.G.iloc[:, :0]  # no candidate effect: the ranking is the information alone
    cand = pd.DataFrame({"condition_id": ["H150", "H75"], "particle_d_min_mm": 4.0, "cylinder_diameter_mm": 40.0,
                         "fill_height_mm": [150.0, 75.0]})
    mu = np.vstack([30.0 + 20.0 * ev.draws[:, 0], 30.0 + 5.0 * ev.draws[:, 0]])
    t = rank_conditions(ev, cand, mu, np.ones(2), 10, VARS)
    assert list(t["condition_id"]) == ["H150", "H75"]  # without the column, the larger gain first
    t = rank_conditions(ev, cand.assign(beyond_heaps=["fill height 150 beyond the heaps' 50-100", ""]), mu,
                        np.ones(2), 10, VARS).set_index("condition_id")
    assert list(t.index) == ["H75", "H150"]
    assert t.loc["H150", "info_gain_nats"] > t.loc["H75", "info_gain_nats"] > 0


def test_where_nothing_is_ranked_the_table_does_not_say_best_first():
    """Every candidate beyond the heaps (the hidden-effect run's case): the table keeps the rig's order, so
    neither the command's heading nor the report's may read it as a ranking; one gain inside ranks again."""
    from calib_cli.posterior.suggest import any_ranked, rank_conditions
    from calib_cli.stages.suggest import SuggestResult

    ev = _evidence_for_ranking()
    ev.G = ev.G.iloc[:, :0]
    cand = pd.DataFrame({"condition_id": ["H150", "H75"], "particle_d_min_mm": 4.0, "cylinder_diameter_mm": 40.0,
                         "fill_height_mm": [150.0, 75.0]})
    mu = np.vstack([30.0 + 20.0 * ev.draws[:, 0], 30.0 + 5.0 * ev.draws[:, 0]])
    outside = rank_conditions(ev, cand.assign(beyond_heaps=["fill height 150 beyond", "fill height 75 beyond"]), mu,
                              np.ones(2), 10, VARS)
    inside = rank_conditions(ev, cand.assign(beyond_heaps=["fill height 150 beyond", ""]), mu, np.ones(2), 10, VARS)
    assert not any_ranked(outside) and any_ranked(inside)
    assert list(outside["condition_id"]) == ["H150", "H75"]  # the rig's order, kept
    assert "none is ranked" in SuggestResult(None, table=outside).title()
    assert SuggestResult(None, table=inside).title().endswith("best first")


def test_suggest_simulates_the_named_candidates_at_diagnoses_parameters(ranked, tmp_path, monkeypatch):
    """--simulate: diagnose's finite differences at the named candidates (a stand-in here records what it
    was asked), at the parameters diagnose's table names; they are ranked and written out, and a later
    ranking that does not name them says it does not read them."""
    import shutil

    from calib_cli import artifacts as art
    from calib_cli.stages import suggest as st

    run, rig, _ = ranked
    mine = tmp_path / "run"
    shutil.copytree(run, mine)
    sens = mine / "diagnose" / "sensitivities.parquet"
    theta = {"static_friction": 0.4, "rolling_friction": 0.2, "restitution": 0.3}
    art.write_table(sens, art.read_table(sens), {"theta": theta})
    asked = {}

    def fake(run_, model, theta_, conds, preset, repeats, workers, shear_modulus, cands, seeds="table"):
        assert cands == ["cohesion"] and seeds == "condition"  # the effects diagnose tested, not every one the model lacks
        asked.update(theta=theta_, ids=conds["condition_id"].tolist(), repeats=repeats)
        n = len(conds)
        return (np.zeros(n), [np.full(n, 20.0), np.full(n, 40.0), np.full(n, -2.0)], {"cohesion": np.full(n, 1.0)},
                {"cohesion": np.full(n, 0.1)}, {})

    monkeypatch.setattr(st, "signatures", fake)
    quiet = {"say": lambda *a, **k: None}
    r = st.suggest_conditions(mine, rig, top=2, simulate=["d4-5_D60_H75"], repeats=2, **quiet)
    assert asked == {"theta": {**asked["theta"], **theta}, "ids": ["d4-5_D60_H75"], "repeats": 2}
    t = r.table.set_index("condition_id")
    assert t.loc["d4-5_D60_H75", "simulated"] and t.loc["d4-5_D60_H75", "candidate_cohesion"] == 1.0
    assert np.isfinite(t.loc["d4-5_D60_H75", "separation_cohesion"])  # was unknown: no 60 mm measurement
    out = art.read_table(mine / "suggest" / "sensitivities.parquet")
    assert out["condition_id"].tolist() == ["d4-5_D60_H75"] and out["d_rolling_friction"].tolist() == [40.0]
    assert "sensitivities" in r.summary().columns
    # a ranking that no longer names it reads the measured conditions' there, and says so once
    plain = st.suggest_conditions(mine, rig, top=2, **quiet)
    assert not plain.table.set_index("condition_id").loc["d4-5_D60_H75", "simulated"]
    assert any("simulated before at d4-5_D60_H75" in n for n in plain.notes)
    assert not any("simulated before" in n for n in st.suggest_conditions(mine, rig, top=3, **quiet).notes)
    # a file its lock does not record (an interrupted ranking's) is no reason to stop: the ranking replaces it
    (mine / "suggest" / "sensitivities.parquet").write_bytes(b"not parquet")
    assert st.suggest_conditions(mine, rig, top=4, **quiet).table is not None
    with pytest.raises(CalibError, match="the candidates are"):
        st.suggest_conditions(mine, rig, simulate=["d4-5_D40_H50"], **quiet)  # measured already


def test_suggest_heaps_spreads_more_heaps_at_the_candidates_over_the_posteriors_intervals(ranked, tmp_path, monkeypatch):
    """--heaps N: beside diagnose's steps, N heaps at each named candidate at parameters spread over the
    posterior's 90 % intervals (a scrambled Sobol sequence's first N), one pile each, numbered as a design's; refused without
    --simulate, and at 1 (no design)."""
    import shutil

    from calib_cli import artifacts as art
    from calib_cli.stages import suggest as st

    run, rig, _ = ranked
    mine = tmp_path / "run"
    shutil.copytree(run, mine)
    sens = mine / "diagnose" / "sensitivities.parquet"
    art.write_table(sens, art.read_table(sens), {"theta": {"static_friction": 0.4, "rolling_friction": 0.2,
                                                          "restitution": 0.3}})
    monkeypatch.setattr(st, "signatures", lambda run_, model, theta, conds, *a, **k: (
        np.zeros(len(conds)), [np.full(len(conds), 20.0)] * len(model.parameters), {"cohesion": np.ones(len(conds))},
        {"cohesion": np.full(len(conds), 0.1)}, {}))
    asked = {}

    def fake(run_, model, points, conds, preset, repeats, workers, tag, **k):
        asked.update(points=points, ids=conds["condition_id"].tolist(), repeats=repeats, tag=tag, seeds=k["seeds"])
        return pd.DataFrame()

    monkeypatch.setattr(st, "simulate_points", fake)
    quiet = {"say": lambda *a, **k: None}
    st.suggest_conditions(mine, rig, top=2, simulate=["d4-5_D60_H75"], heaps=4, **quiet)
    post = art.read_table(mine / "posterior" / "summary.parquet").set_index("parameter")
    assert asked["ids"] == ["d4-5_D60_H75"] and asked["repeats"] == 1 and asked["tag"] == "suggest-region"
    assert asked["seeds"] == "content"  # a design's points draw apart
    assert [rid for rid, _ in asked["points"]] == [1, 2, 3, 4]
    for p in post.index:
        xs = sorted(theta[p] for _, theta in asked["points"])
        assert post.loc[p, "q05"] <= xs[0] and xs[-1] <= post.loc[p, "q95"]
        # a scrambled Sobol sequence's first 4 (a power of 2): one point in each quarter of the interval
        assert len({int(4 * (x - post.loc[p, "q05"]) / (post.loc[p, "q95"] - post.loc[p, "q05"])) for x in xs}) == 4
    # advice to simulate at another candidate keeps this one named (its sensitivities are read only where named)
    t = art.read_table(mine / "suggest" / "ranking.parquet")
    assert st._named(t, "d4-5_D40_H75") == "d4-5_D60_H75,d4-5_D40_H75" and st._named(t, "d4-5_D60_H75") == "d4-5_D60_H75"
    assert st._named(t.drop(columns="simulated"), "x") == "x"
    assert st._advice(t, "d4-5_D40_H75") == ("`--simulate d4-5_D60_H75,d4-5_D40_H75 --heaps 12`; --heaps tops up "
                                              "every candidate named")
    assert st._advice(t, "d4-5_D60_H75") == "`--simulate d4-5_D60_H75 --heaps 12`"
    # another --heaps is another ranking (the stage reruns); a larger design keeps the smaller one's points
    first = [theta for _, theta in asked["points"]]
    r = st.suggest_conditions(mine, rig, top=2, simulate=["d4-5_D60_H75"], heaps=6, **quiet)
    assert not r.skipped and len(asked["points"]) == 6 and [t for _, t in asked["points"][:4]] == first
    for bad, match in (({"heaps": 4}, "--heaps, --repeats and --workers choose the heaps --simulate makes"),
                       ({"repeats": 7}, "--heaps, --repeats and --workers choose the heaps"),
                       ({"heaps": 1, "simulate": ["d4-5_D60_H75"]}, "--heaps must be 0 or at least 2")):
        with pytest.raises(CalibError, match=match):
            st.suggest_conditions(mine, rig, **bad, **quiet)


def test_a_region_design_run_again_reuses_its_run_ids_and_a_new_point_is_numbered_on(tmp_path):
    """region_ids: a point the index holds for the region design keeps its run id (a rerun of --heaps finds
    its heaps cached and adds no row); new points take the ids after the largest."""
    from calib_cli import artifacts as art
    from calib_cli.heaps.index import RESULTS
    from calib_cli.posterior.suggest import region_design
    from calib_cli.stages.suggest import REGION, region_heaps, region_ids

    summ = pd.DataFrame({"parameter": ["a", "b"], "q05": [0.1, 1.0], "q95": [0.3, 2.0]})
    d4, d6 = region_design(summ, 4, nested=True), region_design(summ, 6, nested=True)
    assert d6.iloc[:4].equals(d4)
    (tmp_path / RESULTS).parent.mkdir(parents=True)
    made = d4.iloc[[0, 2]].assign(run_id=[7, 9], design=REGION, condition_id="c1", repose_angle=30.0)
    other = d4.iloc[[1]].assign(run_id=[3], design="compare", condition_id="c1", repose_angle=30.0)
    art.write_table(tmp_path / RESULTS, pd.concat([made, other], ignore_index=True))
    assert region_ids(tmp_path, d6, ["a", "b"])["run_id"].tolist() == [7, 10, 9, 11, 12, 13]
    # region_heaps counts the current posterior's design points a candidate has: an earlier posterior's do not
    cand = pd.DataFrame({"condition_id": ["c1", "c2"]})
    assert region_heaps(tmp_path, cand, summ).tolist() == [2, 0]
    assert region_heaps(tmp_path, cand, summ.assign(q05=[0.11, 1.0])).tolist() == [0, 0]
    assert region_heaps(tmp_path / "none", cand, summ).tolist() == [0, 0]


def test_the_surrogates_learn_a_heap_two_designs_name_once(tmp_path):
    """model_rows: the same simulation (run hash) under two designs is one pile, not two; rows without a
    hash (an index calib did not write) are all kept."""
    from calib_cli import artifacts as art
    from calib_cli.heaps.index import RESULTS
    from calib_cli.model import Model
    from calib_cli.posterior.evidence import model_rows

    (tmp_path / RESULTS).parent.mkdir(parents=True)
    rows = pd.DataFrame({"run_hash": ["h1", "h1", "h2"], "design": ["suggest-region", "bbd", "bbd"],
                         "run_id": [1, 5, 6], "repeat": 0, "condition_id": "c", "static_friction": [0.4, 0.4, 0.5],
                         "rolling_friction": 0.2, "restitution": 0.3, "repose_angle": [30.0, 30.0, 31.0],
                         "status": "ok"})
    art.write_table(tmp_path / RESULTS, rows)
    model = Model(("sliding_friction", "rolling_friction", "restitution"))
    assert sorted(model_rows(tmp_path, model)["run_hash"]) == ["h1", "h2"]
    art.write_table(tmp_path / RESULTS, rows.assign(run_hash=np.nan))
    assert len(model_rows(tmp_path, model)) == 3


def test_the_gains_spread_is_the_plug_in_gain_where_the_surrogate_is_sure():
    """gain_spread: realisations that all equal the mean leave every gain at the plug-in one, the largest
    ranked gain the best for certain and nothing to lose there; an unranked candidate gets a range but no
    chance; realisations that disagree widen the range around the plug-in gain and lower the chance."""
    from calib_cli.posterior.suggest import gain_spread, information_gain, unsettled, unsettled_words

    rng = np.random.default_rng(0)
    mu = np.stack([rng.normal(0, s, 100) for s in (1.0, 2.0, 2.2)])  # three candidates, 100 draws
    U = np.array([[1.0]])
    plug = [information_gain(m[:, None], U) for m in mu]
    same = np.broadcast_to(mu, (50, 3, 100))
    q05, q95, p, lose = gain_spread(mu, same, U, np.array([True, True, False]))
    assert np.allclose(q05, plug) and np.allclose(q95, plug)
    assert p.tolist()[:2] == [0.0, 1.0] and np.isnan(p[2]) and lose[1] == 0 and lose[0] > 0 and np.isnan(lose[2])
    noisy = mu + rng.normal(0, 1.5, (200, 3, 100)) * rng.normal(0, 1, (200, 3, 1))  # each realisation its own error
    q05, q95, p, lose = gain_spread(mu, noisy, U, np.ones(3, bool))
    assert np.all(q05 < plug) and np.all(plug < q95) and p.sum() == pytest.approx(1.0) and 0.5 < p[2] < 0.9
    t = pd.DataFrame({"condition_id": ["a", "b", "c"], "info_gain_nats": plug, "p_best_gain": p,
                      "gain_regret_q90": lose})
    # c leads but may lose 0.25 nats; b may be the best too but may lose 0.62: not a safe alternative
    lead, close = unsettled(t)
    assert lead == "c" and [c for c, *_ in close] == ["c"] and lose[2] > 0.1 and lose[1] > lose[2] + 0.1
    assert "c has the largest gain (chance 0.73" in unsettled_words(t) and "choose among them" not in unsettled_words(t)
    near = t.assign(gain_regret_q90=[lose[0], lose[2] + 0.05, lose[2]])  # b's own loss within 0.1 of c's: in
    assert [c for c, *_ in unsettled(near)[1]] == ["c", "b"]
    assert (f"; b (chance {p[1]:.2f}) may be the best too, and each of these 2 may lose up to {lose[2] + 0.05:.2f} "
            "nats (90th percentile): choose among them") in unsettled_words(near)
    five = pd.DataFrame({"condition_id": list("abcdef"), "info_gain_nats": [0.9, 0.8, 0.8, 0.8, 0.8, 0.8],
                         "p_best_gain": [0.3, 0.2, 0.2, 0.1, 0.1, 0.1], "gain_regret_q90": 0.3})
    assert "b (chance 0.20), c (chance 0.20), d (chance 0.10) and 2 more may be the best too" in unsettled_words(five)
    assert unsettled(t.assign(gain_regret_q90=0.05)) is None and unsettled_words(t.drop(columns="gain_regret_q90")) == ""
    with pytest.raises(CalibError, match="do not match"):  # realisations of the angle alone against two responses
        gain_spread(np.stack([mu, mu], axis=2), noisy, U, np.ones(3, bool))


def test_an_effect_no_condition_separates_says_so_in_the_command_and_the_report(ranked):
    """Below one chi-square unit even at its best condition, an effect's line says no condition will settle it,
    in the command's words and the report's alike (unsettling)."""
    from calib_cli.posterior.suggest import SEPARATES, unsettling
    from calib_cli.report.html import RunFiles
    from calib_cli.report import build_report

    run, _, r = ranked
    assert unsettling(SEPARATES) == "" and "no condition the rig offers" in unsettling(0.4)
    weak = r.table.assign(**{c: 0.4 for c in r.table.columns if c.startswith("separation_")})
    read = RunFiles.table
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(RunFiles, "table", lambda self, rel, *a, **k: weak if rel == "suggest/ranking.parquet"
                   else read(self, rel, *a, **k))
        page = build_report(run)
    assert "To tell cohesion apart" in page and unsettling(0.4) in page


def test_the_heaps_advised_at_a_candidate_add_to_those_it_has():
    from calib_cli.posterior.suggest import REGION_HEAPS, heaps_for

    t = pd.DataFrame({"condition_id": ["a", "b", "c"], "region_heaps": [0, 12, 24]})
    assert heaps_for(t, ["a"]) == REGION_HEAPS and heaps_for(t, ["a", "b"]) == 12 + REGION_HEAPS
    assert heaps_for(t.drop(columns="region_heaps"), ["c"]) == REGION_HEAPS


def test_a_later_region_design_is_numbered_after_the_heaps_of_one_before(tmp_path):
    from calib_cli import artifacts as art
    from calib_cli.heaps.index import RESULTS
    from calib_cli.stages.suggest import REGION, next_run_id

    assert next_run_id(tmp_path, REGION) == 1
    (tmp_path / RESULTS).parent.mkdir(parents=True)
    art.write_table(tmp_path / RESULTS, pd.DataFrame({"design": [REGION, REGION, "compare"], "run_id": [3, 12, 40],
                                                      "repose_angle": [30.0, 31.0, 29.0]}))
    assert next_run_id(tmp_path, REGION) == 13 and next_run_id(tmp_path, "bbd") == 1


def test_the_command_to_rank_names_the_two_largest_gains_beyond_the_heaps():
    """simulate_command: the ranking's command with --simulate at the two largest gains not ranked for lying
    beyond the simulated heaps (a ranked or unknown one is not named), and --heaps; "" where there is none."""
    from calib_cli.posterior.suggest import REGION_HEAPS, simulate_command, to_simulate

    t = pd.DataFrame({"condition_id": ["a", "b", "c", "d", "e"], "info_gain_nats": [0.3, 0.9, np.nan, 0.5, 2.0],
                      "beyond_heaps": ["grain size 3", "fill 150", "cylinder 60", "grain size 6", ""]})
    assert to_simulate(t) == ["b", "d"]
    fallback = "calib suggest-conditions --run R --rig G"
    assert simulate_command("calib suggest-conditions --run 'my run' --rig G --top 3", t, fallback) == (
        f"calib suggest-conditions --run 'my run' --rig G --top 3 --simulate b,d --heaps {REGION_HEAPS}")
    # the candidates simulated before stay named (their sensitivities are read only where named; cached)
    assert simulate_command("calib suggest-conditions --run R --simulate a,d --heaps 4 --rig G --simulate=e", t,
                            fallback) == f"calib suggest-conditions --run R --rig G --simulate a,d,e,b --heaps {REGION_HEAPS}"
    # a ranking made from a notebook records its script's command line: the fallback is named instead
    assert simulate_command("nb.py --x", t, fallback) == f"{fallback} --simulate b,d --heaps {REGION_HEAPS}"
    assert simulate_command("x", t.assign(beyond_heaps=""), fallback) == ""
    assert simulate_command("calib suggest-conditions --run R --force --rig G", t, fallback) == (
        f"calib suggest-conditions --run R --rig G --simulate b,d --heaps {REGION_HEAPS}")  # no --force carried
    assert to_simulate(t.drop(columns="beyond_heaps")) == []


def test_each_candidate_effect_is_given_the_condition_that_best_separates_it(ranked):
    run, rig, r = ranked
    lines = r.per_effect()
    assert len(lines) == 1 and lines[0].startswith("cohesion: best told apart at d4-5_D40_H75 (")
    assert r.per_effect(markup=True)[0].startswith("cohesion: best told apart at [bold]d4-5_D40_H75[/]")
    assert "interpolated" in lines[0]


def test_a_simulated_separation_is_weighed_as_diagnose_will_and_its_own_noise_taken_off():
    """The new residual's variance counts the simulated mean's share (compare's u), and a simulated
    signature's expected noise D^2 se^2 / u^2 is not a separation."""
    from dataclasses import replace

    from calib_cli.posterior.suggest import rank_conditions

    ev = _evidence_for_ranking()
    ev = replace(ev, J=pd.DataFrame({"rolling_friction": [30.0, 10.0]}), u=np.array([1.0, 1.0]))
    cand = pd.DataFrame({"condition_id": ["H150"], "particle_d_min_mm": 4.0, "cylinder_diameter_mm": 40.0,
                         "fill_height_mm": [150.0]})
    mu = (30.0 + 10.0 * ev.draws[:, 0])[None, :]
    sims = pd.DataFrame({"d_rolling_friction": [20.0], "candidate_cohesion": [24.0], "se_candidate_cohesion": [0.0]})

    def sep(sim_var, se=0.0):
        e = replace(ev, sim_var=sim_var)
        return rank_conditions(e, cand, mu, np.ones(1), 10, VARS, sims.assign(se_candidate_cohesion=se))[
            "separation_cohesion"].iloc[0]

    # measured alone the new mean's variance is 1.5^2 / 10 = 0.225; with the simulated share 0.225 + 0.775 = 1
    assert sep(0.775) < 0.5 * sep(0.0)
    assert sep(0.775, se=4.0) == pytest.approx(max(sep(0.775) - 0.25 * 16.0 / 1.0, 0.0))


def test_the_residuals_uncertainty_is_compares_when_compare_ran_on_these_conditions(ranked, tmp_path):
    import shutil

    from calib_cli import artifacts as art
    from calib_cli.stages.compare import measured_conditions
    from calib_cli.stages.suggest import _residual_uncertainty

    run = tmp_path / "run"
    shutil.copytree(ranked[0], run)
    meas = measured_conditions(run)
    u = np.array([0.3, 0.4])
    assert _residual_uncertainty(run, meas, u) == (pytest.approx(u), 0.0)  # compare has not run
    art.write_table(run / "compare" / "residuals.parquet",
                    pd.DataFrame({"condition_id": meas["condition_id"][::-1], "uncertainty": [1.0, 0.5]}))
    uc, sim_var = _residual_uncertainty(run, meas, u)  # matched by condition_id, not by row
    by_id = dict(zip(meas["condition_id"][::-1], [1.0, 0.5]))
    assert uc.tolist() == [by_id[c] for c in meas["condition_id"]]
    assert sim_var == pytest.approx(np.mean(np.clip(uc ** 2 - u ** 2, 0, None)))
    art.write_table(run / "compare" / "residuals.parquet", pd.DataFrame({"condition_id": ["other"], "uncertainty": [1.0]}))
    assert _residual_uncertainty(run, meas, u)[1] == 0.0  # another set of conditions: not these residuals


def test_a_gain_where_the_surrogate_extrapolates_says_so(ranked):
    """The tiny run's heaps have fills 50 and 100 mm and one cylinder: a 75 mm fill is inside them."""
    from calib_cli.posterior.gp import GPSurrogate
    from calib_cli.stages.suggest import _beyond_heaps

    run, rig, r = ranked
    assert r.table.set_index("condition_id").loc["d4-5_D40_H75", "beyond_heaps"] == ""
    rows = pd.DataFrame({"a": np.linspace(0, 1, 12), "fill_height_mm": np.tile([50.0, 100.0], 6),
                         "repose_angle": np.linspace(20, 30, 12)})
    gp = GPSurrogate(["a"], ["fill_height_mm"], {"a": (0.0, 1.0)}).fit(rows, rows["repose_angle"])
    cand = pd.DataFrame({"fill_height_mm": [75.0, 150.0]})
    assert _beyond_heaps(gp, cand) == ["", "fill height 150 beyond the heaps' 50-100"]


def test_a_rig_combination_no_heap_test_can_make_is_left_out_and_none_is_an_error():
    """8 mm grains in a 20 mm cylinder filled 10 mm: suggest wrote it into conditions.csv, which
    simulate-heap then refused. It is left out now (and said); a rig of only such is the rig file's error."""
    from calib_cli.stages.suggest import _candidates

    rig = parse_rig({"rig": {"particle_sizes_mm": [[2, 3], [6, 8]], "cylinder_diameter_mm": [20, 40],
                             "fill_height_mm": [50], "lift_speed_mm_s": [50]}})
    cand = _candidates(rig, _measured())
    assert "d6-8_D20_H50" not in set(cand["condition_id"]) and "d2-3_D20_H50" in set(cand["condition_id"])
    assert cand.attrs["unbuildable"] == ["d6-8_D20_H50"]
    small = parse_rig({"rig": {"particle_sizes_mm": [[6, 8]], "cylinder_diameter_mm": [20],
                               "fill_height_mm": [50], "lift_speed_mm_s": [50]}})
    with pytest.raises(CalibError, match="no combination of the rig file's values makes a heap test"):
        _candidates(small, _measured())
