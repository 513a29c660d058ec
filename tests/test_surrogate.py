"""Surrogates, PSO, GA and the inversion, on the paper's Table 7."""

import json

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings, strategies as st
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.cli import app
from calib_cli.surrogate.ga import ga_minimize
from calib_cli.surrogate.inversion import invert
from calib_cli.surrogate.metrics import aad, leave_one_out, mse, r2, scores, split_80_20
from calib_cli.surrogate.models import BPNetwork, PSOBPNetwork, RSMSurrogate, make_model, model_from_state
from calib_cli.surrogate.pso import pso_minimize
from conftest import PAPER, SETTINGS_DIR

INP = ["static_friction", "rolling_friction", "surface_energy"]
runner = CliRunner()


@pytest.fixture
def xy(table7):
    return table7[INP].to_numpy(float), table7["repose_angle"].to_numpy(float)


def test_metrics_are_eqs_8_to_10():
    y, yh = np.array([1.0, 2.0, 3.0]), np.array([1.5, 2.0, 2.0])
    assert mse(y, yh) == pytest.approx((0.25 + 1) / 3) and aad(y, yh) == pytest.approx(0.5)
    assert r2(y, yh) == pytest.approx(1 - 1.25 / 2)


def test_every_surrogate_has_one_interface(table7, xy):
    """fit(X, y) returns the fitted surrogate, predict(X) the response (scikit-learn's shape): the three
    of fit-surrogate, the BBD's response surface and the posterior's Gaussian process alike."""
    import inspect

    from calib_cli.doe.bbd import QuadraticRSM
    from calib_cli.posterior.gp import GPSurrogate
    from calib_cli.space import ParameterSpace
    from calib_cli.surrogate.interface import Surrogate

    X, y = xy
    frame = table7[INP]
    models = [(RSMSurrogate(INP), X), (BPNetwork(INP, epochs=5), X), (PSOBPNetwork(INP, epochs=5, iterations=2), X),
              (QuadraticRSM(ParameterSpace.from_data(table7, INP)), frame), (GPSurrogate(INP, restarts=0), frame)]
    for model, inputs in models:
        assert isinstance(model, Surrogate), model
        assert list(inspect.signature(model.fit).parameters)[:2] == ["X", "y"], model
        assert list(inspect.signature(model.predict).parameters)[:1] == ["X"], model
        assert model.fit(inputs, y) is model
        assert model.predict(inputs).shape == (len(y),), model


def test_rsm_reproduces_table9_rsm_row(xy):
    X, y = xy
    s = scores(y, RSMSurrogate(INP).fit(X, y).predict(X))
    # Table 9's RSM row: MSE 0.4631 and AAD 0.5419 in-sample; its "R2" 0.9503 is the adjusted R2 (Table 8)
    assert (round(s["mse"], 4), round(s["aad"], 4)) == (0.4631, 0.5419)
    assert round(s["r2"], 4) == 0.9783


def test_rsm_loo_r2_equals_predicted_r2(xy):
    X, y = xy
    assert r2(y, leave_one_out(lambda: RSMSurrogate(INP), X, y)) == pytest.approx(0.7948, abs=5e-5)


def test_pso_improves_initial_loss_over_random_init_on_average(xy):
    X, y = xy
    rnd, pso = [], []
    for seed in range(6):
        rnd.append(BPNetwork(INP, seed=seed, epochs=1).fit(X, y).init_loss_)
        pso.append(PSOBPNetwork(INP, seed=seed, epochs=1).fit(X, y).init_loss_)
    assert np.mean(pso) < 0.2 * np.mean(rnd)
    assert sum(p < r for p, r in zip(pso, rnd)) >= 5


def test_networks_fit_and_round_trip_through_json(xy):
    X, y = xy
    for name in ("bp", "pso-bp", "rsm"):
        m = make_model(name, INP, seed=2).fit(X, y)
        assert r2(y, m.predict(X)) > 0.9
        m2 = model_from_state(__import__("json").loads(__import__("json").dumps(m.to_state())))
        np.testing.assert_allclose(m2.predict(X), m.predict(X), rtol=1e-12)


def test_pso_and_ga_are_deterministic_and_work():
    f = lambda x: float(np.sum((x - 0.7) ** 2))  # noqa: E731
    a, b = pso_minimize(f, 3, seed=4), pso_minimize(f, 3, seed=4)
    assert np.array_equal(a.x, b.x) and a.f < 1e-3 and np.all(np.diff(a.history) <= 0)
    g = lambda P: np.sum((np.atleast_2d(P) - 0.3) ** 2, axis=1)  # noqa: E731
    r1, r2_ = ga_minimize(g, [0, 0], [1, 1], seed=3), ga_minimize(g, [0, 0], [1, 1], seed=3)
    assert np.array_equal(r1.x, r2_.x) and r1.f < 1e-3
    assert np.all(np.diff(r1.best) <= 1e-15)  # elitism: the best never gets worse


@settings(max_examples=20, deadline=None)
@given(n=st.integers(5, 60), seed=st.integers(0, 1000))
def test_split_is_seeded_and_partitions(n, seed):
    tr, te = split_80_20(n, seed)
    assert sorted(np.r_[tr, te].tolist()) == list(range(n)) and len(te) == max(1, round(0.2 * n))
    assert np.array_equal(split_80_20(n, seed)[1], te)


def test_rsm_inversion_to_the_paper_target(xy):
    X, y = xy
    m = RSMSurrogate(INP).fit(X, y)
    lo, hi = X.min(0), X.max(0)
    res = invert(lambda P: m.predict(P)[:, None], INP, lo, hi, [32.07], seed=0)
    assert np.all(res.best >= lo) and np.all(res.best <= hi)
    assert abs(m.predict(res.best[None, :])[0] - 32.07) < 0.05
    # the paper's solution is among the near-optimal points' span, and one angle cannot pin 3 parameters
    paper = np.array([0.158, 0.187, 1.580])
    r = res.ranges.set_index("parameter")
    assert all(r.loc[n, "low"] <= v <= r.loc[n, "high"] for n, v in zip(INP, paper))
    assert not res.identifiable
    assert (res.solution_set["fitness"] <= 0.25).all() and len(res.solution_set) > 100


def test_cli_fit_predict_invert(tmp_path):
    run = tmp_path / "run"
    assert runner.invoke(app, ["init", "--run", str(run), "--settings", str(SETTINGS_DIR / "paper.toml")]).exit_code == 0
    r = runner.invoke(app, ["fit-surrogate", "--run", str(run)])
    assert r.exit_code == 2 and "bbd analyze" in r.output
    r = runner.invoke(app, ["bbd", "analyze", "--run", str(run), "--responses", str(PAPER / "table7_bbd.csv")])
    assert r.exit_code == 0
    r = runner.invoke(app, ["fit-surrogate", "--run", str(run)])
    assert r.exit_code == 0, r.output
    met = art.read_table(run / "surrogate" / "metrics.parquet")
    assert list(met.columns) == ["model", "split", "r2", "mse", "aad"]
    assert set(met["split"]) == {"train", "split_train", "split_test", "loo"} and len(met) == 12
    assert "Best on held-out data" in r.output
    r = runner.invoke(app, ["predict", "--run", str(run), "--set", "static_friction=0.158", "--set",
                            "rolling_friction=0.187", "--set", "surface_energy=1.580", "--model", "rsm"])
    assert r.exit_code == 0 and "32.06" in r.output
    r = runner.invoke(app, ["predict", "--run", str(run), "--set", "static_friction=0.158"])
    assert r.exit_code == 2 and "rolling_friction" in r.output
    r = runner.invoke(app, ["invert", "--run", str(run), "--target", "32.07", "--model", "rsm"])
    assert r.exit_code == 0, r.output
    sol = art.read_table(run / "invert" / "solution.parquet").iloc[0]
    assert abs(sol["predicted_angle"] - 32.07) < 0.05
    hist = art.read_table(run / "invert" / "history.parquet")
    assert list(hist.columns) == ["generation", "best", "mean"] and len(hist) == 50
    assert (run / "invert" / "fitness.png").is_file() and "not identifiable" in r.output
    r = runner.invoke(app, ["invert", "--run", str(run), "--target", "120"])
    assert r.exit_code == 2
    # validation heaps run on the measured rig (here a 40 mm cylinder), not the preset's (50 mm)
    (run / "measure").mkdir()
    art.write_table(run / "measure" / "conditions.parquet", pd.DataFrame(
        {"condition_id": ["rig40"], "mean": [32.07], "sd": [1.0], "n": [5], "particle_d_min_mm": [6.0],
         "particle_d_max_mm": [8.0], "cylinder_diameter_mm": [40.0], "fill_height_mm": [40.0]}))
    r = runner.invoke(app, ["invert", "--run", str(run), "--model", "rsm", "--validate", "1", "--preset", "smoke"])
    assert r.exit_code == 0, r.output
    val = art.read_table(run / "invert" / "validation.parquet")
    assert list(val["condition_id"]) == ["rig40"] and "validation (rig40)" in r.output
    sims = art.read_table(run / "simulate" / "results.parquet")
    assert list(sims[["cylinder_diameter_mm", "fill_height_mm"]].iloc[0]) == [40.0, 40.0]
    # one correction at most: every round's heaps are kept, the refinement table says which round won
    r = runner.invoke(app, ["invert", "--run", str(run), "--model", "rsm", "--validate", "1", "--refine", "1",
                            "--preset", "smoke"])
    assert r.exit_code == 0, r.output
    ref = art.read_table(run / "invert" / "refinement.parquet")
    val = art.read_table(run / "invert" / "validation.parquet")
    assert set(val["round"]) == set(ref["round"]) and len(val) == len(ref) <= 2
    assert "Refinement by simulation" in r.output
    chosen = art.read_provenance(run / "invert" / "refinement.parquet")["chosen_round"]
    sol = art.read_table(run / "invert" / "solution.parquet").iloc[0]
    assert sol["rolling_friction"] == ref.loc[ref["round"] == chosen, "rolling_friction"].iloc[0]
    r = runner.invoke(app, ["report", "--run", str(run)])
    assert r.exit_code == 0
    page = (run / "report.html").read_text()
    assert "Box-Behnken" in page and "GA inversion" in page and 'src="bbd/surface_' in page
    r = runner.invoke(app, ["report", "--run", str(tmp_path / "empty")])
    assert r.exit_code == 2 and "no stage output" in r.output


def test_the_near_optimal_set_contains_the_reported_optimum(monkeypatch):
    """The GA reports its best-ever point, which its final population (mutated after the last
    selection) and the Sobol sample may both miss: the set and its ranges must contain it."""
    from calib_cli.surrogate import inversion as inv
    from calib_cli.surrogate.ga import GAResult

    def predict(P):  # a sharp well at a = 0.6 on a flat floor, two conditions
        P = np.atleast_2d(P)
        base = 35.0 + 5.0 * np.exp(-((P[:, 0] - 0.6) / 0.001) ** 2)
        return np.column_stack([base, base])

    def ga_found_the_well(f, lo, hi, *a, **k):  # a population that has drifted off the best
        pop = np.array([[0.2, 0.5], [1.2, 0.5]])
        return GAResult(np.array([0.6, 0.5]), 0.0, np.zeros(1), np.zeros(1), pop, f(pop))

    monkeypatch.setattr(inv, "ga_minimize", ga_found_the_well)
    res = inv.invert(predict, ["a", "b"], [0.0, 0.0], [1.6, 1.0], [40.0, 40.0], samples=256, restarts=2)
    r = res.ranges.set_index("parameter")
    assert r.loc["a", "low"] <= 0.6 <= r.loc["a", "high"] and r.loc["a", "high"] - r.loc["a", "low"] < 0.01
    assert res.solution_set["fitness"].min() == 0.0


def _simulated_bbd(tmp_path, lost, var=("fill_height_mm", "H", (50.0, 100.0), -0.05)):
    """A run whose BBD was 'simulated' under two conditions, by default two fill heights (a plane
    plus the condition variable's effect); ``lost``: (run_id, condition_id) pairs that gave no
    angle (a timeout)."""
    from calib_cli.heaps.index import RESULTS
    from calib_cli.heaps.keys import CACHE_SOURCE

    name, tag, levels, slope = var
    run = tmp_path / "run"
    assert runner.invoke(app, ["init", "--run", str(run), "--settings", str(SETTINGS_DIR / "paper.toml")]).exit_code == 0
    assert runner.invoke(app, ["bbd", "design", "--run", str(run)]).exit_code == 0
    design = art.read_table(run / "bbd" / "design.parquet")
    rows = []
    for _, d in design.iterrows():
        for level in levels:
            cid = f"{tag}{level:g}"
            y = 20 + 10 * d["static_friction"] + 30 * d["rolling_friction"] + 5 * d["surface_energy"] + slope * level
            bad = (int(d["run_id"]), cid) in lost
            rows.append({"design": "bbd", "run_id": int(d["run_id"]), "repeat": 0, "condition_id": cid,
                         name: level, "run_hash": f"{int(d['run_id'])}-{cid}", "model": "",
                         "source": CACHE_SOURCE, "status": "timeout" if bad else "ok",
                         "repose_angle": np.nan if bad else y, **{k: d[k] for k in INP}})
    art.write_table(run / RESULTS, pd.DataFrame(rows))
    return run


def test_fit_on_simulations_leaves_out_failed_runs_and_refuses_a_hole_in_the_design(tmp_path):
    fit = ["fit-surrogate", "--from-simulations", "bbd", "-s", 'surrogate.models=["rsm"]']
    run = _simulated_bbd(tmp_path / "a", {(3, "H50")})
    r = runner.invoke(app, [*fit, "--run", str(run)])
    assert r.exit_code == 0, r.output
    assert "1 of 34 simulations of the bbd design gave no angle (timeout 1)" in " ".join(r.output.split())
    assert len(art.read_table(run / "surrogate" / "predictions.parquet")) == 33
    # every condition of a design point lost: the surface would guess that corner, as `bbd analyze` refuses
    run = _simulated_bbd(tmp_path / "b", {(3, "H50"), (3, "H100")})
    r = runner.invoke(app, [*fit, "--run", str(run)])
    assert r.exit_code == 2 and "design run(s) 3 of bbd gave no angle under any condition" in " ".join(r.output.split())
    assert not (run / "surrogate" / "predictions.parquet").exists()


def test_a_floor_that_differs_between_conditions_is_a_surrogate_input(tmp_path):
    """Conditions on two floors of given friction: the surrogate takes the floor's friction as an
    input, as it takes a fill height, so that the inversion can tell the floors apart."""
    run = _simulated_bbd(tmp_path, set(), var=("floor_static_friction", "F", (0.2, 0.6), 8.0))
    r = runner.invoke(app, ["fit-surrogate", "--from-simulations", "bbd", "-s", 'surrogate.models=["rsm"]',
                            "--run", str(run)])
    assert r.exit_code == 0, r.output
    best = json.loads((run / "surrogate" / "best.json").read_text())
    assert best["inputs"][-1] == "floor_static_friction"


def _refine_problem(bias):
    """A plane surrogate f = 30 + 10 a + 5 b that the 'simulator' y = f + bias(a, b) contradicts."""
    from calib_cli.discrepancy.stats import residual_table
    from calib_cli.surrogate import inversion as inv

    names, lo, hi, target = ["a", "b"], [0.0, 0.0], [1.0, 1.0], [38.0]

    def f(P):
        P = np.atleast_2d(P)
        return (30.0 + 10.0 * P[:, 0] + 5.0 * P[:, 1])[:, None]

    calls = []

    def simulate(x, k):
        calls.append(k)
        y = float(f(x)[0, 0] + bias(x))
        sim = pd.DataFrame({"condition_id": ["c"], "mean": [y], "sd": [1.0], "n": [3]})
        rt = residual_table([target[0]], [1.0], [5], [y], [1.0], [3])
        return pd.concat([sim, rt], axis=1)

    def reinvert(d, x):
        again = inv.invert(lambda P: f(P) + d[None, :], names, lo, hi, target, samples=1024, restarts=2)
        return inv.nearest(again.solution_set, names, lo, hi, x)

    x0 = inv.invert(f, names, lo, hi, target, samples=1024, restarts=2).best
    return inv.refine(f, simulate, reinvert, x0, target, names, rounds=4), calls, f, bias


def test_refinement_corrects_a_wrong_surrogate_until_the_simulations_agree():
    """The surrogate is 3 deg too steep and its slope in a 20 % off: the first validation fails,
    output space mapping moves the point until the simulated angle meets the target within 1 sd."""
    ref, calls, f, bias = _refine_problem(lambda x: -3.0 - 2.0 * x[0])
    r0 = ref.rounds[ref.rounds["round"] == 0].iloc[0]
    assert r0["fails"] and abs(r0["bias"] - bias(r0[["a", "b"]].to_numpy(float))) < 1e-9
    assert ref.accepted and ref.best_round >= 1 and calls == list(range(ref.best_round + 1))
    y = f(ref.best)[0, 0] + bias(ref.best)
    u = ref.rounds.loc[ref.rounds["round"] == ref.best_round, "uncertainty"].iloc[0]
    assert abs(y - 38.0) <= u
    # every round is recorded with its parameters, prediction and correction
    assert {"round", "a", "b", "target", "predicted", "bias", "z", "fails"} <= set(ref.rounds.columns)


def test_refinement_stops_at_once_when_the_first_validation_agrees():
    ref, calls, _, _ = _refine_problem(lambda x: 0.5)
    assert ref.accepted and ref.best_round == 0 and calls == [0] and len(ref.rounds) == 1


def test_refinement_that_cannot_reach_the_target_keeps_the_closest_round():
    """No point of the box reaches 38 deg (the simulator is 30 deg lower everywhere): not accepted,
    and the chosen round is the one with the smallest |z|."""
    ref, calls, _, _ = _refine_problem(lambda x: -30.0)
    # the corrected surrogate's best is the box's steepest corner; once there, it stays: no re-measuring
    assert not ref.accepted and ref.stalled and len(calls) < 5
    worst = ref.rounds.groupby("round")["z"].apply(lambda z: z.abs().max())
    assert ref.best_round == int(worst.idxmin())


def test_nearest_point_of_a_set_is_measured_in_coded_units():
    from calib_cli.surrogate.inversion import nearest

    s = pd.DataFrame({"a": [0.0, 10.0], "b": [0.5, 0.0]})
    # a spans 0-100, b 0-1: (10, 0) is 0.1 + 0.0 coded from (0, 0); (0, 0.5) is 0.5 away
    assert list(nearest(s, ["a", "b"], [0, 0], [100, 1], [0.0, 0.0])) == [10.0, 0.0]


def test_cli_refine_needs_validation_heaps(tmp_path):
    run = tmp_path / "run"
    assert runner.invoke(app, ["init", "--run", str(run), "--settings", str(SETTINGS_DIR / "paper.toml")]).exit_code == 0
    assert runner.invoke(app, ["bbd", "analyze", "--run", str(run), "--responses",
                               str(PAPER / "table7_bbd.csv")]).exit_code == 0
    assert runner.invoke(app, ["fit-surrogate", "--run", str(run)]).exit_code == 0
    r = runner.invoke(app, ["invert", "--run", str(run), "--target", "32.07", "--refine", "2"])
    assert r.exit_code == 2 and "--validate" in r.output and not (run / "invert").exists()


def test_one_target_serves_every_validation_condition():
    """`invert --target T --validate N` on a run measured under two conditions: no refinement, and
    each condition's heaps are compared with the one target."""
    from calib_cli.surrogate.inversion import refine

    sim = pd.DataFrame({"condition_id": ["a", "b"], "mean": [30.0, 31.0], "sd": [1.0, 1.0], "n": [3, 3],
                        "z": [0.1, -0.2], "fails": [False, False]})
    ref = refine(lambda P: np.array([[30.5]]), lambda x, k: sim, None, [0.2, 0.3], [30.5], ["p", "q"], rounds=0)
    assert list(ref.rounds["target"]) == [30.5, 30.5] and list(ref.rounds["bias"]) == [-0.5, 0.5]
    assert ref.accepted and ref.best_round == 0


def test_refinement_stops_when_the_correction_keeps_the_point():
    """A correction that returns the point just simulated would only re-measure it (and keep the
    luckiest draw): refinement stops there and keeps the best round so far."""
    from calib_cli.surrogate.inversion import refine

    calls = []

    def simulate(x, k):
        calls.append(k)
        return pd.DataFrame({"condition_id": ["a"], "mean": [31.0], "sd": [1.0], "n": [4], "z": [-1.5],
                             "fails": [False]})

    ref = refine(lambda P: np.array([[30.0]]), simulate, lambda d, x: x.copy(), [0.2, 0.3], [30.0], ["p", "q"],
                 rounds=3)
    assert calls == [0] and ref.stalled and not ref.accepted and ref.best_round == 0


def test_refinement_stops_when_the_correction_moves_the_point_less_than_its_tolerance():
    """A correction of 0.0002 (seen on the hidden-effect lab) re-measures the same heaps in all but
    name: within ``xtol`` it counts as keeping the point; with no tolerance it is another round."""
    from calib_cli.surrogate.inversion import refine

    def run(xtol):
        calls = []

        def simulate(x, k):
            calls.append(k)
            return pd.DataFrame({"condition_id": ["a"], "mean": [31.0], "sd": [1.0], "n": [4], "z": [-1.5],
                                 "fails": [False]})

        ref = refine(lambda P: np.array([[30.0]]), simulate, lambda d, x: x + np.array([0.0002, 0.0]),
                     [0.2, 0.3], [30.0], ["p", "q"], rounds=3, xtol=xtol)
        return ref, calls

    ref, calls = run(np.array([0.003, 0.003]))
    assert calls == [0] and ref.stalled and ref.best_round == 0
    ref, calls = run(0.0)
    assert calls == [0, 1, 2, 3] and not ref.stalled


def test_invert_warns_when_the_solution_sits_on_the_edge_of_the_fitted_range(tmp_path):
    """A target steeper than any heap of the design drives the GA into a corner of the box the
    surrogate was fitted on: `invert` must say that the data may want a value beyond it. The
    paper's own target (32.07 deg) lies inside the box: no such warning."""
    run = tmp_path / "run"
    assert runner.invoke(app, ["init", "--run", str(run), "--settings", str(SETTINGS_DIR / "paper.toml")]).exit_code == 0
    assert runner.invoke(app, ["bbd", "analyze", "--run", str(run), "--responses",
                               str(PAPER / "table7_bbd.csv")]).exit_code == 0
    assert runner.invoke(app, ["fit-surrogate", "--run", str(run)]).exit_code == 0
    r = runner.invoke(app, ["invert", "--run", str(run), "--target", "32.07"])
    assert r.exit_code == 0, r.output
    assert "end of the range" not in r.output
    r = runner.invoke(app, ["invert", "--run", str(run), "--target", "70", "--force"])
    assert r.exit_code == 0, r.output
    assert "at the high end of the range the surrogate was fitted on" in " ".join(r.output.split())


def test_a_refinement_without_validation_heaps_names_where_it_was_asked(tmp_path):
    """The sample calibration's settings ask for three corrections (invert.refine = 3): `invert` without
    --validate names that setting, not an option the user did not give, and writes nothing."""
    import shutil
    from pathlib import Path

    from calib_cli.errors import CalibError
    from calib_cli.stages.invert import invert

    run = tmp_path / "cal"
    shutil.copytree(Path(__file__).resolve().parents[1] / "sample_runs" / "calibration", run)
    before = (run / "invert" / "solve.lock.json").read_bytes()
    with pytest.raises(CalibError, match=r"the settings' invert.refine = 3 corrects .* --validate N too, or --refine 0"):
        invert(run, say=lambda *a, **k: None)
    with pytest.raises(CalibError, match=r"^--refine corrects"):
        invert(run, refine=1, say=lambda *a, **k: None)
    assert (run / "invert" / "solve.lock.json").read_bytes() == before


def test_invert_says_which_measured_conditions_lie_beyond_what_the_surrogate_learnt(tmp_path):
    """A surrogate over condition variables predicts a measured condition outside the range it learnt them over
    by extrapolation: the inversion's warnings name the condition and the variable (fill height 300 mm against
    a surrogate of 50-100 mm, as a helper found invert passing in silence)."""
    from calib_cli.stages.invert import _beyond_learnt

    (tmp_path / "measure").mkdir()
    art.write_table(tmp_path / "measure" / "conditions.parquet",
                    pd.DataFrame({"condition_id": ["a", "b"], "mean": [30.0, 31.0], "fill_height_mm": [300.0, 75.0],
                                  "particle_d_min_mm": [4.0, 5.0]}))
    best = {"inputs": ["static_friction", "particle_d_min_mm", "fill_height_mm"], "lows": [0.3, 4.0, 50.0],
            "highs": [0.7, 5.0, 100.0]}
    said = _beyond_learnt(tmp_path, best)
    assert len(said) == 1 and said[0].startswith("condition(s) a set fill_height_mm beyond the 50 to 100")
    assert _beyond_learnt(tmp_path, {**best, "highs": [0.7, 5.0, 300.0]}) == []
    assert _beyond_learnt(tmp_path, {"inputs": ["static_friction"], "lows": [0.3], "highs": [0.7]}) == []
