"""The discrepancy loop: residual statistics and the score test on controlled data, the model
file with revisions, and the compare / diagnose / synth-lab plumbing on tiny heaps."""

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.cli import app
from calib_cli.discrepancy.stats import (difference_se, per_condition, residual_table, score_effects,
                                        signature_noise, summary, trends)
from calib_cli.errors import CalibError
from calib_cli.model import EFFECTS, Model, load_model, save_model

runner = CliRunner()

# six conditions: particle sizes and cylinder diameters
D_P = np.array([3.0, 4.0, 5.0, 3.0, 4.0, 5.0])  # mean particle diameter, mm
D_C = np.array([50.0, 50.0, 50.0, 100.0, 100.0, 100.0])  # cylinder diameter, mm
J = np.column_stack([np.full(6, 20.0) + np.array([0, 1, -1, 0.5, -0.5, 0]),  # d angle / d static friction
                     np.full(6, 40.0) + np.array([1, 0, -1, 0, 1, -1])])  # d angle / d rolling friction
G = {"cohesion": 8.0 / D_P,  # grows as grains get smaller
     "wall_friction": 600.0 / D_C,  # grows as the cylinder narrows
     "restitution": np.array([-0.5, -0.45, -0.55, -0.5, -0.6, -0.4])}  # small, no size or diameter trend
U = np.full(6, 0.45)  # combined uncertainty of each residual (deg)


def lab(effect, strength, seed):
    rng = np.random.default_rng(seed)
    r = (strength * G[effect] if effect else 0.0) + rng.normal(0, U[0], 6)
    # the calibration absorbed what the current parameters can: leave only the orthogonal part
    w = 1 / U**2
    beta = np.linalg.lstsq(J.T @ (w[:, None] * J), J.T @ (w * r), rcond=None)[0]
    return r - J @ beta


@pytest.mark.parametrize("hidden,strength", [("cohesion", 2.5), ("wall_friction", 0.2)])
def test_hidden_effect_is_ranked_first(hidden, strength):
    """After projecting out what friction and rolling absorb, the hidden effect's signal is
    2.5 deg (cohesion: +4 to +7 deg from 5 mm to 3 mm grains) or 1.5 deg (wall friction) in norm,
    against 0.45 deg of noise per condition."""
    firsts, sig = 0, 0
    for seed in range(40):
        rank = score_effects(lab(hidden, strength, seed), U, J, G)
        firsts += rank.iloc[0]["effect"] == hidden
        sig += rank.iloc[0]["p_value"] < 0.05
    assert firsts >= 36 and sig >= 36  # 90 % of labs


def test_control_lab_has_no_significant_effect():
    false = 0
    for seed in range(200):
        rank = score_effects(lab(None, 0.0, seed), U, J, G)
        false += (rank["p_value"] < 0.05 / len(G)).any()  # Bonferroni over the candidates
    assert false / 200 <= 0.06


def test_collinear_candidates_are_reported_as_confounded():
    from calib_cli.discrepancy.stats import confounded

    G2 = {**G, "twin": 2.0 * G["cohesion"] + 0.01 * J[:, 0]}
    pairs = confounded(U, J, G2)
    assert ("cohesion", "twin") in pairs or ("twin", "cohesion") in pairs
    assert not confounded(U, J, G)


def test_score_is_invariant_to_what_the_parameters_absorb():
    r = lab("cohesion", 1.0, 3)
    base = score_effects(r, U, J, G).set_index("effect")
    # adding any combination of J's columns to a candidate changes nothing: it is projected out
    G2 = {**G, "cohesion": G["cohesion"] + J @ np.array([0.3, -0.2])}
    again = score_effects(r, U, J, G2).set_index("effect")
    assert again.loc["cohesion", "score"] == pytest.approx(base.loc["cohesion", "score"], rel=1e-9)
    assert 0 <= base.loc["cohesion", "explained_fraction"] <= 1


def test_pooled_scatter_keeps_the_false_failure_rate_near_nominal():
    """No true misfit, 3 measured and 2 simulated heaps per condition, 6 conditions, the same
    scatter everywhere: with each condition's own sd a chance small sd makes it 'fail' far more
    often than |z| > 2 promises; pooled over conditions the rate is near the t distribution's
    (df = 18: 6 %)."""
    rng = np.random.default_rng(7)
    fails = {True: 0, False: 0}
    n_labs = 2000
    for _ in range(n_labs):
        meas = rng.normal(30.0, 2.0, (6, 3))
        sim = rng.normal(30.0, 2.0, (6, 2))
        for pool in (True, False):
            t = residual_table(meas.mean(1), meas.std(1, ddof=1), [3] * 6, sim.mean(1), sim.std(1, ddof=1), [2] * 6,
                               pool=pool)
            fails[pool] += int(t["fails"].sum())
    rate = {k: v / (6 * n_labs) for k, v in fails.items()}
    assert 0.04 <= rate[True] <= 0.08
    assert rate[False] > 1.5 * rate[True]


def test_difference_se_pools_the_scatter_of_both_ends():
    rows = pd.DataFrame({"condition_id": ["a"] * 4 + ["b"] * 4, "repose_angle": [30, 32, 34, 36, 20, 22, 24, 26.0]})
    a = per_condition(rows, ["a", "b"])
    b = per_condition(rows.assign(repose_angle=rows["repose_angle"] - 1.0), ["a", "b"])
    sd = np.std([30, 32, 34, 36.0], ddof=1)  # every group has the same sd
    assert np.allclose(difference_se(a, b, 0.5), np.sqrt(2 * sd**2 / 4) / 0.5)
    assert np.isnan(difference_se(a, per_condition(rows[rows["condition_id"] == "a"], ["a", "b"]), 1.0)[1])


def test_signature_noise_flags_noise_at_the_nominal_rate_and_resolves_a_signal():
    rng = np.random.default_rng(3)
    se = np.array([0.5, 1.0, 2.0, 1.0, 0.7, 1.5])
    p = np.array([signature_noise(rng.normal(0, se), se)[1] for _ in range(4000)])
    assert abs(np.mean(p < 0.05) - 0.05) < 0.012  # a pure-noise signature is "resolved" 5 % of the time
    x2, p1 = signature_noise(4 * se + rng.normal(0, se), se)
    assert p1 < 1e-6 and x2 > 50
    assert np.isnan(signature_noise([1.0, 2.0], [np.nan, 0.0])[1])


def test_residuals_and_summary():
    t = residual_table([30.0, 33.0], [1.0, 1.0], [4, 4], [30.2, 30.0], [0.5, 0.5], [4, 4])
    u = np.sqrt(1 / 4 + 0.25 / 4)
    assert t["uncertainty"].tolist() == pytest.approx([u, u])
    assert t["z"].tolist() == pytest.approx([-0.2 / u, 3.0 / u])
    assert t["fails"].tolist() == [False, True]
    s = summary(t, 1)
    assert s["rmse"] == pytest.approx(np.sqrt((0.04 + 9) / 2)) and s["n_fail"] == 1
    tr = trends(pd.DataFrame({"residual": 8.0 / D_P}), pd.DataFrame({"d": D_P}))
    assert tr.iloc[0]["slope"] < 0


@pytest.mark.parametrize("n_params,sim_n", [(4, 4), (3, 4), (4, 40), (8, 4)])
def test_chi2_per_dof_is_one_on_average_where_the_fitted_model_is_right(n_params, sim_n):
    """A model that fits: p parameters fitted (least squares) to 6 measured means of 10 piles each, then
    compare's fresh heaps at the fit (``sim_n`` a condition). chi2/dof averages 1 over many labs: the fit
    shrinks only the measured part of the residuals. Dividing by C - p read 2.7 at p = 4 with four heaps a
    condition (1.6 with forty; 4.9 with more parameters than conditions, where the fit is exact). The
    variances are estimated from the piles (18 degrees of freedom for four heaps at six conditions), which
    lifts the mean of z^2 by up to ~12 % (E[1/s^2] = 1 / sigma^2 * nu / (nu - 2))."""
    rng = np.random.default_rng(7)
    C, sm, ss = 6, 3.0, 3.5
    X = np.column_stack([np.ones(C), rng.normal(size=(C, n_params - 1))])
    truth = X @ rng.normal(size=n_params)
    new, old = [], []
    for _ in range(3000):
        piles = truth[:, None] + rng.normal(0, sm, (C, 10))
        m = piles.mean(axis=1)
        fit = X @ np.linalg.lstsq(X, m, rcond=None)[0]
        heaps = fit[:, None] + rng.normal(0, ss, (C, sim_n))
        t = residual_table(m, piles.std(axis=1, ddof=1), np.full(C, 10), heaps.mean(axis=1),
                           heaps.std(axis=1, ddof=1), np.full(C, sim_n))
        new.append(summary(t, n_params)["chi2_dof"])
        old.append(np.sum(t["z"] ** 2) / max(C - n_params, 1))
    assert 0.95 < np.mean(new) < 1.13
    if (n_params, sim_n) == (4, 4):
        assert np.mean(old) > 1.8


def test_model_revisions_and_pinning(tmp_path):
    m = load_model(tmp_path)
    assert m.revision == 0 and "cohesion" not in m.effects
    assert m.pin({"static_friction": 0.4, "rolling_friction": 0.1, "restitution": 0.3})["surface_energy"] == 0.0
    m1 = save_model(tmp_path, Model((*m.effects, "cohesion")))
    m2 = save_model(tmp_path, Model(tuple(e for e in m1.effects if e != "rolling_friction")))
    assert (m1.revision, m2.revision) == (1, 2)
    assert load_model(tmp_path).effects == m2.effects
    assert (tmp_path / "model" / "rev-0001.toml").is_file() and (tmp_path / "model" / "rev-0002.toml").is_file()
    assert m1.hash != m2.hash
    assert "wall_static_friction" not in m2.pin({"static_friction": 0.4})  # tied to the particles' value
    with pytest.raises(Exception):
        Model(("levitation",))


def test_a_revision_kept_is_never_overwritten_nor_a_lost_model_file_read_as_the_default(tmp_path):
    """model.toml set back to revision 1 and an effect added: revision 3, not a second revision 2; model.toml
    gone while model/ keeps revisions, or a folder, or model/ a file: one line each, nothing written."""
    base = load_model(tmp_path).effects
    save_model(tmp_path, Model((*base, "cohesion")))
    save_model(tmp_path, Model((*base, "cohesion", "capillary")))
    kept = (tmp_path / "model" / "rev-0002.toml").read_bytes()
    shutil.copy(tmp_path / "model" / "rev-0001.toml", tmp_path / "model.toml")
    m3 = save_model(tmp_path, Model((*base, "cohesion", "wall_friction")))
    assert m3.revision == 3 and (tmp_path / "model" / "rev-0002.toml").read_bytes() == kept
    (tmp_path / "model.toml").unlink()
    with pytest.raises(CalibError, match=r"model.toml is missing, but .*model keeps revisions 1-3: restore"):
        load_model(tmp_path)
    (tmp_path / "model.toml").mkdir()
    with pytest.raises(CalibError, match="model.toml is not a file"):
        load_model(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    (other / "model").write_text("")
    with pytest.raises(CalibError, match="model is not a folder"):
        save_model(other, Model((*base, "cohesion")))
    assert not (other / "model.toml").exists()


def test_model_refuses_values_it_would_drop():
    m = Model(("sliding_friction", "rolling_friction", "restitution", "wall_friction"), 1)
    m.check({"static_friction": 0.4, "wall_static_friction": 0.2, "surface_energy": 0.0})  # cohesion off: fine
    with pytest.raises(Exception, match="cohesion not in the model"):
        m.check({"static_friction": 0.4, "surface_energy": 0.5})
    with pytest.raises(Exception, match="wall_rolling"):  # NaN neutral: any value means the effect is on
        m.check({"wall_rolling_friction": 0.1})
    with pytest.raises(Exception, match="no effect"):
        m.check({"wall_restitution": 0.3})
    # a contact-law switch chooses the law, it is no effect's value: checked by the kernel, passed on
    m.check({"static_friction": 0.4, "rolling_spring": 1.0})
    assert m.pin({"static_friction": 0.4, "rolling_spring": 1.0})["rolling_spring"] == 1.0
    assert "rolling_spring" not in m.pin({"static_friction": 0.4})


def test_diagnose_probes_forward_from_neutral_and_central_around_the_grains_value():
    theta = {"static_friction": 0.3, "rolling_friction": 0.12, "restitution": 0.3}
    assert EFFECTS["cohesion"].probe(theta) == (0.0, 0.5)  # forward from neutral (effect off)
    assert not EFFECTS["cohesion"].two_sided and EFFECTS["wall_friction"].two_sided
    # the walls default to the grains' friction: step both ways around it, over the same span
    lo, hi = EFFECTS["wall_friction"].probe(theta)
    assert (lo, hi) == pytest.approx((0.2, 0.4))
    assert EFFECTS["wall_rolling"].probe(theta) == pytest.approx((0.07, 0.17))
    # clipped to the effect's bounds on either side
    assert EFFECTS["wall_friction"].probe({**theta, "static_friction": 0.95}) == pytest.approx((0.85, 1.0))
    assert EFFECTS["wall_rolling"].probe({**theta, "rolling_friction": 0.0}) == pytest.approx((0.0, 0.05))


def test_model_cli(tmp_path):
    run = str(tmp_path / "run")
    r = runner.invoke(app, ["model", "add", "cohesion", "--run", run])
    assert r.exit_code == 2 and "does not exist" in r.output and not (tmp_path / "run").exists()  # a typo'd --run
    (tmp_path / "run").mkdir()
    r = runner.invoke(app, ["model", "add", "cohesion", "--run", run])
    assert r.exit_code == 0 and "revision 1" in r.output
    r = runner.invoke(app, ["model", "add", "cohesion", "--run", run])
    assert r.exit_code == 2 and "already" in r.output
    r = runner.invoke(app, ["model", "remove", "cohesion", "--run", run])
    assert r.exit_code == 0 and "revision 2" in r.output
    assert runner.invoke(app, ["model", "add", "magic", "--run", run]).exit_code == 2

def test_compare_uses_the_calibration_s_fixed_values_and_effects(tmp_path):
    """Without a model file, an effect the calibration switched on joins the model (simulate-heap
    pins nothing then), and parameters the BBD held fixed keep their fixed values."""
    from calib_cli.discrepancy.point import model_and_theta as _model_and_theta

    (tmp_path / "bbd").mkdir()
    (tmp_path / "invert").mkdir()
    design = pd.DataFrame({"run_id": [1, 2], "static_friction": [0.2, 0.4], "rolling_friction": [0.1, 0.3],
                           "surface_energy": [0.0, 0.5], "restitution": [0.25, 0.25]})
    art.write_table(tmp_path / "bbd" / "design.parquet", design)
    sol = {"static_friction": 0.3, "rolling_friction": 0.2, "surface_energy": 0.4, "predicted_angle": 31.0}
    art.write_table(tmp_path / "invert" / "solution.parquet", pd.DataFrame([sol]))
    model, theta = _model_and_theta(tmp_path, None)
    assert "cohesion" in model.effects and model.revision == 0
    assert theta == {"static_friction": 0.3, "rolling_friction": 0.2, "restitution": 0.25, "surface_energy": 0.4}
    # at its neutral value the effect stays out (a candidate for diagnose); --set wins over all
    model, theta = _model_and_theta(tmp_path, ["surface_energy=0", "restitution=0.3"])
    assert "cohesion" not in model.effects and theta["restitution"] == 0.3
    # a model file is the user's word: nothing joins it
    save_model(tmp_path, Model(("sliding_friction", "rolling_friction", "restitution")))
    assert "cohesion" not in _model_and_theta(tmp_path, None)[0].effects


def test_chi2_dof_counts_only_the_parameters_the_calibration_fitted(tmp_path):
    """A parameter the response surface held fixed (restitution here) or --set by hand took no degree of freedom
    from the measured means: compare's chi2/dof counts the calibrated point's own (hidden-wall's revision 1 read
    1.96 with four counted where three were fitted)."""
    from calib_cli.discrepancy.point import fitted_parameters, model_and_theta as _model_and_theta

    (tmp_path / "invert").mkdir()
    sol = {"static_friction": 0.3, "rolling_friction": 0.2, "surface_energy": 0.4, "predicted_angle": 31.0}
    art.write_table(tmp_path / "invert" / "solution.parquet", pd.DataFrame([sol]))
    save_model(tmp_path, Model(("sliding_friction", "rolling_friction", "restitution", "cohesion"), 1))
    model, _ = _model_and_theta(tmp_path, ["restitution=0.3"])
    assert model.parameters == ["static_friction", "rolling_friction", "restitution", "surface_energy"]
    assert fitted_parameters(tmp_path, model) == ["static_friction", "rolling_friction", "surface_energy"]
    assert fitted_parameters(tmp_path, model, ["surface_energy=0.5"]) == ["static_friction", "rolling_friction"]
    # the posterior's point (calibrate): an effect's parameter at its neutral value is a draw of the model
    # without it (control-lab's answer, 98 % off), which fitted no surface energy
    (tmp_path / "calibrate").mkdir()
    point = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.0}
    art.write_table(tmp_path / "calibrate" / "point.parquet", pd.DataFrame([point]), {"model_revision": 1})
    assert fitted_parameters(tmp_path, model) == ["static_friction", "rolling_friction", "restitution"]
    art.write_table(tmp_path / "calibrate" / "point.parquet", pd.DataFrame([{**point, "surface_energy": 0.41}]),
                    {"model_revision": 1})
    assert fitted_parameters(tmp_path, model) == model.parameters
    # chi2/dof = sum z^2 / (C - min(C, p) * mean share): p is what enters
    res = residual_table(np.full(6, 30.0), np.full(6, 1.0), np.full(6, 10), np.full(6, 29.0), np.full(6, 1.0),
                         np.full(6, 8))
    share = float(res["measured_share"].mean())
    assert summary(res, 3)["chi2_dof"] == pytest.approx(float(np.sum(res["z"] ** 2)) / (6 - 3 * share))


TRUTH = ["--set", "static_friction=0.5", "--set", "rolling_friction=0.2", "--set", "restitution=0.3"]


def _lab(tmp_path, sizes, cylinders):
    lab_dir, run = tmp_path / "lab", tmp_path / "run"
    r = runner.invoke(app, ["synth-lab", "--out", str(lab_dir), *TRUTH, "--set", "surface_energy=0.5",
                            "--sizes", sizes, "--cylinders", cylinders, "--repeats", "2", "--preset", "smoke"])
    assert r.exit_code == 0, r.output
    assert (lab_dir / "truth.toml").is_file()
    r = runner.invoke(app, ["measure-angle", "--run", str(run), "--images", str(lab_dir), "--conditions",
                            str(lab_dir / "conditions.csv")])
    assert r.exit_code == 0, r.output
    return lab_dir, run


SIM = ["--preset", "smoke", "--repeats", "1", *TRUTH]


def test_loop_plumbing_on_tiny_heaps(tmp_path):
    """synth-lab -> measure-angle -> compare -> model add -> compare, end to end, on tiny heaps.
    (Their pile-to-pile scatter is several degrees: no ranking is asserted here.)"""
    lab_dir, run = _lab(tmp_path, "6-7,7-8", "40")
    assert len(list(lab_dir.glob("*.png"))) == 4
    r = runner.invoke(app, ["compare", "--run", str(run), *SIM])
    assert r.exit_code == 0, r.output
    res = art.read_table(run / "compare" / "residuals.parquet")
    for c in ["condition_id", "measured", "measured_sd", "simulated", "simulated_sd", "residual", "z", "fails"]:
        assert c in res.columns
    assert len(res) == 2
    hist = art.read_table(run / "compare" / "history.parquet")
    assert list(hist[["revision", "n_conditions"]].iloc[0]) == [0, 2]
    assert runner.invoke(app, ["model", "add", "cohesion", "--run", str(run)]).exit_code == 0
    r = runner.invoke(app, ["compare", "--run", str(run), *SIM, "--set", "surface_energy=0.5"])
    assert r.exit_code == 0, r.output
    hist = art.read_table(run / "compare" / "history.parquet")
    assert list(hist["revision"]) == [0, 1] and "cohesion" in hist["effects"].iloc[1]
    # a rerun of a revision replaces its row: the history stays one row per revision
    r = runner.invoke(app, ["compare", "--run", str(run), *SIM, "--set", "surface_energy=0.6"])
    assert r.exit_code == 0, r.output
    hist = art.read_table(run / "compare" / "history.parquet")
    assert list(hist["revision"]) == [0, 1] and hist["param_surface_energy"].iloc[1] == 0.6
    assert (run / "compare" / "history.png").is_file() and (run / "compare" / "residuals.png").is_file()
    lock = json.loads((run / "compare" / "rev1.lock.json").read_text())  # one commit: both under its lock
    assert {"residuals.parquet", "history.parquet", "history.png"} <= set(lock["outputs"])
    # the same comparison again is skipped, the run directory untouched; --force redoes it
    before = {p: p.read_bytes() for p in (run / "compare").iterdir()}
    r = runner.invoke(app, ["compare", "--run", str(run), *SIM, "--set", "surface_energy=0.6"])
    assert r.exit_code == 0 and "nothing to do" in r.output
    assert {p: p.read_bytes() for p in (run / "compare").iterdir()} == before
    r = runner.invoke(app, ["compare", "--run", str(run), *SIM, "--set", "surface_energy=0.6", "--force"])
    assert r.exit_code == 0 and "model vs measurements" in r.output
    # the run's [heap] setting stands for --preset: the same comparison, so nothing to do
    (run / "settings.toml").write_text('[heap]\npreset = "smoke"\n')
    r = runner.invoke(app, ["compare", "--run", str(run), "--repeats", "1", *TRUTH, "--set", "surface_energy=0.6"])
    assert r.exit_code == 0 and "nothing to do" in r.output, r.output


@pytest.mark.slow
def test_diagnose_end_to_end_on_tiny_heaps(tmp_path):
    _, run = _lab(tmp_path, "5-6,6-7,7-8", "40,48")
    assert runner.invoke(app, ["compare", "--run", str(run), *SIM]).exit_code == 0
    r = runner.invoke(app, ["diagnose", "--run", str(run), *SIM])
    assert r.exit_code == 0, r.output
    rank = art.read_table(run / "diagnose" / "ranking.parquet")
    assert list(rank.columns) == ["effect", "score", "p_value", "explained_fraction", "signature_p",
                                  "confounded_with", "confound", "verdict", "evidence"]
    # one heap a step (SIM) leaves the scatter unknown: no signature counts as resolved, so no
    # candidate can be called significant
    assert rank["signature_p"].isna().all() and "not resolved" in r.output
    assert not (rank["verdict"] == "significant").any()
    assert ((rank["verdict"] == "unresolved") == (rank["p_value"] < 0.05 / len(rank))).all()
    assert set(rank["effect"]) == set(EFFECTS) - {"sliding_friction", "rolling_friction", "restitution"}
    assert "simulations" in r.output  # the cost is printed before it starts


def test_diagnose_needs_more_conditions_than_parameters(tmp_path):
    run = tmp_path / "run"
    (run / "measure").mkdir(parents=True)
    art.write_table(run / "measure" / "conditions.parquet",
                    pd.DataFrame({"condition_id": ["A", "B"], "mean": [30.0, 31.0], "sd": [1.0, 1.0], "n": [3, 3]}))
    (run / "compare").mkdir()
    art.write_table(run / "compare" / "residuals.parquet",
                    pd.DataFrame({"condition_id": ["A", "B"], "residual": [1.0, 2.0], "uncertainty": [0.5, 0.5]}))
    r = runner.invoke(app, ["diagnose", "--run", str(run), "--set", "static_friction=0.4", "--set",
                            "rolling_friction=0.1", "--set", "restitution=0.3"])
    assert r.exit_code == 2 and "more conditions" in r.output


def test_synth_lab_is_a_stage_the_same_lab_asked_again_is_skipped(tmp_path, monkeypatch):
    """synth-lab's lock records what made the photographs: the same lab asked again is skipped without its
    heaps (a fresh clone of a committed lab has no heap cache) or its engine; another noise, or a photograph
    changed by hand, makes it again; a kill before the commit leaves the lab as it was."""
    import shutil

    import calib_cli.stages.lab as lab_mod

    lab = tmp_path / "lab"
    args = ["synth-lab", "--out", str(lab), *TRUTH, "--sizes", "6-8", "--cylinders", "40", "--repeats", "1",
            "--preset", "smoke"]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    before = {f.name: f.read_bytes() for f in lab.iterdir() if f.is_file()}
    assert "synth-lab.lock.json" in before and "d6-8_D40_r1.png" in before
    shutil.rmtree(lab / ".runs")

    def no_heaps(*a, **k):
        raise AssertionError("an up-to-date lab simulated a heap")

    monkeypatch.setattr(lab_mod, "run_campaign", no_heaps)
    monkeypatch.setattr(lab_mod, "_engine_ready", no_heaps)
    r = runner.invoke(app, args)
    assert r.exit_code == 0 and "up to date" in " ".join(r.output.split()), r.output  # the path may wrap the line
    assert {f.name: f.read_bytes() for f in lab.iterdir() if f.is_file()} == before
    for changed in (args + ["--noise", "7"], args + ["--force"]):
        r = runner.invoke(app, changed)  # out of date: it simulates (here: refused by the stand-in)
        assert r.exit_code != 0 and isinstance(r.exception, AssertionError)
    (lab / "d6-8_D40_r1.png").write_bytes(b"not the photograph")
    r = runner.invoke(app, args)
    assert r.exit_code != 0 and isinstance(r.exception, AssertionError)
    assert (lab / "d6-8_D40_r1.png").read_bytes() == b"not the photograph"  # nothing written before the commit
    monkeypatch.undo()
    r = runner.invoke(app, args)
    assert r.exit_code == 0 and "heaps (1 formed)" in " ".join(r.output.split()), r.output
    assert {f.name: f.read_bytes() for f in lab.iterdir() if f.is_file()} == before


def test_synth_lab_crosses_fill_heights(tmp_path):
    """--fills adds heap size as a condition variable (crossed with sizes and cylinders)."""
    lab = tmp_path / "lab"
    r = runner.invoke(app, ["synth-lab", "--out", str(lab), *TRUTH, "--sizes", "6-8", "--cylinders", "40",
                            "--fills", "40,60", "--repeats", "1", "--preset", "smoke"])
    assert r.exit_code == 0, r.output
    c = pd.read_csv(lab / "conditions.csv")
    assert list(c["condition_id"]) == ["d6-8_D40_H40", "d6-8_D40_H60"]
    assert list(c["fill_height_mm"]) == [40.0, 60.0] and set(c["cylinder_diameter_mm"]) == {40.0}
    r = runner.invoke(app, ["synth-lab", "--out", str(tmp_path / "bad"), *TRUTH, "--fills", "40,high"])
    assert r.exit_code != 0 and "--fills" in r.output and not (tmp_path / "bad").exists()


def test_floor_materials_are_conditions_end_to_end(tmp_path):
    """synth-lab --floor -> measure-angle -> compare: each floor's values travel with its condition
    into the simulations (and their cache keys); a floor named without values is warned about."""
    lab = tmp_path / "lab"
    r = runner.invoke(app, ["synth-lab", "--out", str(lab), *TRUTH, "--sizes", "6-8", "--cylinders", "50",
                            "--floor", "glass:static_friction=0.1,rolling_friction=0.02", "--floor",
                            "rubber:static_friction=0.9", "--repeats", "1", "--preset", "smoke"])
    assert r.exit_code == 0, r.output
    c = pd.read_csv(lab / "conditions.csv")
    assert list(c["condition_id"]) == ["d6-8_D50_glass", "d6-8_D50_rubber"] and list(c["floor"]) == ["glass", "rubber"]
    assert list(c["floor_static_friction"]) == [0.1, 0.9]
    assert c["floor_rolling_friction"].iloc[0] == 0.02 and np.isnan(c["floor_rolling_friction"].iloc[1])
    assert "floor_restitution" not in c.columns
    truth = art.read_table(lab / ".runs" / "simulate" / "results.parquet")
    assert list(truth["floor_static_friction"]) == [0.1, 0.9]
    run = tmp_path / "run"
    # every condition must give a floor column's value or none: rubber's rolling friction is blank
    r = runner.invoke(app, ["measure-angle", "--run", str(run), "--images", str(lab), "--conditions",
                            str(lab / "conditions.csv")])
    assert r.exit_code != 0 and "floor_rolling_friction" in r.output
    c.drop(columns="floor_rolling_friction").to_csv(lab / "conditions.csv", index=False)
    r = runner.invoke(app, ["measure-angle", "--run", str(run), "--images", str(lab), "--conditions",
                            str(lab / "conditions.csv")])
    assert r.exit_code == 0, r.output
    assert list(art.read_table(run / "measure" / "conditions.parquet")["floor_static_friction"]) == [0.1, 0.9]
    assert runner.invoke(app, ["compare", "--run", str(run), *SIM]).exit_code == 0
    sim = art.read_table(run / "simulate" / "results.parquet")
    assert sorted(zip(sim["floor"], sim["floor_static_friction"])) == [("glass", 0.1), ("rubber", 0.9)]
    # the labels alone are no physics: said so when they are all the conditions give
    c.drop(columns=["floor_rolling_friction", "floor_static_friction"]).to_csv(lab / "conditions.csv", index=False)
    r = runner.invoke(app, ["measure-angle", "--run", str(tmp_path / "run2"), "--images", str(lab), "--conditions",
                            str(lab / "conditions.csv")])
    assert r.exit_code == 0 and "glass, rubber" in r.output and "simulated as one floor" in r.output.replace("\n", " ")
    r = runner.invoke(app, ["synth-lab", "--out", str(tmp_path / "bad"), *TRUTH, "--floor", "steel:mu=0.3"])
    assert r.exit_code != 0 and "--floor" in r.output and not (tmp_path / "bad").exists()


CAND_BOUNDS = {"cohesion": (0.0, 3.0), "wall_friction": (-0.5, 0.5), "restitution": (-0.25, 0.5)}


def test_bounded_score_equals_the_free_score_when_no_bound_is_active():
    r = lab("cohesion", 1.0, 3)
    free = score_effects(r, U, J, G).set_index("effect")
    inf = np.full(2, np.inf)
    boxed = score_effects(r, U, J, G, bounds=(-inf, inf),
                          cand_bounds={k: (-np.inf, np.inf) for k in G}).set_index("effect")
    for k in G:
        assert boxed.loc[k, "score"] == pytest.approx(free.loc[k, "score"], rel=1e-9)
        assert boxed.loc[k, "p_value"] == pytest.approx(free.loc[k, "p_value"], rel=1e-9)


def test_a_misfit_the_parameters_cannot_reach_is_evidence_of_a_missing_effect():
    """Friction and rolling at the top of their ranges, every heap 1 deg steeper than the model
    (2 sigma per condition): the free projection explains the offset away with parameter values
    the calibration may not use; the bounded test keeps them in range and finds the effect."""
    at_top = (np.array([-0.3, -0.2]), np.zeros(2))
    found = free = false = 0
    for seed in range(200):
        noise = np.random.default_rng(seed).normal(0, U[0], 6)
        found += (score_effects(1.0 + noise, U, J, G, bounds=at_top, cand_bounds=CAND_BOUNDS)["p_value"]
                  < 0.05 / len(G)).any()
        free += (score_effects(1.0 + noise, U, J, G)["p_value"] < 0.05 / len(G)).any()
        false += (score_effects(noise, U, J, G, bounds=at_top, cand_bounds=CAND_BOUNDS)["p_value"]
                  < 0.05 / len(G)).any()
    assert found / 200 >= 0.95 and free / 200 <= 0.1
    assert false / 200 <= 0.08  # the control stays near nominal (chi-bar approximation)


def test_at_bounds():
    from calib_cli.discrepancy.stats import at_bounds

    ranges = {"static_friction": (0.3, 0.7), "rolling_friction": (0.1, 0.3), "restitution": (0.1, 0.5)}
    got = at_bounds({"static_friction": 0.63, "rolling_friction": 0.2999, "restitution": 0.1}, ranges)
    assert got == {"rolling_friction": "high", "restitution": "low"}


def test_a_parameter_stuck_at_its_bound_does_not_make_candidates_look_alike():
    """Two candidates that differ by what static friction (column 0) would absorb look alike
    while it is free to move, and differ once it is stuck at a bound and projected out no more
    (diagnose passes only the free parameters' columns)."""
    from calib_cli.discrepancy.stats import confounded

    G2 = {"a": G["cohesion"], "b": G["cohesion"] + 0.5 * J[:, 0]}
    assert ("a", "b") in confounded(U, J, G2)
    assert not confounded(U, J[:, [1]], G2)


@pytest.fixture(scope="module")
def hidden_effect_lab(tmp_path_factory):
    """`make hidden-effect` into a scratch run directory, once for the tests that read it. About
    38 min on 2 cores from nothing; where this checkout holds the sample run's simulation cache
    (not committed) it is copied in, and the heaps are reused through the cache, whose keys
    include the kernel's source hash."""
    return _make_lab(tmp_path_factory.mktemp("lab"), "hidden-effect", "hidden-effect")


@pytest.mark.slow
def test_hidden_cohesion_is_found_on_dem_heaps(hidden_effect_lab):
    """SPEC section 6's bars on DEM heaps of the `default` numerics, the loop calibrated in rounds:
    compare flags the starting model, diagnose finds cohesion significant (with capillary bridges,
    whose signature it cannot tell apart here, and no other), and once cohesion is added and the model
    calibrated again the misfit falls to the noise (chi2/dof below 2, about the 95 % point at its ~5
    degrees of freedom) and the posterior calls for cohesion with every interval holding its truth.
    Measured on the sample run: capillary p 3.3e-4, cohesion 3.7e-4; chi2/dof 3.34 -> 1.06, one
    condition failing at each revision, RMSE 2.49 -> 2.39 deg; Bayes factor of off < 0.066
    (docs/tutorial-hidden-effect.md)."""
    lab = hidden_effect_lab
    rank = art.read_table(lab / "diagnose" / "ranking.parquet").set_index("effect")
    assert rank.loc["cohesion", "p_value"] < 0.01 and rank.loc["cohesion", "signature_p"] < 0.01
    assert rank.loc["cohesion", "verdict"] == "significant"
    assert set(rank.index[rank["verdict"] == "significant"]) <= {"cohesion", "capillary"}
    hist = art.read_table(lab / "compare" / "history.parquet")
    assert list(hist["revision"]) == [0, 1]
    assert hist["n_fail"].iloc[0] >= 1 and hist["chi2_dof"].iloc[0] > 2.5
    assert hist["chi2_dof"].iloc[1] < min(2.0, 0.6 * hist["chi2_dof"].iloc[0])
    t = art.read_table(lab / "posterior" / "summary.parquet").set_index("parameter")
    assert t.loc["surface_energy", "bf_off"] < 0.1 and t["decided"].all()
    for p_, v in {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}.items():
        assert t.loc[p_, "q05"] <= v <= t.loc[p_, "q95"], p_


@pytest.mark.slow
def test_hidden_cohesion_is_measured(hidden_effect_lab):
    """The posterior of revision 1 calls for cohesion (Bayes factor of off below 0.1, stated because the
    surrogate is sure enough) and every 90 % interval holds the lab's truth; revision 1's calibration
    simulates at most 250 heaps. Sample run: surface energy 0.32-0.67 J/m2 (truth 0.6), Bayes factor
    < 0.066, 240 heaps."""
    t = art.read_table(hidden_effect_lab / "posterior" / "summary.parquet").set_index("parameter")
    truth = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}
    for p, v in truth.items():
        assert t.loc[p, "q05"] <= v <= t.loc[p, "q95"], (p, t.loc[p, "q05"], t.loc[p, "q95"])
    assert t.loc["surface_energy", "bf_off"] < 0.1 and t["decided"].all()
    rounds = art.read_table(hidden_effect_lab / "calibrate" / "rounds.parquet")
    assert rounds.loc[rounds["revision"] == 1, "calibration_heaps"].max() <= 250


def _make_lab(tmp_path, target, sample):
    """`make TARGET` into a scratch run directory, reusing the sample run's local simulation
    cache where this checkout holds it (not committed; keys include the kernel's source hash): its heaps'
    folders, not its results index, whose rows a calibration in rounds would count as heaps at hand
    from the start (it then chose other heaps than a run from nothing, and simulated them)."""
    import shutil
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    lab = tmp_path / target
    for sub in ("simulate/runs", "lab/.runs"):
        if (root / "sample_runs" / sample / sub).is_dir():
            shutil.copytree(root / "sample_runs" / sample / sub, lab / sub)
    var = {"hidden-effect": "LAB", "control-lab": "CTRL", "hidden-wall": "WALL", "hidden-floor": "FLOOR"}[target]
    r = subprocess.run(["make", "-C", str(root), target, f"{var}={lab}"], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return lab


@pytest.mark.slow
def test_control_lab_on_dem_heaps_finds_nothing(tmp_path):
    """`make control-lab`: the same six conditions with nothing hidden (the truth lies inside the
    starting model). compare flags at most one condition (the sample run: one, z = 2.7, chi2/dof 2.87)
    and diagnose finds no significant effect (Bonferroni over the candidates). 24 min on 2 cores with
    the hidden-effect lab's first rounds cached, ~4 min with every heap cached."""
    lab = _make_lab(tmp_path, "control-lab", "control-lab")
    hist = art.read_table(lab / "compare" / "history.parquet").set_index("revision")
    assert hist.loc[0, "n_fail"] <= 1
    rank = art.read_table(lab / "diagnose" / "ranking.parquet")
    assert (rank["p_value"] > 0.05 / len(rank)).all()
    # cohesion added all the same: favoured off (sample run: Bayes factor 68), and the answer, averaged over
    # cohesion on and off, holds every truth (rolling friction 0.144-0.162)
    t = art.read_table(lab / "posterior" / "summary.parquet").set_index("parameter")
    assert t.loc["surface_energy", "bf_off"] > 10
    for p_, v in {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.0}.items():
        assert t.loc[p_, "q05"] <= v <= t.loc[p_, "q95"], p_


@pytest.mark.slow
def test_control_lab_states_cohesion_off_and_revision_1_passes(tmp_path):
    """The control's answer is stated (the surrogates sure enough) and compare at its most probable draw
    fails no condition: the sample run since revision 1 learns from 4 side views (ratio 0.69, RMSE 0.88 deg;
    with one view a heap it failed one condition, and before that run the verdict was not stated)."""
    lab = _make_lab(tmp_path, "control-lab", "control-lab")
    t = art.read_table(lab / "posterior" / "summary.parquet")
    assert t["decided"].all()
    assert art.read_table(lab / "compare" / "history.parquet")["n_fail"].iloc[-1] == 0


@pytest.fixture(scope="module")
def hidden_wall_lab(tmp_path_factory):
    """`make hidden-wall` into a scratch run directory, once for the two tests that read it
    (31 min on 2 cores with the hidden-effect run's revision-0 BBD heaps cached; ~40 min from
    nothing, an estimate)."""
    return _make_lab(tmp_path_factory.mktemp("wall"), "hidden-wall", "hidden-wall")


@pytest.mark.slow
def test_slippery_walls_are_found_on_dem_heaps(hidden_wall_lab):
    """`make hidden-wall`: walls slipperier than the grains. compare fails the starting model (its
    residuals fall with the fill, the slippery floor's signature), diagnose ranks wall friction
    first with a resolved signature, and with it added and recalibrated the error falls to within
    1.5 x the noise and the wall friction comes back. Measured on the sample run (portable kernel,
    both revisions refined): 4 of 6 failing, chi2/dof 13.4; wall friction p 1.5e-6, signature
    p 5e-29; fill trend slope -0.06 deg/mm (p 0.076: six conditions rarely make it significant on
    their own; 0.0075 on the earlier draw); 1.63 -> 0.82 deg, x 0.50, 1.23 x the uncertainty of
    0.67 deg; wall friction 0.200 against 0.2."""
    lab = hidden_wall_lab
    hist = art.read_table(lab / "compare" / "history.parquet")
    assert hist["n_fail"].iloc[0] >= 2 and hist["chi2_dof"].iloc[0] > 5
    tr = art.read_table(lab / "diagnose" / "trends.parquet").set_index("variable")
    assert tr.loc["fill_height_mm", "slope"] < 0
    rank = art.read_table(lab / "diagnose" / "ranking.parquet")
    assert rank.iloc[0]["effect"] == "wall_friction" and rank.iloc[0]["p_value"] < 0.01
    assert rank.iloc[0]["verdict"] == "significant"
    assert list(hist["revision"]) == [0, 1]
    assert hist["rmse"].iloc[1] <= 0.6 * hist["rmse"].iloc[0]
    res = art.read_table(lab / "compare" / "residuals.parquet")
    assert hist["rmse"].iloc[1] < 1.5 * res["uncertainty"].mean()
    assert abs(art.read_table(lab / "invert" / "solution.parquet").iloc[0]["wall_static_friction"] - 0.2) < 0.05


@pytest.mark.slow
@pytest.mark.xfail(reason="on the sample run wall friction is first (p = 1.5e-6), but cohesion too passes the bar after "
                   "Bonferroni (p = 0.011 < 0.05/3), and revision 1 cut the RMSE by 1.99x (1.63 -> 0.82 deg), not 2x "
                   "(docs/changelog.md, the former tutorial section 7)", strict=False)
def test_diagnose_ranks_slippery_walls_first(hidden_wall_lab):
    """The issue's bar for `make hidden-wall`: diagnose ranks wall friction first and significant and
    nothing else, and the recalibration cuts the RMSE by a factor 2."""
    lab = hidden_wall_lab
    rank = art.read_table(lab / "diagnose" / "ranking.parquet")
    assert rank.iloc[0]["effect"] == "wall_friction" and rank.iloc[0]["p_value"] < 0.01
    assert (rank["p_value"].iloc[1:] > 0.05 / len(rank)).all()
    hist = art.read_table(lab / "compare" / "history.parquet")
    assert hist["rmse"].iloc[1] <= 0.5 * hist["rmse"].iloc[0]


@pytest.mark.slow
@pytest.mark.xfail(reason="not found: on the sample run revision 0 fails one condition and diagnose finds nothing "
                   "significant (best: cohesion p = 0.40; the floor p = 0.83, confounded with cohesion); adding the "
                   "floor anyway gives 1.46 -> 0.62 deg and no failure (docs/changelog.md, the former tutorial section 8)",
                   strict=False)
def test_rough_floor_is_found_on_dem_heaps(tmp_path):
    """`make hidden-floor`: the floor's rolling resistance 0.4 against the grains' 0.15, a third
    hidden effect whose central step was not tuned on any lab. The grains' rolling friction
    absorbs most of it; the bar: diagnose ranks it first and significant after Bonferroni over the
    candidates, and adding it removes any failure and lowers the error (met on the kernel before
    the JKR speed-up: 1.19 -> 0.88 deg; on the sample run now: not ranked first, though adding it
    gives 1.46 -> 0.62 deg with no failure). 39 min on 2 cores with the hidden-effect run's
    revision-0 BBD heaps cached (~47 min from nothing, an estimate)."""
    lab = _make_lab(tmp_path, "hidden-floor", "hidden-floor")
    rank = art.read_table(lab / "diagnose" / "ranking.parquet")
    assert rank.iloc[0]["effect"] == "wall_rolling" and rank.iloc[0]["p_value"] < 0.05 / len(rank)
    assert (rank["p_value"].iloc[1:] > 0.05 / len(rank)).all()
    hist = art.read_table(lab / "compare" / "history.parquet")
    assert list(hist["revision"]) == [0, 1] and hist["n_fail"].iloc[1] == 0
    assert hist["rmse"].iloc[1] < hist["rmse"].iloc[0]


def test_report_shows_the_discrepancy_loop(tmp_path):
    """`calib report` on a run that went through compare and diagnose (the committed hidden-effect
    sample run's tables) shows the error history, the residuals and the ranking with its verdicts,
    and says which model revision diagnose judged."""
    import shutil
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "sample_runs" / "hidden-effect"
    run = tmp_path / "run"
    for stage in ("compare", "diagnose"):
        shutil.copytree(src / stage, run / stage)
    r = runner.invoke(app, ["report", "--run", str(run)])
    assert r.exit_code == 0, r.output
    page = (run / "report.html").read_text()
    assert "Discrepancy loop" in page and 'src="compare/history.png"' in page
    assert "ranking.parquet (model revision 0)" in page and "residuals.parquet (model revision 1)" in page
    assert "not significant" in page and ">significant<" in page
    assert "Heaps in this run directory" not in page  # no simulate/ copied: nothing to say


def test_report_says_at_which_modulus_the_heaps_ran(tmp_path):
    """The report lists the run's heaps by what they were for, with the preset, shear modulus and
    contact laws of each group: a calibration holds only at its heaps' modulus."""
    import shutil
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "sample_runs"
    run = tmp_path / "run"
    shutil.copytree(src / "default-bbd-150mpa", run)
    rows = art.read_table(run / "simulate" / "results.parquet")
    extra = rows.head(2).assign(design="compare", shear_modulus=float("nan"), rolling_spring=1.0)
    art.write_table(run / "simulate" / "results.parquet", pd.concat([rows, extra], ignore_index=True))
    r = runner.invoke(app, ["report", "--run", str(run)])
    assert r.exit_code == 0, r.output
    page = (run / "report.html").read_text()
    assert "<li>bbd: 34 heap(s), preset default at 150 MPa</li>" in page
    assert "<li>compare: 2 heap(s), preset default at 5 MPa, rolling_spring 1</li>" in page


def _compare_seeds(run, *opts):
    r = runner.invoke(app, ["compare", "--run", str(run), *SIM, *opts])
    assert r.exit_code == 0, r.output
    from calib_cli.heaps.runner import load_results

    rows = load_results(run)
    return dict(zip(rows.loc[rows["design"] == "compare", "condition_id"], rows.loc[rows["design"] == "compare", "seed"]))


def test_compare_seeds_a_condition_by_its_values_not_its_row(tmp_path):
    """A condition's compare heaps are the same heaps whatever its row in the measured table (cached across a
    table that gains or reorders rows), unless --seeds table asks for the seeding by row that older runs used;
    a run keeps the seeding its comparison began with, and diagnose follows it."""
    from calib_cli.discrepancy.point import run_seeding

    _, run = _lab(tmp_path, "6-7,7-8", "40")
    conds = art.read_table(run / "measure" / "conditions.parquet")
    other = tmp_path / "reordered"
    (other / "measure").mkdir(parents=True)
    art.write_table(other / "measure" / "conditions.parquet", conds.iloc[::-1].reset_index(drop=True))
    assert run_seeding(run) == "condition"
    forward, backward = _compare_seeds(run), _compare_seeds(other)
    assert forward == backward and len(set(forward.values())) == 2
    assert art.read_provenance(run / "compare" / "residuals.parquet")["seeds"] == "condition"
    by_row = tmp_path / "by-row"
    (by_row / "measure").mkdir(parents=True)
    art.write_table(by_row / "measure" / "conditions.parquet", conds.iloc[::-1].reset_index(drop=True))
    rows = _compare_seeds(by_row, "--seeds", "table")
    assert all(rows[c] != forward[c] for c in forward)
    # silent provenance: a comparison seeded by row (every one made before --seeds); the run keeps it
    assert "seeds" not in art.read_provenance(by_row / "compare" / "residuals.parquet")
    assert run_seeding(by_row) == "table"
    r = runner.invoke(app, ["compare", "--run", str(run), *SIM, "--seeds", "rows"])
    assert r.exit_code == 2 and "--seeds must be one of condition, table" in r.output


def test_candidates_rank_by_p_value_a_one_sided_one_above_a_larger_two_sided_score():
    """A one-sided candidate's p is halved (chi-bar mixture): with LR 3.0 (p 0.042) it ranks above a two-sided
    one with LR 3.5 (p 0.061), which the data support less."""
    from scipy import stats as st

    r = np.array([np.sqrt(3.5), np.sqrt(3.0), 0.0, 0.0])
    G2 = {"two_sided": np.array([1.0, 0.0, 0.0, 0.0]), "one_sided": np.array([0.0, 1.0, 0.0, 0.0])}
    rank = score_effects(r, np.ones(4), np.zeros((4, 0)), G2,
                         cand_bounds={"one_sided": (0.0, np.inf), "two_sided": (-np.inf, np.inf)})
    assert list(rank["effect"]) == ["one_sided", "two_sided"]
    assert rank["score"].tolist() == pytest.approx([3.0, 3.5])
    assert rank["p_value"].tolist() == pytest.approx([0.5 * st.chi2.sf(3.0, 1), st.chi2.sf(3.5, 1)])


def test_a_trend_is_quoted_as_observed_only_where_it_is_significant():
    from calib_cli.stages.diagnose import observed_trend

    tr = pd.DataFrame({"variable": ["particle_d_min_mm", "fill_height_mm"], "slope": [-1.0, 0.2],
                       "p_value": [0.152, 0.6], "r": [-0.6, 0.2]})
    assert observed_trend(tr, 0.05) is None  # the hidden-cohesion lab's: the likeliest, p = 0.152
    assert observed_trend(tr.assign(p_value=[0.03, 0.6]), 0.05) is None  # not below 0.05 / 2 variables
    assert observed_trend(tr.assign(p_value=[0.01, 0.6]), 0.05)["variable"] == "particle_d_min_mm"
    assert observed_trend(tr.iloc[:0], 0.05) is None


def test_a_measured_condition_s_seed_is_its_name_and_values_not_its_row():
    """Two conditions of the same values under two names (a rig measured twice) draw heaps of their own; a
    condition's seed does not move with its row (compare's --seeds condition)."""
    from calib_cli.dem.heap import HeapCondition
    from calib_cli.heaps.inputs import measured_seed

    c = HeapCondition(4.0, 5.0, 40.0, 75.0, 50.0)
    assert measured_seed(0, "A", c, 0) == measured_seed(0, "A", c, 0)
    assert len({measured_seed(0, "A", c, 0), measured_seed(0, "A-again", c, 0), measured_seed(0, "A", c, 1),
                measured_seed(0, "A", HeapCondition(5.0, 6.0, 40.0, 75.0, 50.0), 0)}) == 4


def test_a_comparison_whose_seeding_cannot_be_read_asks_for_seeds(tmp_path):
    """compare and diagnose follow the seeding compare's residuals record; where that cannot be read (not
    calib's provenance, a value it never writes) they say to give --seeds, which overrides it, rather than
    sending the user to rerun compare, which would stop at the same file."""
    from calib_cli.discrepancy.point import run_seeding

    (tmp_path / "compare").mkdir()
    res = tmp_path / "compare" / "residuals.parquet"
    res.write_bytes(b"not parquet")
    with pytest.raises(CalibError, match="give --seeds condition or --seeds table"):
        run_seeding(tmp_path)
    art.write_table(res, pd.DataFrame({"a": [1.0]}), {"seeds": "rows"})
    with pytest.raises(CalibError, match="'rows', which is none of condition, table: give --seeds"):
        run_seeding(tmp_path)
    art.write_table(res, pd.DataFrame({"a": [1.0]}), {"seeds": "condition"})
    assert run_seeding(tmp_path) == "condition"


def test_diagnose_seeds_its_heaps_as_compare_seeded_its_residuals(tmp_path, monkeypatch):
    """diagnose's base point is compare's own heaps only if both seed alike: by default it follows the seeding
    compare's residuals record (silent: by row, as every comparison before --seeds), and --seeds overrides."""
    from calib_cli.stages import diagnose as diag

    ids = ["A", "B", "C", "D"]
    (tmp_path / "measure").mkdir()
    art.write_table(tmp_path / "measure" / "conditions.parquet",
                    pd.DataFrame({"condition_id": ids, "mean": [30.0, 31, 32, 33], "sd": [1.0] * 4, "n": [5] * 4,
                                  "particle_d_min_mm": [4.0, 5, 4, 5], "particle_d_max_mm": [5.0, 6, 5, 6]}))
    (tmp_path / "compare").mkdir()
    seen = []

    class Stop(Exception):
        pass

    def signatures(*a, seeds, **k):
        seen.append(seeds)
        raise Stop

    monkeypatch.setattr(diag, "signatures", signatures)
    given = ["static_friction=0.4", "rolling_friction=0.1", "restitution=0.3"]
    residuals = pd.DataFrame({"condition_id": ids, "residual": [1.0, 2, 3, 4], "uncertainty": [0.5] * 4})
    for prov, option, want in [({}, None, "table"), ({"seeds": "condition"}, None, "measured"),
                               ({}, "condition", "measured")]:
        art.write_table(tmp_path / "compare" / "residuals.parquet", residuals, prov)
        with pytest.raises(Stop):
            diag.diagnose(tmp_path, given, preset="smoke", seeds=option, force=True)
        assert seen[-1] == want


def test_diagnose_refuses_residuals_of_another_point_or_another_measurement(tmp_path):
    """compare's residuals name the point they were simulated at: diagnose at another (another --set) or after
    the lab measured again under the same condition names would set its sensitivities against another misfit."""
    from calib_cli.stages.diagnose import current_residuals

    src = Path(__file__).resolve().parents[1] / "sample_runs" / "hidden-effect"
    run = tmp_path / "he"
    for sub in ("compare", "measure"):
        shutil.copytree(src / sub, run / sub)
    model, theta = Model(("sliding_friction", "rolling_friction", "restitution", "cohesion"), 1), \
        {"static_friction": 0.456, "rolling_friction": 0.123, "restitution": 0.22, "surface_energy": 0.438}
    path = run / "compare" / "residuals.parquet"
    prov = art.read_provenance(path)
    for lock in (run / "compare").glob("*.lock.json"):  # the edits stand in for what compare would write
        lock.unlink()
    art.write_table(path, art.read_table(path), {**prov, "theta": theta})
    conds = art.read_table(run / "measure" / "conditions.parquet")
    assert len(current_residuals(run, model, conds, theta)) == 6
    with pytest.raises(CalibError, match=r"at another point than this one \(static_friction 0.456 against 0.4\)"):
        current_residuals(run, model, conds, {**theta, "static_friction": 0.4})
    again = conds.assign(mean=conds["mean"] + np.r_[0.0, 0.5, 0, 0, 0, 0])
    with pytest.raises(CalibError, match=f"other measured means .* at {conds['condition_id'].iloc[1]}:"):
        current_residuals(run, model, again, theta)
