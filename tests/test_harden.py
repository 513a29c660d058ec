"""Issue #34, hardening: user errors are one line and exit 2, settings are checked by type, the
model refuses values it would drop, diagnose refuses stale residuals, --force keeps the cache until
each heap is replaced, one writer per run directory, and stage commits are all-or-nothing."""

import json
import sys
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.cli import app
from calib_cli.errors import CalibError

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]


def one_line_error(r, *needles):
    """A user error: exit 2 and one line naming each needle."""
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert isinstance(r.exception, SystemExit), r.exception
    text = " ".join(r.output.split())
    for n in needles:
        assert n in text, (n, r.output)


# ------------------------------------------------------------------ row 7: Python version
def test_python_version_is_required_where_tomllib_is(monkeypatch):
    """tomllib is 3.11's: pyproject says so, and an older Python gets a sentence, not a traceback."""
    assert 'requires-python = ">=3.11"' in (ROOT / "pyproject.toml").read_text()
    src = (ROOT / "calib_cli" / "__init__.py").read_text()
    monkeypatch.setattr(sys, "version_info", (3, 10, 12))
    with pytest.raises(ImportError, match="Python 3.11 or newer"):
        exec(compile(src, "calib_cli/__init__.py", "exec"), {"__name__": "calib_cli"})


# ------------------------------------------------------------------ row 1: a missing conditions table
def test_missing_conditions_table_is_a_user_error(tmp_path):
    r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "run"), "--preset", "smoke",
                            "--conditions", str(tmp_path / "missing.csv")])
    one_line_error(r, "missing.csv", "not found")
    bad = tmp_path / "bad.csv"
    bad.write_bytes(b"\xff\xfe\x00garbage")
    r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "run"), "--preset", "smoke",
                            "--conditions", str(bad)])
    assert r.exit_code == 2, r.output


# ------------------------------------------------------------------ row 2: settings checked by type
@pytest.mark.parametrize("item, needles", [
    ("pb.alpha=abc", ["pb.alpha", "'abc'", "number in (0, 1)"]),
    ("pb.alpha=1.5", ["pb.alpha", "1.5", "number in (0, 1)"]),
    ("pb.runs=abc", ["pb.runs", "'abc'", "positive integer"]),
    ("pb.runs=12.5", ["pb.runs", "12.5", "positive integer"]),
    ("pb.runs=0", ["pb.runs", "positive integer"]),
    ("invert.population=ten", ["invert.population", "integer"]),
    ("surrogate.models='rsm'", ["surrogate.models", "list"]),
    ("factors.restitution.low='a'", ["factors.restitution.low", "number"]),
    ("bbd.fixed.restitution=true", ["bbd.fixed.restitution", "number"]),
    ("factors.x=1", ["factors.x", "table"]),
])
def test_settings_are_checked_by_type(item, needles):
    from calib_cli.settings import load_settings

    with pytest.raises(CalibError) as e:
        load_settings(overrides=[item])
    msg = str(e.value)
    assert "\n" not in msg and all(n in msg for n in needles), msg


def test_bad_setting_values_are_refused_at_init_every_command_and_in_the_file(tmp_path):
    run = tmp_path / "run"
    r = runner.invoke(app, ["pb", "design", "--run", str(run), "-s", "pb.alpha=abc"])
    one_line_error(r, "pb.alpha", "'abc'", "number in (0, 1)")
    r = runner.invoke(app, ["init", "--run", str(run), "-s", "pb.runs=abc"])
    one_line_error(r, "pb.runs", "'abc'", "positive integer")
    assert not (run / "settings.toml").exists()
    r = runner.invoke(app, ["init", "--run", str(run), "-s", "pb.runs=12.5"])
    one_line_error(r, "pb.runs", "12.5", "positive integer")
    # a file edited by hand: the same error, naming the file
    assert runner.invoke(app, ["init", "--run", str(run)]).exit_code == 0
    (run / "settings.toml").write_text('[pb]\nruns = "abc"\n')
    r = runner.invoke(app, ["pb", "design", "--run", str(run)])
    one_line_error(r, "pb.runs", "'abc'", "positive integer", "settings.toml")
    # good values still pass, integers where numbers are wanted included
    (run / "settings.toml").write_text('[pb]\nruns = 12\nalpha = 0.1\n')
    r = runner.invoke(app, ["pb", "design", "--run", str(run), "-s", "target=33"])
    assert r.exit_code == 0, r.output


# ------------------------------------------------------------------ row 3: compare --set of a parameter the model lacks
TRUTH = ["--set", "static_friction=0.5", "--set", "rolling_friction=0.2", "--set", "restitution=0.3"]


def test_compare_refuses_a_value_for_a_parameter_the_model_does_not_have(tmp_path):
    from calib_cli.model import Model, save_model

    run = tmp_path / "run"
    save_model(run, Model(("sliding_friction", "rolling_friction", "restitution")))
    for cmd in ("compare", "diagnose"):
        r = runner.invoke(app, [cmd, "--run", str(run), *TRUTH, "--set", "surface_energy=0.5"])
        one_line_error(r, "surface_energy", "static_friction, rolling_friction, restitution", "model add cohesion")
    # its neutral value is what the model simulates anyway: no error about it (the next one is the missing lab)
    r = runner.invoke(app, ["compare", "--run", str(run), *TRUTH, "--set", "surface_energy=0"])
    one_line_error(r, "measured conditions")


# ------------------------------------------------------------------ row 4: diagnose on the current revision's residuals
DEFAULT = ["sliding_friction", "rolling_friction", "restitution"]


def _diagnose_run(tmp_path, ids, residual_ids, revision_of_residuals):
    from calib_cli.model import Model, save_model

    run = tmp_path / "run"
    art.write_table(run / "measure" / "conditions.parquet",
                    pd.DataFrame({"condition_id": ids, "mean": 30.0, "sd": 1.0, "n": 3,
                                  "particle_d_max_mm": [5.0 + k for k in range(len(ids))]}))
    art.write_table(run / "compare" / "residuals.parquet",
                    pd.DataFrame({"condition_id": residual_ids, "residual": [float(i) for i in range(len(ids))],
                                  "uncertainty": 0.5}),
                    {"stage": "compare.rev1", "model_revision": revision_of_residuals, "model": DEFAULT})
    save_model(run, Model(tuple(DEFAULT)))
    return run


def test_diagnose_refuses_residuals_of_another_model_revision(tmp_path):
    run = _diagnose_run(tmp_path, ["A", "B"], ["A", "B"], 1)
    assert runner.invoke(app, ["model", "add", "cohesion", "--run", str(run)]).exit_code == 0
    r = runner.invoke(app, ["diagnose", "--run", str(run), *TRUTH, "--set", "surface_energy=0.5"])
    one_line_error(r, "revision 1", "revision 2", "run `calib compare", "first")


def test_diagnose_aligns_residuals_to_conditions_by_condition_id(tmp_path, monkeypatch):
    from calib_cli.stages import diagnose as dg

    run = _diagnose_run(tmp_path, ["A", "B", "C", "D"], ["D", "B", "A", "C"], 1)
    seen = {}

    def rank(run, model, theta, res, conds, *rest, **kw):
        seen["res"], seen["conds"] = res, conds
        raise CalibError("stop")

    monkeypatch.setattr(dg, "signatures", lambda *a, **k: (None,) * 5)
    monkeypatch.setattr(dg, "_rank", rank)
    with pytest.raises(CalibError, match="stop"):
        dg.diagnose(run, TRUTH[1::2])
    assert list(seen["res"]["condition_id"]) == ["A", "B", "C", "D"]
    assert list(seen["res"]["residual"]) == [2.0, 1.0, 3.0, 0.0]
    # residuals of other conditions than those measured now are stale too
    run = _diagnose_run(tmp_path / "other", ["A", "B", "C", "D"], ["A", "B", "C", "E"], 1)
    with pytest.raises(CalibError, match=r"conditions are A, B, C, D: run `calib compare"):
        dg.diagnose(run, TRUTH[1::2])


# ------------------------------------------------------------------ row 8: all-or-nothing stage commits
@pytest.mark.parametrize("crash_after", [0, 1, 2, 3])
def test_a_commit_cut_short_leaves_the_previous_outputs_or_a_rerun_error(tmp_path, monkeypatch, crash_after):
    """os.replace fails after ``crash_after`` successful calls: each output then reads as the previous
    run's, or is refused with a message saying to rerun the command that writes it; never the new file under the old lock."""
    import os

    old = {"a.parquet": pd.DataFrame({"a": [1]}), "b.parquet": pd.DataFrame({"b": [1]})}
    new = {"a.parquet": pd.DataFrame({"a": [2]}), "b.parquet": pd.DataFrame({"b": [2]})}

    def commit(k, tables):
        st = art.Stage(tmp_path, "g", "s", settings={"k": k})
        with st.commit() as out:
            for rel, df in tables.items():
                out.table(rel, df)
        return st

    commit(1, old)
    real, calls = os.replace, []

    def crashing(src, dst):
        if len(calls) >= crash_after:
            raise OSError("power cut")
        calls.append(dst)
        return real(src, dst)

    monkeypatch.setattr(os, "replace", crashing)
    with pytest.raises(OSError, match="power cut"):
        commit(2, new)
    monkeypatch.setattr(os, "replace", real)
    refused = 0
    for rel, df in old.items():
        try:
            pd.testing.assert_frame_equal(art.read_table(tmp_path / "g" / rel), df)
        except CalibError as e:
            assert "rerun the command" in str(e) and "g.s" in str(e) and "\n" not in str(e)
            refused += 1
    assert refused == min(max(crash_after - 1, 0), 2)  # the files renamed before the crash
    assert not art.Stage(tmp_path, "g", "s", settings={"k": 2}).up_to_date()
    commit(2, new)  # a rerun makes everything readable again
    for rel, df in new.items():
        pd.testing.assert_frame_equal(art.read_table(tmp_path / "g" / rel), df)
    assert art.Stage(tmp_path, "g", "s", settings={"k": 2}).up_to_date()


def test_an_output_changed_behind_its_lock_is_refused_and_unlisted_files_are_not_checked(tmp_path):
    st = art.Stage(tmp_path, "g", "s", settings={})
    with st.commit() as out:
        out.table("a.parquet", pd.DataFrame({"a": [1]}))
    art.write_table(tmp_path / "g" / "a.parquet", pd.DataFrame({"a": [5]}))
    with pytest.raises(CalibError, match="rerun the command"):
        art.read_table(tmp_path / "g" / "a.parquet")
    art.write_table(tmp_path / "g" / "history.parquet", pd.DataFrame({"a": [5]}))  # no lock lists it
    assert art.read_table(tmp_path / "g" / "history.parquet")["a"].tolist() == [5]


def test_a_json_output_changed_behind_its_lock_is_refused_too(tmp_path):
    """A stage's JSON outputs (invert's best.json, the networks' states) are read through the lock as its
    tables are: a best.json from one run beside the tables of another is refused, not read."""
    st = art.Stage(tmp_path, "g", "t", settings={})
    with st.commit() as out:
        out.text("best.json", json.dumps({"best": "rsm"}))
    assert art.read_json(tmp_path / "g" / "best.json") == {"best": "rsm"}
    art.write_json(tmp_path / "g" / "best.json", {"best": "bp"})
    with pytest.raises(CalibError, match="rerun the command"):
        art.read_json(tmp_path / "g" / "best.json")
    art.write_json(tmp_path / "g" / "notes.json", {"a": 1})  # no lock lists it
    assert art.read_json(tmp_path / "g" / "notes.json") == {"a": 1}


def test_committed_sample_runs_read_through_their_locks():
    """Several locks may list one file (compare's revisions): it is enough that one records its hash."""
    for p in sorted((ROOT / "sample_runs").rglob("*.parquet")):
        art.read_table(p)


# ------------------------------------------------------------------ row 6: one writer per run directory
HOLDER = """
import sys, time
from calib_cli import artifacts as art
with art.run_lock(sys.argv[1]):
    print("held", flush=True)
    time.sleep(120)
"""


def test_a_second_writer_of_a_run_directory_fails_naming_the_holder(tmp_path):
    """Two processes: one holds RUN/.lock; a writing command on the same run fails in one line naming
    the run directory and the holder's pid and command, writes nothing, and works once it is gone."""
    import os
    import subprocess

    run = tmp_path / "run"
    script = tmp_path / "holder.py"
    script.write_text(HOLDER)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, str(script), str(run)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "held"
        r = runner.invoke(app, ["pb", "design", "--run", str(run)])
        one_line_error(r, str(run), "in use", f"pid {proc.pid}", "holder.py")
        r = runner.invoke(app, ["simulate-heap", "--run", str(run), "--preset", "smoke", "--set",
                                "static_friction=0.3"])
        one_line_error(r, str(run), f"pid {proc.pid}")
        assert "run(s)" not in r.output and "runs" not in r.output  # refused before its plan and progress bars
        r = runner.invoke(app, ["model", "add", "cohesion", "--run", str(run)])
        one_line_error(r, str(run), f"pid {proc.pid}")
        assert sorted(p.name for p in run.iterdir()) == [".lock"]
    finally:
        proc.kill()
        proc.wait()
    r = runner.invoke(app, ["pb", "design", "--run", str(run)])
    assert r.exit_code == 0, r.output


def test_the_run_lock_is_reentrant_and_leaves_no_run_dir_behind_a_failed_command(tmp_path):
    from calib_cli.stages.doe import pb_design

    run = tmp_path / "run"
    with art.run_lock(run):
        pb_design(run)  # a stage inside a stage's lock: the same process, no deadlock
    assert (run / "pb" / "design.parquet").is_file()
    with pytest.raises(CalibError):
        pb_design(tmp_path / "new", setting=["pb.alpha=abc"])
    assert not (tmp_path / "new").exists()
    with pytest.raises(CalibError):  # nor the folders it made above the run
        pb_design(tmp_path / "a" / "b" / "run", setting=["pb.alpha=abc"])
    assert not (tmp_path / "a").exists()


def test_the_simulation_index_is_merged_with_what_is_on_disk(tmp_path, monkeypatch):
    """A row another writer added to results.parquet while a campaign ran survives the campaign's
    next index update (it used to rewrite the index from the copy it read at its start)."""
    from calib_cli.dem.heap import HeapCondition, Numerics
    from calib_cli.heaps import runner as heap_runner
    from calib_cli.heaps.index import RESULTS, load_results
    from calib_cli.heaps.keys import Request

    reqs = [Request({"static_friction": 0.3}, HeapCondition(), Numerics(), seed=s, run_id=s) for s in (1, 2)]

    def fake_execute(req, run_dir, progress=None, force=False):
        if req.run_id == 1:  # meanwhile, someone else's heap lands in the index
            other = pd.DataFrame([{"run_hash": "other", "design": "", "run_id": 99, "repeat": 0,
                                   "condition_id": "", "status": "ok", "repose_angle": 33.0}])
            art.write_table(tmp_path / RESULTS, other)
        return {"run_hash": req.hash, "status": "ok", "repose_angle": 30.0 + req.run_id}

    monkeypatch.setattr(heap_runner, "execute", fake_execute)
    heap_runner.run_campaign(reqs, tmp_path)
    index = load_results(tmp_path)
    assert sorted(index["run_hash"]) == sorted(["other", reqs[0].hash, reqs[1].hash])


# ------------------------------------------------------------------ row 5: --force keeps the cache until each run is replaced
def _fake_heap(angle):
    """A finished heap as run_heap returns it (what execute writes), without simulating."""
    import numpy as np
    from types import SimpleNamespace as NS

    n = 5
    parts = NS(pos=np.random.default_rng(0).random((n, 3)) * 0.01, rad=np.full(n, 1e-3), vel=np.zeros((n, 3)),
               omg=np.zeros((n, 3)))
    a = NS(angle=angle, sd=0.1, height=0.01, base_radius=0.02, profile_r=np.arange(3.0), profile_h=np.arange(3.0))
    return NS(status="ok", message="", angle=a, angle_drift=0.0, system=NS(particles=parts, n=n, n_steps=10, dt=1e-5,
              max_overlap=0.0), energy=np.zeros((2, 3)), t_end=1.0, t_settled=0.5, t_lift_end=0.4, wall_s=0.1)


def test_force_recomputes_a_cached_heap_without_losing_it_before_the_new_one_is_complete(tmp_path, monkeypatch):
    from calib_cli.heaps import runner as heap_runner
    from calib_cli.heaps.index import load_results
    from calib_cli.heaps.keys import RUNS
    from calib_cli.stages.simulate import plan_simulation, run_simulation

    run = tmp_path / "run"
    monkeypatch.setattr(heap_runner, "run_heap", lambda *a, **k: _fake_heap(30.0))
    plan = run_simulation(plan_simulation(run, {"static_friction": 0.3}, preset="smoke")).rows
    folder = run / RUNS / plan["run_hash"].iloc[0]
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert art.read_json(folder / "result.json")["repose_angle"] == 30.0

    def interrupted(*a, **k):  # Ctrl-C while the new heap is simulated: the cached one is still whole
        assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
        raise KeyboardInterrupt

    monkeypatch.setattr(heap_runner, "run_heap", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_simulation(plan_simulation(run, {"static_friction": 0.3}, preset="smoke", force=True))
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    assert sorted(p.name for p in folder.parent.iterdir()) == [folder.name]  # nothing staged left behind

    def recomputed(*a, **k):
        assert (folder / "result.json").is_file()
        return _fake_heap(31.0)

    monkeypatch.setattr(heap_runner, "run_heap", recomputed)
    rows = run_simulation(plan_simulation(run, {"static_friction": 0.3}, preset="smoke", force=True)).rows
    assert rows["repose_angle"].tolist() == [31.0]
    assert art.read_json(folder / "result.json")["repose_angle"] == 31.0
    assert load_results(run)["repose_angle"].tolist() == [31.0]
    assert sorted(p.name for p in folder.parent.iterdir()) == [folder.name]


def test_a_read_only_run_directory_needs_no_lock(tmp_path, monkeypatch):
    """Up-to-date stages of a read-only run directory (a committed sample run) still answer: where
    the lock file cannot be created nobody can write, so there is nothing to lock against."""
    import errno
    import os

    real = os.open

    def read_only(path, *a, **k):
        if str(path).endswith(art.RUN_LOCK):
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real(path, *a, **k)

    monkeypatch.setattr(os, "open", read_only)
    with art.run_lock(tmp_path):
        pass


# ------------------------------------------------------------------ a heap that blows up is recorded, not fatal
def test_a_heap_that_blows_up_comes_back_unstable_with_no_angle(monkeypatch):
    import numpy as np

    from calib_cli.dem import heap
    from calib_cli.dem.system import System, UnstableError

    calls = []

    def blow_up(self, n):  # the second chunk diverges, as a too-stiff cohesive contact does
        calls.append(n)
        if len(calls) == 2:
            self.particles.pos[0] = np.nan
            raise UnstableError("unstable run: a particle exceeded 50 m/s (or went NaN) at t = 0.01 s")

    monkeypatch.setattr(System, "advance", blow_up)
    res = heap.run_heap({"static_friction": 0.3}, heap.PRESETS["smoke"].condition, heap.PRESETS["smoke"].numerics)
    assert res.status == "unstable" and "50 m/s" in res.message
    assert np.isnan(res.angle.angle) and len(res.angle.profile_r) == 0 and np.isnan(res.t_lift_end)


def test_a_campaign_records_an_unstable_heap_and_goes_on(tmp_path, monkeypatch):
    """One heap of three blows up: its row says so (no angle, no side view) and is cached like any
    finished heap; the others are simulated; the stage's notes name it."""
    import numpy as np
    from types import SimpleNamespace as NS

    from calib_cli.dem.angle import no_angle
    from calib_cli.heaps import runner as heap_runner
    from calib_cli.heaps.keys import RUNS
    from calib_cli.stages.simulate import plan_simulation, run_simulation

    def heaps(params, condition, numerics, seed, progress=None, checkpoint=None):
        if seed != plan.requests[1].seed:
            return _fake_heap(30.0 + seed % 7)
        res = _fake_heap(0.0)
        res.system.particles.pos[:] = np.nan
        return NS(**{**vars(res), "status": "unstable", "message": "unstable run: overlap reached 12% of a radius",
                     "angle": no_angle(), "t_settled": np.nan, "t_lift_end": np.nan, "angle_drift": np.nan})

    run = tmp_path / "run"
    plan = plan_simulation(run, {"static_friction": 0.3}, preset="smoke", repeats=3)
    monkeypatch.setattr(heap_runner, "run_heap", heaps)
    result = run_simulation(plan)
    rows = result.rows.sort_values("repeat")
    assert rows["status"].tolist() == ["ok", "unstable", "ok"]
    assert np.isnan(rows["repose_angle"].iloc[1]) and rows["repose_angle"].notna().sum() == 2
    folder = run / RUNS / rows["run_hash"].iloc[1]
    assert (folder / "result.json").is_file() and not (folder / "side.png").exists()
    assert any("unstable" in n and "12%" in n for n in result.check().notes())

    monkeypatch.setattr(heap_runner, "run_heap", lambda *a, **k: pytest.fail("a cached heap was simulated again"))
    again = run_simulation(plan_simulation(run, {"static_friction": 0.3}, preset="smoke", repeats=3)).rows
    assert again.sort_values("repeat")["status"].tolist() == ["ok", "unstable", "ok"]


def test_a_command_sweeps_what_a_killed_writer_staged(tmp_path):
    """A kill leaves hidden staging folders and temporary files; the next command to take the run
    lock deletes them (no writer is alive then), and nothing else: not a stepped-aside cached run."""
    run = tmp_path / "run"
    runs = run / "simulate" / "runs"
    left = [run / "pb" / ".design.staging-abc", runs / ".0123.staging-xyz", run / "simulate" / ".results.parquet.k2.tmp"]
    kept = [runs / "0123", runs / ".4567.old", run / "pb" / "design.parquet", run / "pb" / "sub" / "deep" / ".x.tmp"]
    for p in left[:2] + kept[:2]:
        p.mkdir(parents=True)
        (p / "state.parquet").write_bytes(b"x")
    for p in left[2:] + kept[2:]:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
    with art.run_lock(run, wait=True):  # a library's index update: others may be staging beside it
        pass
    assert all(p.exists() for p in left)
    with art.run_lock(run):
        assert not any(p.exists() for p in left)
    assert all(p.exists() for p in kept)  # deeper than a run's folders reach: not swept


# ------------------------------------------------------------------ a stopped heap goes on from its checkpoint
def _short_heap():
    from calib_cli.dem.heap import HeapCondition, Numerics

    # ~40 grains lifted fast: settle, lift and rest within 0.03 s (640 steps)
    return ({"static_friction": 0.5, "rolling_friction": 0.1, "surface_energy": 0.3},
            HeapCondition(6.0, 8.0, 32.0, 16.0, 3000.0),
            Numerics(time_max=0.03, settle_time_max=0.006, rest_time_min=0.005, chunk=100))


def test_a_heap_stopped_in_any_phase_goes_on_from_its_checkpoint_as_if_it_had_not_stopped(tmp_path):
    import numpy as np

    from calib_cli.dem.heap import HeapTest, run_heap, save_checkpoint

    params, cond, num = _short_heap()
    whole = run_heap(params, cond, num, 3)
    stages = set()
    for stop in (1, 3, 6):  # in the settle, lift and rest phases (7 chunks in all)
        test = HeapTest(params, cond, num, 3)
        for _ in range(stop):
            test.system.advance(num.chunk)
            test.advanced()
        stages.add(test.stage)
        ck = tmp_path / f"stop{stop}.npz"
        save_checkpoint(ck, test.state())
        again = run_heap(params, cond, num, 3, checkpoint=ck, every=0.0)  # saves after every chunk too
        assert np.array_equal(again.system.particles.pos, whole.system.particles.pos)
        assert np.array_equal(again.system.particles.omg, whole.system.particles.omg)
        assert (again.status, again.system.n_steps, again.t_settled, len(again.energy)) == \
               (whole.status, whole.system.n_steps, whole.t_settled, len(whole.energy))
        assert again.t_lift_end == whole.t_lift_end
    assert stages == {"settle", "lift", "rest"}
    ck.write_bytes(b"not a checkpoint")  # a corrupt one: deleted, and the heap starts afresh
    fresh = run_heap(params, cond, num, 3, checkpoint=ck)
    assert not ck.exists() and np.array_equal(fresh.system.particles.pos, whole.system.particles.pos)


def test_a_campaign_heap_resumes_from_its_checkpoint_and_then_deletes_it(tmp_path, monkeypatch):
    from calib_cli.heaps import runner as heap_runner
    from calib_cli.heaps.keys import RUNS, Request
    from calib_cli.heaps.runner import checkpoint_path

    params, cond, num = _short_heap()
    req = Request(params, cond, num, 3)
    seen = []

    def heap(*a, checkpoint=None, **k):
        seen.append(checkpoint)
        assert checkpoint.read_bytes() == b"state"
        return _fake_heap(30.0)

    monkeypatch.setattr(heap_runner, "run_heap", heap)
    (tmp_path / RUNS).mkdir(parents=True)
    ck = checkpoint_path(tmp_path, req)
    ck.write_bytes(b"state")
    heap_runner.execute(req, str(tmp_path))
    assert seen == [ck] and not ck.exists()
    ck.write_bytes(b"state")
    checkpoint_path(tmp_path, req, fresh=True)  # --force: the heap starts again from its fill
    assert not ck.exists()


@pytest.mark.parametrize("damage", [b"", b"PK\x03\x04 truncated"])
def test_a_damaged_checkpoint_is_deleted_and_the_heap_starts_afresh(tmp_path, damage):
    """An emptied (EOFError) or truncated (BadZipFile) .npz stopped every rerun of its heap with exit 70."""
    from calib_cli.dem.heap import resume

    path = tmp_path / "checkpoint.npz"
    path.write_bytes(damage)
    marker = object()
    assert resume(marker, path) is marker and not path.exists()


def test_a_worker_killed_from_outside_is_one_line_not_an_internal_error(monkeypatch, tmp_path):
    """A pool worker the out-of-memory killer ends breaks the pool: BrokenProcessPool was exit 70."""
    import concurrent.futures as cf
    import contextlib
    from concurrent.futures.process import BrokenProcessPool

    from calib_cli.errors import CalibError
    from calib_cli.heaps import runner

    class Pool:
        def submit(self, *a, **k):
            f = cf.Future()
            f.set_exception(BrokenProcessPool("a child process terminated abruptly"))
            return f

    monkeypatch.setattr(runner, "spawned", lambda workers: contextlib.nullcontext(Pool()))
    with pytest.raises(CalibError, match="a worker process died"):
        runner._run_on_pool([(0, object())], tmp_path, 2, False, lambda i, row: None)
