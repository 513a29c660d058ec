"""calib calibrate: the rounds' designs (space-filling, then where the surrogates are unsure about the
posterior), the stop rule, the resumable stage and its artefacts, on a stand-in heap whose truth is
known (calib_cli.posterior.adaptive, calib_cli.stages.calibrate)."""

from __future__ import annotations

import io
import shutil

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.dem.heap import condition_dict
from calib_cli.errors import CalibError
from calib_cli.heaps.index import append_index
from calib_cli.posterior.adaptive import acquire, first_design, interval_shift, reference_round, stop_reason
from calib_cli.posterior.gp import GPSurrogate

QUIET = {"say": lambda *a, **k: None}
TRUTH = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3}
FILLS = (50.0, 75.0, 100.0)


def stand_in(p, fill):
    """A smooth stand-in for a heap's mean angle over the default model's parameters and the fill, each
    parameter's sensitivity changing differently with the fill (so three fills pin all three)."""
    return (18 + 20 * p["static_friction"] + 40 * p["rolling_friction"] * fill / 75
            - 6 * p["restitution"] * 75 / fill + 0.04 * fill)


def _fake_campaign(calls, stands=lambda p: False, angle=None, views=False):
    """A campaign that 'simulates' each request as the stand-in plus a pile's scatter of 1 deg, seeded by
    the request, and writes its rows to the run's index as the real one does; where ``stands``, the fill
    stands as a column (no angle). ``views``: each row also records 4 side views' mean, a heap's own scatter
    of 0.6 deg and each view's of 0.8 (one view: 1 deg)."""
    def run_campaign(requests, run_dir, workers=1, on_done=None, dask=None, **kw):
        rows = []
        for q in requests:
            rng = np.random.default_rng(q.seed)
            cond = condition_dict(q.condition)
            column = stands(q.params)
            mean = (angle or stand_in)(q.params, cond["fill_height_mm"])
            row = {"run_hash": q.hash, "design": q.design, "run_id": q.run_id, "repeat": q.repeat, "seed": q.seed,
                   "preset": q.preset, "condition_id": q.condition_id, "model": q.model, "engine": q.engine,
                   **q.params, **cond, "status": "column" if column else "ok",
                   "repose_angle": np.nan if column else mean + rng.normal(0, 1.0),
                   "source": q.source}
            if views:
                seen = mean + rng.normal(0, 0.6) + rng.normal(0, 0.8, 4)
                row.update(repose_angle=np.nan if column else seen[0], angle_views=np.nan if column else seen.mean(),
                           side_views=0 if column else 4)
            rows.append(row)
            if on_done:
                on_done(q, row)
        calls.append(len(requests))
        append_index(run_dir, rows)
        return pd.DataFrame(rows)
    return run_campaign


@pytest.fixture
def lab(tmp_path, monkeypatch):
    """A run directory measured at three fills at the truth (ten piles of sd 1 each), the default model."""
    run = tmp_path / "run"
    meas = pd.DataFrame({"condition_id": [f"H{h:g}" for h in FILLS], "fill_height_mm": FILLS,
                         "particle_d_min_mm": 4.0, "particle_d_max_mm": 5.0, "cylinder_diameter_mm": 40.0,
                         "mean": [stand_in(TRUTH, h) for h in FILLS], "sd": 1.0, "n": 10})
    art.write_table(run / "measure" / "conditions.parquet", meas)
    calls = []
    monkeypatch.setattr("calib_cli.stages.calibrate.run_campaign", _fake_campaign(calls))
    return run, calls


# ------------------------------------------------------------------ the designs
def test_round_0_fills_the_prior_box_and_shares_the_conditions_evenly():
    bounds = {"a": (0.0, 1.0), "b": (0.0, 3.0)}
    d = first_design(bounds, ["c1", "c2", "c3"], 30, seed=1)
    assert len(d) == 30 and sorted(d["condition_id"].value_counts().tolist()) == [10, 10, 10]
    for p, (lo, hi) in bounds.items():  # a Latin hypercube: one point in each thirtieth of each range
        assert sorted(np.floor((d[p] - lo) / (hi - lo) * 30).astype(int)) == list(range(30))
    assert first_design(bounds, ["c1"], 30, seed=1).equals(first_design(bounds, ["c1"], 30, seed=1))
    with pytest.raises(CalibError, match="at least 2"):
        first_design(bounds, ["c1"], 1)


def _gp_on(points: np.ndarray) -> GPSurrogate:
    rows = pd.DataFrame({"a": points[:, 0], "b": points[:, 1], "fill_height_mm": 75.0,
                         "repose_angle": 30 + 5 * points[:, 0] + np.random.default_rng(0).normal(0, 0.5, len(points))})
    gp = GPSurrogate(["a", "b"], ["fill_height_mm"], {"a": (0.0, 1.0), "b": (0.0, 1.0)})
    return gp.fit(rows, rows["repose_angle"])


def test_the_variance_rule_goes_where_the_posterior_lies_and_the_heaps_do_not():
    """Heaps cover only a < 0.5; the posterior lies at a ~ 0.8: the chosen points are among its draws, and
    the greedy batch spreads instead of stacking on one point."""
    rng = np.random.default_rng(1)
    gp = _gp_on(rng.random((40, 2)) * [0.5, 1.0])
    samples = pd.DataFrame({"a": rng.normal(0.8, 0.05, 500), "b": rng.random(500)})
    measured = pd.DataFrame({"condition_id": ["H75"], "fill_height_mm": [75.0], "mean": [34.0], "sd": 1.0, "n": 10})
    v = np.array([0.1])
    for rule in ("variance", "max-sd", "draws"):
        d = acquire([(gp, v)], samples, measured, 6, repeats=2, rule=rule, seed=0)
        assert len(d) == 6 and (d["condition_id"] == "H75").all()
        assert d["a"].between(0.6, 1.0).all(), rule
        assert d[["a", "b"]].drop_duplicates().shape[0] == 6, rule
    spread = acquire([(gp, v)], samples, measured, 6, rule="variance", seed=0)["b"]
    assert np.ptp(spread) > 0.4  # not six heaps at the same b
    with pytest.raises(CalibError, match="--rule must be one of"):
        acquire([(gp, v)], samples, measured, 6, rule="best")


def test_a_draw_the_chain_repeated_is_one_pair_not_two():
    """A chain's draws repeat where it rejected a move: two picks of one (draw, condition) would be one cached
    heap that the budget pays for twice, so each pair of a round is a different point."""
    rng = np.random.default_rng(1)
    gp = _gp_on(rng.random((40, 2)) * [0.5, 1.0])
    few = pd.DataFrame({"a": rng.normal(0.8, 0.05, 8), "b": rng.random(8)})
    samples = few.iloc[rng.integers(0, 8, 500)].reset_index(drop=True)  # 8 points, each drawn ~60 times
    measured = pd.DataFrame({"condition_id": ["H75"], "fill_height_mm": [75.0], "mean": [34.0], "sd": 1.0, "n": 10})
    for rule in ("variance", "max-sd", "draws"):
        d = acquire([(gp, np.array([0.1]))], samples, measured, 8, repeats=2, rule=rule, seed=0)
        assert len(d) == 8 and not d.duplicated().any(), rule
    more = acquire([(gp, np.array([0.1]))], samples, measured, 12, repeats=2, rule="variance", seed=0)
    assert len(more) == 8 and not more.duplicated().any()  # 8 distinct points: a twin never fills the round


def test_the_stop_rule_needs_stable_intervals_verdicts_and_a_sure_surrogate():
    t0 = pd.DataFrame({"parameter": ["a"], "q05": [0.2], "q95": [0.6], "low": [0.0], "high": [1.0]})
    t1 = t0.assign(q05=0.23, q95=0.58)
    assert interval_shift(t0, t1) == pytest.approx(0.03)
    assert "stable" in stop_reason(t0, t1, ["on"], ["on"], True)
    assert stop_reason(t0, t1, ["open"], ["on"], True) == ""  # a verdict changed
    assert stop_reason(t0, t1, ["on"], ["on"], False) == ""  # the surrogate is unsure
    assert stop_reason(t0, t0.assign(q95=0.7), [], [], True) == ""  # moved by 10 % of the range
    assert stop_reason(None, t1, [], [], True) == ""


def test_the_stop_rule_looks_back_a_default_batch_of_heaps_whatever_the_rounds_size():
    """Half-size rounds each move the intervals less: compared round by round they would stop sooner."""
    from calib_cli.stages.calibrate import Plan, Round, _stop

    assert reference_round([72, 96, 120], 144, 24) == 2  # the default batch: the previous round
    assert reference_round([72, 84, 96, 108], 120, 24) == 2  # rounds of 12: two back
    assert reference_round([72, 96], 106, 24) == 0  # a round the budget cut short
    assert reference_round([72], 84, 24) is None
    table = pd.DataFrame({"parameter": ["a"], "q05": [0.2], "q95": [0.6], "low": [0.0], "high": [1.0],
                          "decided": [True], "bf_off": [np.nan], "bf_upper": [False]})

    def rnd(k, spent, q95):
        return Round(k, "variance", None, table.assign(q95=q95), None, None, {}, spent, spent=spent)

    # each round of 12 moves an end by 4 % of the range: stable round by round, not over 24 heaps
    halves = [rnd(0, 72, 0.60), rnd(1, 84, 0.64), rnd(2, 96, 0.68)]
    assert _stop(halves, Plan(250, 72, 12, span=24), halves[-1]) == ""
    assert "stable" in _stop(halves, Plan(250, 72, 12, span=12), halves[-1])
    still = halves + [rnd(3, 108, 0.69), rnd(4, 120, 0.70)]
    assert "since round 2, 24 heaps before" in _stop(still, Plan(250, 72, 12, span=24), still[-1])
    full = [rnd(0, 72, 0.60), rnd(1, 96, 0.64)]
    assert "since the previous round" in _stop(full, Plan(250, 72, 24, span=24), full[-1])


# ------------------------------------------------------------------ the stage
def test_calibrate_runs_rounds_until_stable_and_writes_its_artefacts(lab):
    from calib_cli.stages.calibrate import calibrate

    run, calls = lab
    r = calibrate(run, budget=200, first=60, batch=20, walkers=16, steps=400, **QUIET)
    rounds = r.rounds
    assert calls[0] == 60 and all(c == 20 for c in calls[1:])
    assert rounds["round"].max() + 1 == len(calls) and r.stop
    assert set(rounds["rule"]) <= {"space-filling", "variance"}
    t = r.table.set_index("parameter")
    for p, v in TRUTH.items():
        assert t.loc[p, "q05"] <= v <= t.loc[p, "q95"], p
    assert t.loc["rolling_friction", "rel_width"] < 0.5  # three fills pin it to a third of its range
    ratio = rounds.groupby("round")["surrogate_ratio"].first()
    assert ratio.iloc[-1] <= 1.0 < ratio.iloc[0]  # the rounds taught the surrogate until a verdict can stand
    assert "stable" in r.stop and t["decided"].all()
    assert {"rounds.parquet", "rounds.png", "point.parquet"} <= {p.name for p in (run / "calibrate").iterdir()}
    point = art.read_table(run / "calibrate" / "point.parquet")
    assert list(point.columns) == list(TRUTH) and art.read_provenance(run / "calibrate" / "point.parquet")[
        "model_revision"] == 0
    surr = art.read_table(run / "posterior" / "surrogates.parquet")
    assert set(surr["surrogate"]) == {"gp", "rsm", "bp"}
    rows = pd.read_parquet(run / "simulate" / "results.parquet")
    assert len(rows) == sum(calls) and (rows["design"] == "calibrate").all()
    # a rerun reads every round back and simulates nothing
    again = calibrate(run, budget=200, first=60, batch=20, walkers=16, steps=400, **QUIET)
    assert again.skipped and len(calls) == rounds["round"].max() + 1


def test_with_two_workers_the_held_out_scores_run_beside_the_chains_and_come_out_the_same(lab, tmp_path, monkeypatch):
    """More than one worker: each posterior's held-out scores are computed in a second process while the chains
    run (calib_cli.pool.beside), and every table is the one a single worker writes, bit for bit."""
    from calib_cli import pool
    from calib_cli.stages.calibrate import calibrate

    run, calls = lab
    other = tmp_path / "one"
    shutil.copytree(run, other)
    used, real = [], pool.beside

    def counted(fn, *args, spawn=True):
        if spawn:
            used.append(fn.__name__)
        return real(fn, *args, spawn=spawn)

    monkeypatch.setattr(pool, "beside", counted)
    kw = dict(budget=60, first=60, walkers=16, steps=200, **QUIET)
    calibrate(run, workers=2, **kw)
    assert used == ["held_out", "held_out"]  # round 0's posterior and the answer's
    calibrate(other, workers=1, **kw)
    assert len(used) == 2  # one worker: scored in this process
    for f in ("posterior/surrogates.parquet", "posterior/summary.parquet", "posterior/samples.parquet",
              "calibrate/rev0/round-00/surrogates.parquet", "calibrate/rounds.parquet"):
        assert art.read_table(run / f).equals(art.read_table(other / f)), f


def test_with_side_views_the_surrogates_learn_each_heap_from_their_mean_and_only_then(lab, monkeypatch):
    """--side-views: the rounds' surrogates learn from the heaps' views' mean (their provenance names the share
    of one view's variance it keeps, and the rounds' lock the option); without it, from one view, under the
    settings the rounds were locked with before views were an option."""
    import json

    from calib_cli.model import DEFAULT_EFFECTS, Model
    from calib_cli.stages.calibrate import Plan, calibrate

    run, calls = lab
    monkeypatch.setattr("calib_cli.stages.calibrate.run_campaign", _fake_campaign(calls, views=True))
    kw = dict(budget=60, first=60, walkers=16, steps=200, **QUIET)
    calibrate(run, views=True, **kw)
    meta = art.read_provenance(run / "calibrate" / "rev0" / "round-00" / "summary.parquet")
    assert 0.3 < meta["view_share"] < 0.9, meta.get("view_share")  # (0.6^2 + 0.8^2 / 4) / 1: 0.52
    lock = run / "calibrate" / "rev0-round-00.lock.json"
    with_views = json.loads(lock.read_text())["settings_hash"]
    calibrate(run, force=True, **kw)
    meta = art.read_provenance(run / "calibrate" / "rev0" / "round-00" / "summary.parquet")
    assert "view_share" not in meta and json.loads(lock.read_text())["settings_hash"] != with_views
    # the option enters a round's settings only where given: rounds locked before it stay up to date
    assert "views" not in Plan(60, 60, 20).round_settings(Model(DEFAULT_EFFECTS)) and Plan(60, 60, 20, views=True).round_settings(
        Model(DEFAULT_EFFECTS))["views"] is True


def test_a_stopped_calibration_goes_on_from_its_last_finished_round(lab, tmp_path):
    """Killed after round 1's heaps (before its posterior): the rerun reads round 0 and its design, finds
    round 1's heaps cached and ends where an unbroken run ends."""
    from calib_cli.stages import calibrate as cal

    run, calls = lab
    real = cal._round_posterior
    seen = []

    def dies_at_round_1(run_, model, k, *a, **kw):
        if k == 1 and not seen:
            seen.append(k)
            raise KeyboardInterrupt
        return real(run_, model, k, *a, **kw)

    cal._round_posterior = dies_at_round_1
    try:
        with pytest.raises(KeyboardInterrupt):
            cal.calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=400, **QUIET)
        n_heaps = len(pd.read_parquet(run / "simulate" / "results.parquet"))
        assert n_heaps == 80 and not (run / "calibrate" / "rounds.parquet").exists()
        r = cal.calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=400, **QUIET)
    finally:
        cal._round_posterior = real
    assert len(pd.read_parquet(run / "simulate" / "results.parquet").drop_duplicates("run_hash")) == 100
    assert r.rounds["calibration_heaps"].max() == 100 and "budget" in r.stop


def _as_compare(rows: pd.DataFrame, tag: str) -> pd.DataFrame:
    """The rows as if compare had simulated them: another design, other heaps."""
    return rows.assign(design="compare", run_hash=[f"{tag}{i}" for i in range(len(rows))], run_id=1)


def test_heaps_added_after_a_calibration_leave_it_as_it_went_and_those_before_it_join_it(lab):
    """compare's heaps, added after the calibration, do not make a rerun recalibrate (a pipeline run twice
    does nothing the second time); the heaps at hand when a calibration begins are recorded and learnt from."""
    from calib_cli.stages.calibrate import calibrate

    run, calls = lab
    r = calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=300, **QUIET)
    rows = pd.read_parquet(run / "simulate" / "results.parquet")
    assert art.read_table(run / "calibrate" / "rev0" / "round-00" / "reused.parquet").empty
    append_index(run, _as_compare(rows.head(24), "late").to_dict("records"))
    n = len(calls)
    again = calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=300, **QUIET)
    assert again.skipped and len(calls) == n
    other = tmp_run(run)
    append_index(other, _as_compare(rows.head(24), "early").to_dict("records"))
    r2 = calibrate(other, budget=100, first=60, batch=20, walkers=16, steps=300, **QUIET)
    reused = art.read_table(other / "calibrate" / "rev0" / "round-00" / "reused.parquet")
    assert len(reused) == 24 and (reused["design"] == "compare").all()
    assert r2.rounds["heaps"].iloc[0] == r.rounds["heaps"].iloc[0] + 24
    # --force begins again from every heap at hand: the late compare heaps join round 0
    forced = calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=300, force=True, **QUIET)
    assert len(art.read_table(run / "calibrate" / "rev0" / "round-00" / "reused.parquet")) == 24
    assert forced.rounds["heaps"].iloc[0] == r.rounds["heaps"].iloc[0] + 24


def test_a_round_learns_only_from_its_own_designs_not_another_calibrations_heaps(lab):
    """Heaps labelled as this model's calibration but not of its designs (another --seed's, or of a round
    designed again at a smaller budget after a kill) share its run ids; they stay out of its rounds."""
    from calib_cli.model import load_model
    from calib_cli.posterior.evidence import model_rows
    from calib_cli.stages import calibrate as cal

    run, _ = lab
    cal.calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=300, **QUIET)
    model = load_model(run)
    before = {k: cal._until_round(run, model_rows(run, model), model, k) for k in (0, 1, None)}
    rows = pd.read_parquet(run / "simulate" / "results.parquet")
    stray = rows[rows["run_id"] < 1010].assign(run_hash=lambda r: "stray" + r["run_hash"],
                                               static_friction=lambda r: r["static_friction"] + 0.01)
    append_index(run, stray.to_dict("records"))
    assert len(model_rows(run, model)) == len(rows) + len(stray)
    for k, b in before.items():
        now = cal._until_round(run, model_rows(run, model), model, k)
        assert set(now["run_hash"]) == set(b["run_hash"]), k
    assert len(before[0]) == 60 and len(before[None]) == 100


def test_a_calibration_designed_anew_leaves_no_later_round_of_the_one_before(lab):
    """Three rounds, then the same calibration with another seed and a budget for two: round 0 is designed
    anew, so the first run's round 2 (its folder and locks) goes, and the whole calibration's heaps are the
    second run's own."""
    from calib_cli.model import load_model
    from calib_cli.posterior.evidence import model_rows
    from calib_cli.stages import calibrate as cal

    run, _ = lab
    cal.calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=300, **QUIET)
    assert (run / "calibrate" / "rev0" / "round-02").is_dir()
    cal.calibrate(run, budget=80, first=60, batch=20, walkers=16, steps=300, seed=1, **QUIET)
    assert not (run / "calibrate" / "rev0" / "round-02").exists()
    assert not list((run / "calibrate").glob("rev0-round-02*"))
    model = load_model(run)
    assert len(cal._until_round(run, model_rows(run, model), model, None)) == 80


def test_a_calibration_with_other_options_stopped_on_the_way_leaves_the_answer_before_it(lab, monkeypatch):
    """Another --seed, killed at its round 1: the first calibration's answer (posterior/, rounds, point) is as it
    was and its round 2 is still on disk; its options given again find it, simulate no new heap and answer
    as before."""
    from calib_cli.stages import calibrate as cal

    run, calls = lab
    opts = dict(budget=100, first=60, batch=20, walkers=16, steps=300, **QUIET)
    cal.calibrate(run, **opts)
    answer = ["posterior/summary.parquet", "posterior/samples.parquet", "calibrate/rounds.parquet",
              "calibrate/point.parquet"]
    before = {f: (run / f).read_bytes() for f in answer}
    round_2 = run / "calibrate" / "rev0" / "round-02" / "design.parquet"
    made = round_2.stat().st_mtime_ns
    real = cal._round_posterior

    def dies_at_round_1(run_, model, k, *a, **kw):
        if k == 1:
            raise KeyboardInterrupt
        return real(run_, model, k, *a, **kw)

    monkeypatch.setattr(cal, "_round_posterior", dies_at_round_1)
    with pytest.raises(KeyboardInterrupt):
        cal.calibrate(run, seed=1, **opts)
    assert {f: (run / f).read_bytes() for f in answer} == before and round_2.is_file()
    monkeypatch.setattr(cal, "_round_posterior", real)
    had = set(pd.read_parquet(run / "simulate" / "results.parquet")["run_hash"])
    asked = []
    monkeypatch.setattr(cal, "run_campaign", lambda requests, *a, **kw: (asked.extend(q.hash for q in requests),
                                                                          _fake_campaign(calls)(requests, *a, **kw))[1])
    again = cal.calibrate(run, **opts)
    assert set(asked) <= had
    assert round_2.stat().st_mtime_ns == made
    pd.testing.assert_frame_equal(again.rounds, art.read_table(run / "calibrate" / "rounds.parquet"))
    for f in answer[:1] + answer[2:]:
        pd.testing.assert_frame_equal(pd.read_parquet(run / f), pd.read_parquet(io.BytesIO(before[f])), obj=f)


def test_a_round_of_an_odd_number_of_heaps_says_it_simulates_whole_points(lab):
    """--first 61 with 2 piles a point makes 60 heaps (30 points): said, not done in silence."""
    from calib_cli.stages import calibrate as cal

    run, calls = lab
    said = []
    cal.calibrate(run, budget=81, first=61, batch=21, walkers=16, steps=300, say=lambda m, **k: said.append(m))
    assert "note: --first 61 makes 60 and --batch 21 makes 20 heaps, whole points of 2 piles (--repeats)" in said
    assert calls[0] == 60


def test_heaps_of_another_preset_are_refused_before_any_runs(lab):
    """The model's heaps at hand were simulated at the default preset: a calibration at another one would mix
    two setups in one surrogate, refused before round 0 spends its heaps (not after them)."""
    from calib_cli.stages.calibrate import calibrate

    run, calls = lab
    calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=300, **QUIET)
    n = len(calls)
    with pytest.raises(CalibError, match="simulated at preset default at 5 MPa, and this calibration would "
                                         "simulate at preset smoke at 5 MPa"):
        calibrate(run, budget=100, first=60, batch=20, walkers=16, steps=300, preset="smoke", force=True, **QUIET)
    assert len(calls) == n


def test_heaps_that_form_no_heap_are_made_up_by_a_space_filling_top_up(lab, monkeypatch):
    """A fifth of the prior box stands as a column: round 0's 40 heaps leave the surrogate short of its 40
    (10 per input), so round 1 adds space-filling heaps before any posterior; a budget that cannot make
    them up is refused in words."""
    from calib_cli.stages import calibrate as cal

    run, calls = lab
    monkeypatch.setattr(cal, "run_campaign", _fake_campaign(calls, lambda p: p["static_friction"] > 0.41))
    said = []
    r = cal.calibrate(run, budget=80, first=40, batch=20, walkers=16, steps=300, say=lambda m, **k: said.append(m))
    assert calls[0] == 40 and calls[1] < 20 and r.rounds["round"].min() == 1
    assert any("another space-filling round" in m for m in said)
    assert r.rounds["calibration_heaps"].iloc[0] == calls[0] + calls[1]
    with pytest.raises(CalibError, match="raise --budget"):
        cal.calibrate(tmp_run(run), budget=42, first=40, walkers=16, steps=300, **QUIET)


def tmp_run(run):
    other = run.parent / "other"
    shutil.copytree(run / "measure", other / "measure")
    return other


def test_calibrate_refuses_a_budget_too_small_an_unknown_rule_and_an_unusable_sampler_or_cluster(lab):
    from calib_cli.stages.calibrate import calibrate

    run, _ = lab
    with pytest.raises(CalibError, match="--budget 3 leaves round 0 fewer than 2 points"):
        calibrate(run, budget=3, **QUIET)
    with pytest.raises(CalibError, match="--rule must be one of"):
        calibrate(run, rule="best", **QUIET)
    # refused before round 0 is designed or a heap runs, not when the first posterior is fitted
    with pytest.raises(CalibError, match="emcee needs at least"):
        calibrate(run, walkers=2, **QUIET)
    with pytest.raises(CalibError, match="--batch 3 with --repeats 2 gives a later round fewer than 2 points"):
        calibrate(run, batch=3, **QUIET)
    with pytest.raises(CalibError, match="at most 999 points"):  # a round's run ids are its thousand
        calibrate(run, first=2000, budget=3000, **QUIET)
    with pytest.raises(CalibError, match="--first 500 is more than --budget 10"):
        calibrate(run, first=500, budget=10, **QUIET)
    with pytest.raises(CalibError, match="not a scheduler address"):
        calibrate(run, dask="notanaddress", **QUIET)
    assert not (run / "calibrate").exists()


def test_a_step_for_another_revision_does_nothing(lab):
    from calib_cli.stages.calibrate import calibrate

    run, calls = lab
    said = []
    r = calibrate(run, at_revision=1, say=lambda m, **k: said.append(m))
    assert r.skipped and not calls and "nothing to do" in said[0]


def test_the_command_leads_with_the_posterior(lab):
    from calib_cli.cli import app

    run, _ = lab
    r = CliRunner().invoke(app, ["calibrate", "--run", str(run), "--budget", "100", "--first", "60", "--batch",
                                 "20", "--walkers", "16", "--steps", "300"], env={"COLUMNS": "160"})
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())
    assert out.index("posterior of model revision 0") < out.index("rounds: heaps")
    assert "rolling_friction:" in out and "stopped:" in out and "calib compare" in out


# ------------------------------------------------------------------ coverage under the adaptive design
def _adaptive_coverage(tmp_path, monkeypatch, runs: int) -> tuple[float, list]:
    """The share of 90 % intervals holding the truth over whole calibrations (round 0, then the variance
    rule until stable or 100 heaps) of labs whose truths are drawn from the prior (the default factor
    table), ten piles a condition scattering as the stand-in's piles do."""
    from calib_cli.settings import DEFAULTS
    from calib_cli.stages import calibrate as cal

    box = {p: (DEFAULTS["factors"][p]["low"], DEFAULTS["factors"][p]["high"]) for p in TRUTH}
    hits = []
    for k in range(runs):
        rng = np.random.default_rng(700 + k)
        truth = {p: rng.uniform(lo, hi) for p, (lo, hi) in box.items()}
        piles = [stand_in(truth, h) + rng.normal(0, 1.0, 10) for h in FILLS]
        run = tmp_path / f"lab{k}"
        art.write_table(run / "measure" / "conditions.parquet", pd.DataFrame({
            "condition_id": [f"H{h:g}" for h in FILLS], "fill_height_mm": FILLS, "particle_d_min_mm": 4.0,
            "particle_d_max_mm": 5.0, "cylinder_diameter_mm": 40.0, "mean": [p.mean() for p in piles],
            "sd": [p.std(ddof=1) for p in piles], "n": 10}))
        monkeypatch.setattr(cal, "run_campaign", _fake_campaign([]))
        t = cal.calibrate(run, budget=100, first=40, batch=20, walkers=16, steps=500, seed=k, **QUIET).table
        hits += [r.q05 <= truth[r.parameter] <= r.q95 for r in t.itertuples()]
    return float(np.mean(hits)), hits


@pytest.mark.slow
def test_under_the_adaptive_design_the_90_percent_intervals_hold_the_truth_80_to_95_percent(tmp_path, monkeypatch):
    """40 whole calibrations (120 intervals, ~4 min): the rounds place heaps where the posterior lies, so
    the surrogate is sure there and wrong elsewhere; the intervals must still hold their truths."""
    share, _ = _adaptive_coverage(tmp_path, monkeypatch, 40)
    print(f"coverage under the adaptive design: {share:.3f} of 120 intervals")
    assert 0.80 <= share <= 0.95, share


def test_a_bayes_factor_only_bounded_is_resolved_by_sampling_the_final_posterior_longer(lab, monkeypatch):
    """Cohesion in the model and plainly present in the lab: no draw falls near surface_energy = 0, so the
    last round's Bayes factor of off is only a bound; the final posterior samples longer, and its bound
    is smaller."""
    from calib_cli.model import Model, save_model
    from calib_cli.stages import calibrate as cal

    run, calls = lab
    save_model(run, Model(("sliding_friction", "rolling_friction", "restitution", "cohesion")))
    (run / "settings.toml").write_text("[factors.surface_energy]\nlow = 0.0\nhigh = 2.0\n")
    truth = {**TRUTH, "surface_energy": 1.2}

    def with_cohesion(p, fill):
        return stand_in(p, fill) + 6.0 * p["surface_energy"] * (75 / fill)

    meas = pd.read_parquet(run / "measure" / "conditions.parquet")
    art.write_table(run / "measure" / "conditions.parquet", meas.assign(mean=[with_cohesion(truth, h) for h in FILLS]))
    monkeypatch.setattr(cal, "run_campaign", _fake_campaign(calls, angle=with_cohesion))
    said = []
    r = cal.calibrate(run, budget=120, first=60, batch=20, walkers=16, steps=300, say=lambda m, **k: said.append(m))
    last = r.rounds[r.rounds["parameter"] == "surface_energy"].iloc[-1]
    se = r.table.set_index("parameter").loc["surface_energy"]
    assert last["bf_upper"] and any("the answer: the last round's posterior sampled" in m for m in said)
    assert se["q05"] > 0.5 and se["bf_off"] < last["bf_off"]


def test_a_wall_effect_is_weighed_round_by_round_against_the_grains_own_value(lab, monkeypatch):
    """A lab whose wall is 0.2 less frictional than its grains, calibrated with the wall's friction free: each
    round records the wall effect's Bayes factor of off (the wall at the grains' value) and its word, and
    the answer leans to the effect (on these 120 heaps, 0.049: "the data call for it")."""
    from calib_cli.model import Model, load_model, save_model
    from calib_cli.stages import calibrate as cal

    run, calls = lab
    save_model(run, Model(("sliding_friction", "rolling_friction", "restitution", "wall_friction")))
    truth = {**TRUTH, "wall_static_friction": 0.25}

    def with_wall(p, fill):
        return stand_in(p, fill) + 12.0 * (p["wall_static_friction"] - p["static_friction"]) * (fill / 75) ** 2

    meas = pd.read_parquet(run / "measure" / "conditions.parquet")
    art.write_table(run / "measure" / "conditions.parquet", meas.assign(mean=[with_wall(truth, h) for h in FILLS]))
    monkeypatch.setattr(cal, "run_campaign", _fake_campaign(calls, angle=with_wall))
    r = cal.calibrate(run, budget=120, first=60, batch=20, walkers=16, steps=400, **QUIET)
    wall = r.rounds[r.rounds["parameter"] == "wall_static_friction"]
    assert wall["bf_off"].notna().all() and (wall["effect"] != "").all()
    assert (r.rounds.loc[r.rounds["parameter"] != "wall_static_friction", "effect"] == "").all()  # no effect of theirs
    answer = r.table.set_index("parameter").loc["wall_static_friction"]
    assert answer["bf_off"] < 1 and "(wall_static_friction = static_friction) against on" in answer["verdict"]
    # its locks name the wall's Bayes factor: a wall's posterior locked before it had one is stale; no other is
    from calib_cli.posterior.evidence import evidence_lock
    rows = pd.read_parquet(run / "simulate" / "results.parquet")
    assert evidence_lock(run, load_model(run), rows, None)[1]["wall_bayes_factor"] == 1
    assert "wall_bayes_factor" not in evidence_lock(run, Model(("sliding_friction", "rolling_friction", "restitution")),
                                                    rows, None)[1]


@pytest.mark.parametrize("argv", [["compare"], ["diagnose"], ["model", "add", "cohesion"]])
def test_a_pipeline_step_for_another_revision_does_nothing(lab, argv):
    """compare, diagnose and model add take --at-revision as calibrate does: a rerun of a whole loop's
    pipeline skips the steps of the revisions it has passed instead of redoing them on the current one."""
    from calib_cli.cli import app

    run, calls = lab
    r = CliRunner().invoke(app, [*argv, "--run", str(run), "--at-revision", "1"], env={"COLUMNS": "160"})
    assert r.exit_code == 0, r.output
    assert "the model is at revision 0, this step is for revision 1: nothing to do" in " ".join(r.output.split())
    assert not calls and not (run / "model.toml").exists()
