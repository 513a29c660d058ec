"""Heap scenario, angle from coordinates, rendering, cached campaigns, simulate-heap CLI."""

import math
import re
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.cli import app
from calib_cli.dem.angle import repose_angle_coords
from calib_cli.dem.heap import DRIFT_WINDOW, DriftMeter, HeapCondition, Numerics, fill_cylinder, interactions, run_heap
from calib_cli.dem.render import render_side_view
from calib_cli.errors import CalibError
from calib_cli.heaps.index import load_results
from calib_cli.heaps.keys import Request, derive_seed, host
from calib_cli.heaps.runner import run_campaign

TINY = HeapCondition(5.0, 6.0, 30.0, 24.0, 100.0)
TINY_NUM = Numerics(time_max=1.5)
runner = CliRunner()


def cone(angle_deg, d=4e-3, H=0.04, seed=0):
    """Particles filling a cone of the given angle (a heap of known angle)."""
    rng = np.random.default_rng(seed)
    t = math.tan(math.radians(angle_deg))
    g = np.arange(-H / t, H / t, d)
    pts = np.array([(x, y, z) for x in g for y in g for z in np.arange(d / 2, H, d)
                    if z + d / 2 <= H - math.hypot(x, y) * t])
    pts += rng.uniform(-0.05, 0.05, pts.shape) * d
    return pts, np.full(len(pts), d / 2)


@pytest.mark.parametrize("angle", [25.0, 32.0, 40.0, 45.0])
def test_angle_from_coordinates_of_a_known_cone(angle):
    # a heap 16 grains tall (a coarser one, 10 grains, reads up to ~2 deg low: docs/physics.md)
    pos, rad = cone(angle, d=2.5e-3)
    a = repose_angle_coords(pos, rad)
    assert a.n_sectors == 8
    assert a.angle == pytest.approx(angle, abs=1.0)
    assert a.height == pytest.approx(0.04, abs=3e-3)


def test_drift_meter_measures_the_creep_of_the_angle():
    # a heap flattening at -5 deg/s (cones of 40 -> 38 deg over 0.4 s), sampled every 0.05 s;
    # only the last DRIFT_WINDOW before the earliest end counts, and the meter waits for it
    m = DriftMeter(t_start=1.0, min_duration=0.6)
    cones = {round(t, 2): cone(40.0 - 5.0 * (t - 1.2), d=2.5e-3) for t in np.arange(1.2, 1.61, 0.05)}
    for t, (pos, rad) in cones.items():
        assert m.done(t) == (t >= 1.6)
        m.sample(t, pos, rad)
    assert all(t >= 1.6 - DRIFT_WINDOW for t, _ in m.samples)
    # the coordinate angle of a lattice cone is good to ~1 deg, not better: the slope to ~1.5 deg/s
    assert m.rate() == pytest.approx(-5.0, abs=1.5)
    assert np.isnan(DriftMeter(0.0, 1.0).rate())


def test_fill_is_non_overlapping_inside_the_cylinder():
    p = fill_cylinder(HeapCondition(3, 5, 50, 40, 50), 0.6, np.random.default_rng(1))
    r = np.hypot(p.pos[:, 0], p.pos[:, 1]) + p.rad
    assert r.max() < 0.025 and p.pos[:, 2].min() > p.rad.max() * 0.5
    from scipy.spatial import cKDTree

    pairs = cKDTree(p.pos).query_pairs(2 * p.rad.max())
    assert all(np.linalg.norm(p.pos[i] - p.pos[j]) >= p.rad[i] + p.rad[j] for i, j in pairs)
    assert 3 <= p.rad.min() * 2e3 and p.rad.max() * 2e3 <= 5


def test_render_side_view_silhouette():
    pos, rad = cone(30.0)
    v = render_side_view(pos, rad, px_per_m=2000)
    dark = v.image[: v.floor_row] < 128
    rows = np.flatnonzero(dark.any(axis=1))
    height_px = v.floor_row - rows.min()
    assert height_px == pytest.approx((pos[:, 2] + rad).max() * 2000, abs=2)
    assert v.image[v.floor_row + 2].max() < 128  # the floor strip


def test_side_views_go_round_the_heap_over_half_a_turn():
    """View 0 is the side view the results row always had; view k sees the grains turned by k * 45 deg about
    the cylinder's axis: a wall of grains along x fills view 0's width and is end-on in view 2."""
    from calib_cli.dem.render import SIDE_VIEWS, side_views, turned

    x = np.linspace(-0.02, 0.02, 41)
    pos, rad = np.column_stack([x, np.zeros_like(x), np.full_like(x, 0.002)]), np.full(41, 0.001)
    views = side_views(pos, rad)
    assert len(views) == SIDE_VIEWS == 4
    assert np.array_equal(views[0].image, render_side_view(pos, rad).image)
    assert np.allclose(turned(pos, np.pi / 2)[:, :2], np.column_stack([np.zeros_like(x), x]), atol=1e-15)
    width = [int((v.image[: v.floor_row] < 128).any(axis=0).sum()) for v in views]
    assert width[0] > 10 * width[2] and width[0] > width[1] > width[2], width


def test_tiny_heap_runs_and_is_deterministic():
    # at mu_s 0.5 / mu_r 0.3 this 4-grain-high fill stands as a "column" for some seeds (height
    # 0.8 of the fill, base inside 1.5 cylinder radii): a border case; at 0.3 / 0.1 seeds 0-5 all
    # slump into heaps (height 0.44-0.57 of the fill)
    params = {"static_friction": 0.3, "rolling_friction": 0.1, "restitution": 0.3}
    a = run_heap(params, TINY, TINY_NUM, seed=0)
    b = run_heap(params, TINY, TINY_NUM, seed=0)
    assert a.status in ("ok", "timeout") and np.isfinite(a.angle.angle)
    assert a.angle.angle == b.angle.angle
    assert a.system.max_overlap < 0.1 and len(a.energy) > 3
    assert a.t_settled < a.t_lift_end <= a.t_end


def test_standing_column_is_reported_not_measured():
    r = run_heap({"static_friction": 0.6, "rolling_friction": 0.3, "surface_energy": 30.0},
                 HeapCondition(3.0, 4.0, 24.0, 40.0, 100.0), Numerics(time_max=1.5), seed=1)
    assert r.status == "column" and "column" in r.message


def test_parameter_validation():
    with pytest.raises(CalibError, match="restitution"):
        interactions({"restitution": 0.0})
    with pytest.raises(CalibError, match="unknown heap parameter"):
        interactions({"friction": 0.3})
    with pytest.raises(CalibError, match="4 particle diameters"):
        HeapCondition(3, 5, 15, 40, 50).validate()
    assert all(w.surface_energy == 0.0 for w in interactions({"surface_energy": 1.0})[1:])  # walls do not stick
    with pytest.raises(CalibError, match="floor 'plate'.*static_friction must be >= 0"):
        HeapCondition(floor="plate", floor_static_friction=-0.1).validate()
    with pytest.raises(CalibError, match="unknown heap parameter"):
        interactions({"floor_static_friction": 0.3})  # the floor's values are the rig's, not parameters


def test_each_wall_value_comes_from_its_own_then_wall_then_the_grains():
    plate = HeapCondition(floor="plate", floor_static_friction=0.7, floor_surface_energy=0.4)
    pp, floor, cyl = interactions({"static_friction": 0.3, "rolling_friction": 0.2, "wall_static_friction": 0.5,
                                   "cylinder_rolling_friction": 0.05}, plate)
    assert (pp.static_friction, floor.static_friction, cyl.static_friction) == (0.3, 0.7, 0.5)
    assert (pp.rolling_friction, floor.rolling_friction, cyl.rolling_friction) == (0.2, 0.2, 0.05)
    assert (floor.surface_energy, cyl.surface_energy) == (0.4, 0.0)
    assert floor.restitution == cyl.restitution == pp.restitution
    # without floor values or cylinder_* both walls are what wall_* made of them before the split
    _, f, c = interactions({"static_friction": 0.3, "wall_rolling_friction": 0.1}, HeapCondition())
    assert f == c and (f.static_friction, f.rolling_friction) == (0.3, 0.1)


def test_floor_values_key_a_run_only_when_given():
    """Conditions without floor values keep the cache keys they had before the floor had values."""
    from calib_cli.dem.heap import run_key

    assert "floor_static_friction" not in run_key({}, TINY, TINY_NUM, 0)["condition"]
    steel = HeapCondition(5.0, 6.0, 30.0, 24.0, 100.0, "steel", floor_static_friction=0.4)
    k = run_key({}, steel, TINY_NUM, 0)["condition"]
    assert k["floor_static_friction"] == 0.4 and "floor_rolling_friction" not in k
    label_only = HeapCondition(5.0, 6.0, 30.0, 24.0, 100.0, "steel")
    assert Request({}, steel, TINY_NUM, 0).hash != Request({}, label_only, TINY_NUM, 0).hash


def test_a_lammps_heap_is_keyed_by_the_engine_source(monkeypatch):
    """A LAMMPS heap's key names calib_cli/engines/'s source (its parameter mapping), so a changed
    mapping is re-simulated rather than served from the cache; built-in keys do not carry it."""
    from calib_cli.heaps import keys

    lam = Request({}, TINY, TINY_NUM, 0, engine="lammps")
    assert lam.key["engine_source"] == keys.ENGINE_SOURCE and "engine_source" not in Request({}, TINY, TINY_NUM, 0).key
    before = lam.hash
    monkeypatch.setattr(keys, "ENGINE_SOURCE", "000000000000")
    assert lam.hash != before


def test_campaign_caches_and_survives_interruption(tmp_path):
    reqs = [Request({"static_friction": mu}, TINY, TINY_NUM, derive_seed(0, i, 0), "tiny", "", i)
            for i, mu in enumerate([0.3, 0.6], start=1)]
    calls = []

    def interrupt(req, row):
        calls.append(req.run_id)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_campaign(reqs, tmp_path, on_done=interrupt)
    res = load_results(tmp_path)
    assert list(res["run_id"]) == [1]  # the finished run is kept
    rows = run_campaign(reqs, tmp_path)
    assert len(rows) == 2 and len(load_results(tmp_path)) == 2
    # the first run came from the cache: same result, identical artefact
    assert rows.iloc[0]["run_hash"] == res.iloc[0]["run_hash"]
    assert rows.iloc[0]["wall_s"] == res.iloc[0]["wall_s"]
    for sub in ("state.parquet", "side.png", "particles.vtp", "result.json"):
        assert (tmp_path / "simulate" / "runs" / rows.iloc[1]["run_hash"] / sub).is_file()

    # rerunning finished runs (the first alone, then both) leaves the index as it was, byte for byte:
    # the stages that read it stay up to date
    index = tmp_path / "simulate" / "results.parquet"
    before = index.read_bytes()
    run_campaign(reqs[:1], tmp_path)
    assert index.read_bytes() == before
    run_campaign(reqs, tmp_path)
    assert index.read_bytes() == before
    # each row says what its last bits depend on beyond the run hash (docs/performance.md)
    import numba

    assert rows.iloc[1]["host"] == host()
    assert f"numpy {np.__version__}" in host() and f"numba {numba.__version__}" in host()


@pytest.mark.parametrize("text", ["{}", "[1]", '{"run_hash": "0000000000000000", "status": "ok"}'])
def test_a_cached_result_calib_did_not_write_stops_the_campaign_before_the_index(tmp_path, text):
    """A heap folder's result.json edited to {} entered the index as a row of NaN (and moved compare's RMSE);
    a list was exit 70. Now one line naming the file, and the index as it was."""
    reqs = [Request({"static_friction": 0.3}, TINY, TINY_NUM, derive_seed(0, 1, 0), "tiny", "", 1)]
    run_campaign(reqs, tmp_path)
    index = tmp_path / "simulate" / "results.parquet"
    before = index.read_bytes()
    (tmp_path / "simulate" / "runs" / reqs[0].hash / "result.json").write_text(text)
    with pytest.raises(CalibError, match=f"is not the result of heap {reqs[0].hash}.*move .* aside"):
        run_campaign(reqs, tmp_path)
    assert index.read_bytes() == before


def test_a_heaps_row_holds_its_side_views_means_and_a_heap_that_blew_up_none(tmp_path):
    """The row's angle_views and fullness_views are the means over the heap's side views rendered from its
    final grains (view 0 the row's own angle_image), measured as the photographs are; a heap without a
    measured view records 0 views and no means."""
    from calib_cli.dem.render import side_views
    from calib_cli.heaps.runner import _views_means
    from calib_cli.imaging.measure import measure_image
    from calib_cli.profile import fullness

    req = Request({"static_friction": 0.3, "rolling_friction": 0.1, "restitution": 0.3}, TINY, TINY_NUM, 0, "tiny", "", 1)
    row = run_campaign([req], tmp_path).iloc[0]
    assert row["status"] == "ok" and row["side_views"] == 4
    st = pd.read_parquet(tmp_path / "simulate" / "runs" / row["run_hash"] / "state.parquet")
    m = [measure_image(v.image, limits=None) for v in side_views(st[["x", "y", "z"]].to_numpy(), st["radius"].to_numpy())]
    assert m[0].repose_angle == row["angle_image"]
    assert row["angle_views"] == pytest.approx(np.mean([x.repose_angle for x in m]), abs=1e-12)
    assert row["fullness_views"] == pytest.approx(np.mean([fullness(x.profile_s, x.profile_h) for x in m]), abs=1e-12)
    assert len({round(x.repose_angle, 6) for x in m}) > 1  # the views differ: other flanks
    none = _views_means([])
    assert none["side_views"] == 0 and np.isnan(none["angle_views"]) and np.isnan(none["fullness_views"])


def test_a_heap_whose_row_is_indexed_needs_no_folder_where_rows_suffice(tmp_path, monkeypatch):
    """A committed run keeps its results rows, not its heaps' folders: a caller that reads rows only
    (rows_suffice: the calibration's rounds, compare, diagnose) takes the indexed row, under its own
    labels, and simulates nothing; any other caller, and --force, simulates the heap again."""
    import shutil

    from calib_cli.heaps import runner as runner_mod

    reqs = [Request({"static_friction": 0.4}, TINY, TINY_NUM, derive_seed(0, 1, 0), "tiny", "", 1)]
    first = run_campaign(reqs, tmp_path)
    shutil.rmtree(tmp_path / "simulate" / "runs" / first.iloc[0]["run_hash"])
    calls = []
    real = runner_mod.execute
    monkeypatch.setattr(runner_mod, "execute", lambda req, *a, **k: calls.append(req.hash) or real(req, *a, **k))
    relabelled = [Request({"static_friction": 0.4}, TINY, TINY_NUM, derive_seed(0, 1, 0), "tiny", "again", 7)]
    rows = run_campaign(relabelled, tmp_path, rows_suffice=True)
    assert calls == [] and rows.iloc[0]["repose_angle"] == first.iloc[0]["repose_angle"]
    assert (rows.iloc[0]["design"], rows.iloc[0]["run_id"]) == ("again", 7)
    run_campaign(reqs, tmp_path)
    assert calls == [reqs[0].hash]  # a caller that needs the folder gets it back


def test_host_reports_the_simd_level_numpy_dispatches_on():
    """The level in the host column follows numpy's dispatch, NPY_DISABLE_CPU_FEATURES included
    (which is how performance.md's "Reproducibility" shows that the SIMD level changes heaps)."""
    import os
    import subprocess
    import sys

    from calib_cli.heaps.keys import numpy_dispatch_targets

    targets = numpy_dispatch_targets()

    def level(**env):
        code = "from calib_cli.heaps.keys import simd_level; print(simd_level())"
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                              env={**os.environ, **env}).stdout.strip()

    assert level() in targets + ["baseline"]
    assert level(NPY_DISABLE_CPU_FEATURES=" ".join(targets)) == "baseline"


def test_seeds_differ_per_run_and_repeat():
    seeds = {derive_seed(0, r, k) for r in range(1, 13) for k in range(3)}
    assert len(seeds) == 36


def test_simulate_design_then_analyze_end_to_end(tmp_path):
    run = tmp_path / "run"
    cond = ["--condition", "particle_d_min_mm=5", "--condition", "particle_d_max_mm=6",
            "--condition", "cylinder_diameter_mm=30", "--condition", "fill_height_mm=24",
            "--condition", "lift_speed_mm_s=100"]
    assert runner.invoke(app, ["pb", "design", "--run", str(run)]).exit_code == 0
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), "--design", str(run / "pb" / "design.parquet"),
                            "--preset", "smoke", *cond])
    assert r.exit_code == 0, r.output
    res = art.read_table(run / "simulate" / "results.parquet")
    assert len(res) == 12 and set(res["design"]) == {"pb"}
    for c in ["repose_angle", "angle_coords", "angle_image", "seed", "n_particles", "n_steps", "wall_s",
              "static_friction", "cylinder_diameter_mm", "angle_drift_deg_s"]:
        assert c in res.columns
    # heaps still creeping when measured are pointed out, and only then
    creeping = (res["status"] == "ok") & (res["angle_drift_deg_s"].abs() > 2.0)
    assert ("creeping" in r.output) == bool(creeping.any())
    assert "the floor's static friction follows the grains'" in " ".join(r.output.split())
    r2 = runner.invoke(app, ["simulate-heap", "--run", str(run), "--design", str(run / "pb" / "design.parquet"),
                             "--preset", "smoke", *cond])
    assert "12 cached" in r2.output
    ok = res["status"] == "ok"
    if ok.all():
        r3 = runner.invoke(app, ["pb", "analyze", "--run", str(run)])
        assert r3.exit_code == 0, r3.output
        assert art.read_table(run / "pb" / "data.parquet")["n_repeats"].eq(1).all()


def test_simulate_heap_bad_input(tmp_path):
    for args, needle in [(["--set", "static_friction=-1"], "static_friction"),
                         (["--set", "static_friction=nan"], "finite"),
                         (["--preset", "huge"], "unknown preset"),
                         (["--condition", "cylinder_diameter_mm=5"], "particle diameters"),
                         (["--design", str(tmp_path / "nope.parquet")], "not found"),
                         (["--shear-modulus", "0"], "outside"),
                         (["--shear-modulus", "nan"], "outside"),
                         (["--shear-modulus", "1e13"], "outside")]:
        r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "r"), *args])
        assert r.exit_code == 2 and needle in r.output, (args, r.output)
        assert not (tmp_path / "r" / "simulate" / "results.parquet").exists()


def test_shear_modulus_option_sets_grains_and_walls_and_is_recorded(tmp_path):
    """--shear-modulus replaces the preset's reduced modulus for grains and walls: a 4x stiffer
    cohesionless heap runs at half the (Rayleigh) step, is a run of its own in the cache, and its
    row says which modulus it had; rows at the preset's modulus keep their columns."""
    run = tmp_path / "run"
    cond = ["--preset", "smoke", "--condition", "particle_d_min_mm=5", "--condition", "particle_d_max_mm=6",
            "--condition", "cylinder_diameter_mm=30", "--condition", "fill_height_mm=24",
            "--set", "surface_energy=0"]
    for extra in ([], ["--shear-modulus", "2e7"]):
        r = runner.invoke(app, ["simulate-heap", "--run", str(run), *cond, *extra])
        assert r.exit_code == 0, r.output
    assert "shear modulus 20 MPa" in r.output
    res = art.read_table(run / "simulate" / "results.parquet")
    assert len(res) == 2 and res["run_hash"].nunique() == 2
    soft, stiff = res.iloc[0], res.iloc[1]
    assert math.isnan(soft["shear_modulus"]) and stiff["shear_modulus"] == 2e7
    assert stiff["dt"] == pytest.approx(soft["dt"] / 2, rel=1e-12)
    key = art.read_json(run / "simulate" / "runs" / stiff["run_hash"] / "key.json")
    assert key["numerics"]["shear_modulus"] == key["numerics"]["wall_shear_modulus"] == 2e7


def test_the_run_settings_heap_setup_is_every_simulating_commands_default(tmp_path):
    """RUN/settings.toml [heap] sets the preset and modulus of the run's heaps once: simulate-heap
    without options runs exactly the heap the options name (one cache entry), and an option wins."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "settings.toml").write_text('[heap]\npreset = "smoke"\nshear_modulus = 2e7\n')
    cond = ["--condition", "particle_d_min_mm=5", "--condition", "particle_d_max_mm=6", "--condition",
            "cylinder_diameter_mm=30", "--condition", "fill_height_mm=24", "--set", "surface_energy=0"]
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), *cond])
    assert r.exit_code == 0, r.output
    assert "preset smoke" in r.output and "shear modulus 20 MPa" in r.output
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), *cond, "--preset", "smoke", "--shear-modulus", "2e7"])
    assert r.exit_code == 0 and "1 cached" in r.output, r.output
    res = art.read_table(run / "simulate" / "results.parquet")
    assert len(res) == 1 and res["preset"].iloc[0] == "smoke" and res["shear_modulus"].iloc[0] == 2e7
    (run / "settings.toml").write_text('[heap]\npreset = "smoke"\nshear_modulus = -1\n')
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), *cond])
    assert r.exit_code == 2 and "heap.shear_modulus" in r.output, r.output
    assert art.read_table(run / "simulate" / "results.parquet").equals(res)


def _fake_design_results(run, moduli, stage="pb", laws=({},)):
    """RUN/simulate/results.parquet with one row per design run, modulus and set of contact-law
    switches (current kernel)."""
    from calib_cli.heaps.keys import CACHE_SOURCE

    d = art.read_table(run / stage / "design.parquet")
    rows = []
    for m in moduli:
        for law in laws:
            for _, r in d.iterrows():
                rows.append({"run_hash": f"{r['run_id']}-{m}-{law}", "design": stage, "run_id": r["run_id"],
                             "repeat": 0, "condition_id": "", "preset": "default", "source": CACHE_SOURCE,
                             "status": "ok", **{c: r[c] for c in d.columns if c != "run_id"}, **law,
                             "repose_angle": 30.0 + m / 1e7 + 0.1 * r["run_id"],
                             **({"shear_modulus": m} if m != 5e6 else {})})
    art.write_table(run / "simulate" / "results.parquet", pd.DataFrame(rows))


def test_heaps_of_two_rolling_laws_are_not_averaged_and_the_bbd_law_carries_on(tmp_path):
    """A design simulated once with the constant torque and once with the rolling spring is two
    setups, not repeats; a BBD simulated with the spring hands it to the simulations at the
    calibrated point (bbd_fixed: validation, compare, diagnose), a BBD with the default laws
    hands on nothing (their cache keys stay as they were)."""
    from calib_cli.stages.common import bbd_fixed
    from calib_cli.settings import load_settings

    run = tmp_path / "run"
    assert runner.invoke(app, ["pb", "design", "--run", str(run)]).exit_code == 0
    _fake_design_results(run, [5e6], laws=({}, {"rolling_spring": 1.0}))
    r = runner.invoke(app, ["pb", "analyze", "--run", str(run)])
    assert r.exit_code == 2 and "2 setups" in r.output and "rolling_spring 1" in r.output, r.output
    art.write_table(run / "bbd" / "design.parquet", pd.DataFrame(  # as `bbd design` writes one
        {"run_id": [1, 2, 3], "static_friction": [0.1, 0.3, 0.2], "restitution": 0.25}))
    cfg = load_settings()
    _fake_design_results(run, [5e6], "bbd", laws=({"rolling_spring": 1.0},))
    assert bbd_fixed(run, cfg) == {"restitution": 0.25, "rolling_spring": 1.0}
    _fake_design_results(run, [5e6], "bbd", laws=({"rolling_spring": 0.0},))
    assert "rolling_spring" not in bbd_fixed(run, cfg)
    _fake_design_results(run, [5e6], "bbd")
    assert "rolling_spring" not in bbd_fixed(run, cfg)


def test_simulate_heap_runs_the_rolling_spring_with_a_model_file(tmp_path):
    """`--set rolling_spring=1` chooses the law (a heap parameter of its own, in the cache key and
    the results row); a model file does not refuse it as a parameter of no effect."""
    run = tmp_path / "run"
    cond = ["--preset", "smoke", "--condition", "particle_d_min_mm=5", "--condition", "particle_d_max_mm=6",
            "--condition", "cylinder_diameter_mm=30", "--condition", "fill_height_mm=24"]
    run.mkdir()
    assert runner.invoke(app, ["model", "add", "cohesion", "--run", str(run)]).exit_code == 0
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), *cond, "--set", "rolling_spring=1",
                            "--set", "surface_energy=0.2"])
    assert r.exit_code == 0, r.output
    res = art.read_table(run / "simulate" / "results.parquet")
    assert res.iloc[0]["rolling_spring"] == 1.0 and res.iloc[0]["status"] in ("ok", "no_heap")
    key = art.read_json(run / "simulate" / "runs" / res.iloc[0]["run_hash"] / "key.json")
    assert key["params"]["rolling_spring"] == 1.0
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), *cond, "--set", "rolling_spring=0.5"])
    assert r.exit_code == 2 and "rolling_spring must be 0 or 1" in r.output


def test_simulate_heap_refuses_two_friction_caps(tmp_path):
    """`caps_pulloff` and `friction_net_force` are two readings of the same cap: one line, exit 2,
    nothing simulated."""
    run = tmp_path / "run"
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), "--preset", "smoke", "--set", "caps_pulloff=1",
                            "--set", "friction_net_force=1", "--set", "surface_energy=0.2"])
    assert r.exit_code == 2 and "caps_pulloff and friction_net_force exclude each other" in r.output, r.output
    assert not (run / "simulate" / "results.parquet").exists()


def test_heaps_of_two_moduli_are_not_averaged_as_repeats(tmp_path, capsys):
    from calib_cli.stages.common import warn_other_modulus

    run = tmp_path / "run"
    assert runner.invoke(app, ["pb", "design", "--run", str(run)]).exit_code == 0
    _fake_design_results(run, [5e6, 5e8])
    r = runner.invoke(app, ["pb", "analyze", "--run", str(run)])
    assert r.exit_code == 2 and "2 setups" in r.output and "500 MPa" in r.output, r.output
    assert not (run / "pb" / "anova.parquet").exists()
    _fake_design_results(run, [5e8])  # one modulus: analysed; a validation at another is warned about
    assert runner.invoke(app, ["pb", "analyze", "--run", str(run)]).exit_code == 0
    capsys.readouterr()
    warn_other_modulus(run, None, "these")
    assert "500 MPa, these at 5 MPa" in capsys.readouterr().err.replace("\n", " ")
    warn_other_modulus(run, 5e8, "these")
    assert "warning" not in capsys.readouterr().err


def test_dask_local_cluster_gives_the_process_pool_results(tmp_path):
    reqs = [Request({"static_friction": mu}, TINY, TINY_NUM, derive_seed(0, i, 0), "tiny", "", i)
            for i, mu in enumerate([0.3, 0.6], start=1)]
    a = run_campaign(reqs, tmp_path / "pool", workers=2)
    b = run_campaign(reqs, tmp_path / "dask", workers=2, dask="local")
    cols = ["run_hash", "repose_angle", "angle_coords", "n_steps", "status"]
    pd.testing.assert_frame_equal(a[cols].reset_index(drop=True), b[cols].reset_index(drop=True))


def test_heap_bits_do_not_depend_on_threads_changed_mid_run():
    """A heap's bits do not depend on the numba thread count, even when it changes between chunks
    (pair forces are summed in pair order): a campaign's results do not depend on how it ran."""
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs 2 numba threads")
    params = {"static_friction": 0.3, "rolling_friction": 0.1, "surface_energy": 0.5, "restitution": 0.3}
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = run_heap(params, TINY, TINY_NUM, seed=3)
        flip = iter(range(10**6))
        b = run_heap(params, TINY, TINY_NUM, seed=3, progress=lambda *_: numba.set_num_threads(1 + next(flip) % 2))
        assert next(flip) > 4  # the thread count changed many times
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(a.system.particles.pos, b.system.particles.pos)
    assert a.angle.angle == b.angle.angle and a.system.n_steps == b.system.n_steps


def test_a_floor_left_unset_on_some_heaps_is_the_default_floor_not_a_hole_in_the_index(tmp_path):
    """NaN in a floor variable is the default floor (heaps on glass and on the rig's own floor in one index)."""
    rows = pd.DataFrame({"run_hash": ["a", "b"], "repose_angle": [30.0, 31.0], "fill_height_mm": [50.0, 50.0],
                         "floor_static_friction": [0.1, float("nan")]})
    art.write_table(tmp_path / "simulate" / "results.parquet", rows)
    assert len(load_results(tmp_path)) == 2


def test_analyses_ignore_rows_of_older_kernels_and_duplicates(tmp_path):
    from calib_cli.heaps.index import current_results
    from calib_cli.heaps.keys import CACHE_SOURCE

    rows = pd.DataFrame({"run_hash": ["a", "a", "b", "c"], "design": "pb", "run_id": [1, 1, 2, 3], "repeat": 0,
                         "condition_id": "", "source": [CACHE_SOURCE, CACHE_SOURCE, "old", CACHE_SOURCE],
                         "repose_angle": [30.0, 30.0, 89.0, 31.0]})
    art.write_table(tmp_path / "simulate" / "results.parquet", rows)
    cur = current_results(tmp_path)
    assert sorted(cur["run_hash"]) == ["a", "c"]  # the old kernel's row is not a repeat, nor is a duplicate


def test_analyses_see_rows_in_one_order_whatever_order_the_heaps_finished_in(tmp_path):
    """Workers append rows as they finish; a surrogate fitted to them must not depend on that order
    (a fresh clone of a sample run gave other digits than the committed one before this)."""
    from calib_cli.heaps.index import current_results
    from calib_cli.heaps.keys import CACHE_SOURCE

    rng = np.random.default_rng(0)
    n = 40
    rows = pd.DataFrame({"run_hash": [f"{h:04x}" for h in rng.permutation(n)],
                         "design": rng.choice(["calibrate", "bbd", "compare"], n), "run_id": rng.integers(0, 6, n),
                         "repeat": rng.integers(0, 3, n), "condition_id": rng.choice(["c1", "c2"], n),
                         "source": CACHE_SOURCE, "repose_angle": rng.normal(30, 3, n)})
    seen = []
    for k in range(4):
        art.write_table(tmp_path / "simulate" / "results.parquet", rows.sample(frac=1, random_state=k))
        seen.append(current_results(tmp_path))
    for other in seen[1:]:
        pd.testing.assert_frame_equal(seen[0], other)
    assert list(seen[0]["design"]) == sorted(seen[0]["design"])


def test_a_heap_does_not_depend_on_numpys_simd_level():
    """The same two smoke heaps (one cohesive) in two processes, one as this CPU runs and one
    with numpy's AVX-512 targets switched off and OpenBLAS/OpenCV set down (as on an AVX2 CPU),
    come out bitwise equal: positions, step count, coordinate angle, creep rate, image angle (docs/performance.md,
    "Reproducibility"; `benchmarks/simd_invariance.py` is the longer check). On a CPU without
    AVX-512 both processes run the same loops, so the test cannot tell anything there."""
    import importlib.util
    from pathlib import Path

    from calib_cli.heaps.keys import simd_level

    # what this CPU enables, not what numpy was built for: a wheel with AVX-512 loops on an AVX2 CPU
    # runs the same loops in both processes
    if simd_level() not in {"AVX512F", "AVX512_SKX", "AVX512_CLX", "AVX512_CNL", "AVX512_ICL", "AVX512_SPR", "X86_V4"}:
        pytest.skip(f"this CPU runs numpy's {simd_level()} loops, no AVX-512 ones: nothing to switch off")
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "simd_invariance.py"
    spec = importlib.util.spec_from_file_location("simd_invariance", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    on, off, diffs = mod.compare(mod.points(3)[1:], "avx2")
    assert on["host"] != off["host"]  # the two really ran different loops
    assert all(h["angle"] == h["angle"] for h in on["heaps"])  # both formed heaps
    assert diffs == [[], []]


def test_campaign_reuses_finished_runs_of_other_run_directories(tmp_path, monkeypatch):
    """$CALIB_REUSE: a run another run directory has finished is copied, not recomputed, and the
    row takes this request's labels (docs/campaigns.md)."""
    from calib_cli.heaps import runner as heap_runner

    reqs = [Request({"static_friction": mu}, TINY, TINY_NUM, derive_seed(0, i, 0), "tiny", "", i)
            for i, mu in enumerate([0.3, 0.6], start=1)]
    a = run_campaign(reqs, tmp_path / "a")
    relabelled = [Request(r.params, r.condition, r.numerics, r.seed, r.preset, design="other", run_id=r.run_id + 10)
                  for r in reqs]
    assert [r.hash for r in relabelled] == [r.hash for r in reqs]  # labels are not part of the key

    def no_simulation(*args, **kwargs):
        raise AssertionError("recomputed a run another run directory had finished")

    monkeypatch.setattr(heap_runner, "execute", no_simulation)
    monkeypatch.setenv("CALIB_REUSE", os.pathsep.join([str(tmp_path / "missing"), str(tmp_path / "a")]))
    b = run_campaign(relabelled, tmp_path / "b")
    cols = ["run_hash", "repose_angle", "angle_coords", "n_steps", "status", "wall_s"]
    pd.testing.assert_frame_equal(a[cols], b[cols])
    assert list(b["design"]) == ["other", "other"] and list(b["run_id"]) == [11, 12]
    for h in b["run_hash"]:
        assert (tmp_path / "b" / "simulate" / "runs" / h / "state.parquet").is_file()
    assert not list((tmp_path / "b" / "simulate" / "runs").glob(".*staging*"))
    with pytest.raises(AssertionError, match="recomputed"):  # --force: recompute, do not copy
        run_campaign(relabelled, tmp_path / "d", reuse=False)
    # a run that no directory named has finished is still computed
    monkeypatch.undo()
    monkeypatch.setenv("CALIB_REUSE", str(tmp_path / "b"))
    c = run_campaign([Request({"static_friction": 0.45}, TINY, TINY_NUM, derive_seed(0, 3, 0), "tiny", "", 3)],
                     tmp_path / "c")
    assert len(c) == 1 and c.iloc[0]["run_hash"] not in set(b["run_hash"])


def test_golden_heaps_the_committed_runs_name_come_out_bit_for_bit():
    """The golden heaps: cache keys name the physics (each contact law's version and the kernel's,
    calib_cli.heaps.keys.PHYSICS), not the bytes of the source, so a change of the kernel that keeps every version
    must compute the committed heaps bit for bit. Two committed smoke heaps (one cohesive, one not),
    rebuilt from their results rows (the per-run artefacts are not committed), keep their run hash and
    come out with the same step count, coordinate angle and its sd, heap height, base radius and largest
    overlap, to the last bit. On a machine other than the one that made them (the rows' `host`) a
    difference is no evidence against the claim: skipped there."""
    from calib_cli.heaps import keys
    from calib_cli.heaps.inputs import request_from_row

    res = pd.read_parquet(Path(__file__).resolve().parents[1] / "sample_runs" / "smoke" / "simulate" / "results.parquet")
    res = res[(res["source"] == keys.CACHE_SOURCE) & (res["engine"] == "builtin") & (res["status"] == "ok")]
    assert len(res), f"no committed smoke heap of the current physics {keys.CACHE_SOURCE}: raise no law's version " \
                     "without regenerating the sample runs"
    for row in (res[res["surface_energy"] > 0].iloc[0], res[res["surface_energy"] == 0].iloc[0]):
        req = request_from_row(row)
        assert req.hash == row["run_hash"]
        r = run_heap(req.params, req.condition, req.numerics, req.seed)
        a = r.angle
        got = (r.system.n_steps, a.angle, a.sd, a.height * 1e3, a.base_radius * 1e3, r.system.max_overlap)
        want = tuple(row[k] for k in ("n_steps", "angle_coords", "angle_coords_sd", "heap_height_mm",
                                      "base_radius_mm", "max_overlap"))
        if got != want and row["host"] != host():
            pytest.skip(f"the committed heaps were made on {row['host']}, this is {host()}")
        assert got == want, f"run {row['run_hash']}: {got} != {want}: the physics changed without a new version"


def test_cache_keys_name_law_versions_not_source_bytes():
    """A heap's key depends on keys.PHYSICS (each law's version, the kernel's), not on the source's
    bytes: every law at its first version keeps the committed heaps' name; a raised version renames."""
    from calib_cli.heaps import keys

    assert keys.CACHE_SOURCE == keys.cache_source(keys.PHYSICS) == "77675d5eca62"
    assert Request({"static_friction": 0.4}, TINY, TINY_NUM, 1).key["source"] == "77675d5eca62"
    bumped = keys.cache_source({**keys.PHYSICS, "rolling=sds": 2})
    assert bumped != "77675d5eca62" and bumped != keys.cache_source({**keys.PHYSICS, "kernel": "2"})


def test_raising_one_laws_version_renames_exactly_the_heaps_that_use_it(monkeypatch):
    """JKR at version 2: a cohesive heap (JKR) gets a new key and its old results row stops counting as
    current; a non-cohesive one (Hertz) keeps its key and row; the whole table's version moves too."""
    import dataclasses

    from calib_cli.dem.laws import REGISTRY
    from calib_cli.heaps import keys
    from calib_cli.heaps.index import current_sources

    wet, dry = ({"static_friction": 0.4, "surface_energy": e} for e in (0.5, 0.0))
    reqs = [Request(p, TINY, TINY_NUM, 1) for p in (wet, dry)]
    before = [r.hash for r in reqs]
    rows = pd.DataFrame([{**p, "source": r.source} for p, r in zip((wet, dry), reqs)])
    monkeypatch.setitem(REGISTRY["normal"], "jkr", dataclasses.replace(REGISTRY["normal"]["jkr"], version=2))
    after = [Request(p, TINY, TINY_NUM, 1).hash for p in (wet, dry)]
    assert after[0] != before[0] and after[1] == before[1]
    assert list(rows["source"] == current_sources(rows)) == [False, True]
    assert keys.cache_source(keys.physics()) != keys.CACHE_SOURCE


def test_the_benchmarks_paper_designs_are_the_papers_tables(monkeypatch):
    """`benchmarks/rolling_law.py --design pb|ascent|bbd` runs the paper's Tables 3, 5 and 7 at
    their own values (surface energy times --g-factor). The main effects from the paper's own
    angles are Table 4's sums of squares (15.10, 228.81, 56.25, 0.3008 = 12 b^2, static friction's
    negative) and Table 8's linear ones (28.88, 286.56 = 8 b^2)."""
    import argparse
    import importlib.util
    from pathlib import Path

    bench = Path(__file__).resolve().parents[1] / "benchmarks"
    monkeypatch.syspath_prepend(str(bench))  # rolling_law imports its sibling `factorial`
    spec = importlib.util.spec_from_file_location("rolling_law", bench / "rolling_law.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    from factorial import effects

    names, points, X, y = mod.design(argparse.Namespace(design="pb", g=None, g_factor=0.4))
    assert names == ["static_friction", "rolling_friction", "surface_energy", "restitution"]
    assert {p["surface_energy"] for p in points} == {0.2, 0.8} and {p["static_friction"] for p in points} == {0.05, 0.5}
    assert X.shape == (12, 4) and np.array_equal(X.T @ X, 12 * np.eye(4))  # orthogonal, as a PB design
    assert len({tuple(p.values()) for p in points}) == 11  # the paper ran its run 5 twice (run 8)
    b = effects(X, y[:, None])[1]
    np.testing.assert_allclose(12 * b**2, [15.10, 228.81, 56.25, 0.3008], rtol=5e-4)
    assert b[0] < 0

    names, points, X, y = mod.design(argparse.Namespace(design="bbd", g=None, g_factor=1.0))
    assert names == ["static_friction", "rolling_friction", "surface_energy"] and X.shape == (13, 3)
    assert {p["restitution"] for p in points} == {0.2}
    assert np.isclose(y[(X == 0).all(axis=1)][0], np.mean([34.93, 34.24, 34.37, 33.53, 32.47]))  # the centre runs
    np.testing.assert_allclose(8 * effects(X, y[:, None])[1][:2] ** 2, [28.88, 286.56], rtol=5e-4)

    names, points, X, y = mod.design(argparse.Namespace(design="ascent", g=None, g_factor=0.4))
    assert X is None and len(points) == 5 and points[-1]["surface_energy"] == 0.8 and y[-1] == 46.85
    names, points, X, y = mod.design(argparse.Namespace(design="factorial", g="0.3,0.7", g_factor=0.4))
    assert y is None and X.shape == (8, 3) and {p["surface_energy"] for p in points} == {0.3, 0.7}


def test_a_design_that_drags_the_floors_friction_along_is_pointed_out():
    """simulate-heap notes when the runs vary the grains' static friction and the floor's follows
    it; not when the floor's (or all walls') friction is given, nor for runs at one friction."""
    from calib_cli.stages.simulate import floor_follows_grains

    def reqs(cond=TINY, **extra):
        return [interactions({"static_friction": mu, **extra}, cond) for mu in [0.3, 0.6]]

    assert floor_follows_grains(reqs())
    assert not floor_follows_grains(reqs()[:1])
    assert not floor_follows_grains(reqs(wall_static_friction=0.5))
    assert not floor_follows_grains(reqs(replace(TINY, floor_static_friction=0.5)))
    assert floor_follows_grains(reqs(cylinder_static_friction=0.5))  # the cylinder's own value leaves the floor tied


def test_cohesive_grains_below_the_stiff_reference_modulus_are_pointed_out():
    """simulate-heap notes that a cohesive calibration depends on the modulus when the grains are
    cohesive and softer than the stiff reference; the ratio is the JKR work of separation's G^-2/3."""
    from calib_cli.stages.simulate import STIFF_REFERENCE, cohesion_modulus_note

    def walls(g):
        return [interactions({"surface_energy": g, "static_friction": 0.3}, TINY)]

    note = cohesion_modulus_note(walls(0.5), 5e6)
    assert "5 MPa" in note and "21.5x" in note and "heap.shear_modulus in its settings.toml" in note
    assert "4.64x" in cohesion_modulus_note(walls(0.5), 5e7)
    assert cohesion_modulus_note(walls(0.5), STIFF_REFERENCE) == ""
    assert cohesion_modulus_note(walls(0.0), 5e6) == ""
    assert cohesion_modulus_note(walls(0.0) + walls(0.5), 5e6) != ""  # a design that reaches cohesion


def test_a_design_listing_one_point_twice_computes_it_once(tmp_path):
    """Two requests with one hash (a design that repeats a row) in one parallel campaign: one folder,
    computed once, and a results row under each request's labels (two workers renaming one folder was
    an internal error)."""
    req = Request({"static_friction": 0.45}, TINY, TINY_NUM, derive_seed(0, 1, 0), "tiny", "pb", 1)
    twin = Request({"static_friction": 0.45}, TINY, TINY_NUM, derive_seed(0, 1, 0), "tiny", "pb", 2)
    assert req.hash == twin.hash
    rows = run_campaign([req, twin], tmp_path, workers=2)
    assert sorted(rows["run_id"]) == [1, 2] and rows["run_hash"].nunique() == 1
    assert [p.name for p in (tmp_path / "simulate" / "runs").iterdir() if not p.name.startswith(".")] == [req.hash]


@pytest.mark.parametrize("edit, words", [
    (lambda d: d.assign(repose_angle=d["repose_angle"].astype(str)), "repose_angle hold text where numbers belong"),
    (lambda d: d.assign(static_friction="0.3"), "static_friction hold text where numbers belong"),
    # NaN in a condition variable broke the surrogate's linear algebra (exit 70); 400 deg was fitted as a heap
    (lambda d: d.assign(fill_height_mm=[float("nan"), *d["fill_height_mm"].iloc[1:]]),
     "fill_height_mm have an empty or infinite value"),
    (lambda d: d.assign(repose_angle=[400.0, *d["repose_angle"].iloc[1:]]), "repose_angle 400 deg (row 0) is outside"),
    (lambda d: d.rename(columns={"repose_angle": "angle"}), "no column repose_angle"),
    (lambda d: d.assign(fill_height_mm=["abc", *d["fill_height_mm"].iloc[1:].astype(str)]),
     "fill_height_mm hold text where numbers belong"),
])
def test_a_results_index_edited_into_another_shape_is_one_line(tmp_path, edit, words):
    import shutil

    run = tmp_path / "run"
    smoke = Path(__file__).resolve().parents[1] / "sample_runs" / "smoke"
    shutil.copytree(smoke / "simulate", run / "simulate", ignore=shutil.ignore_patterns("runs"))
    shutil.copy(smoke / "settings.toml", run / "settings.toml")
    path = run / "simulate" / "results.parquet"
    edit(pd.read_parquet(path)).to_parquet(path)
    with pytest.raises(CalibError, match=r"simulation results .*" + re.escape(words)):
        load_results(run)
    r = runner.invoke(app, ["diff-runs", str(run), str(run)])
    assert r.exit_code == 2 and words in " ".join(r.output.split()), r.output


def test_a_dask_address_where_another_service_answers_is_one_line():
    """An SSH server at --dask's address: its banner, read as a Dask frame's length, asked for exabytes
    (MemoryError, exit 70); now one line saying the address did not answer as a scheduler."""
    import socket
    import threading

    from calib_cli.errors import CalibError
    from calib_cli.heaps.runner import _client

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)

    def banner():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.sendall(b"SSH-2.0-OpenSSH_9.2p1 Debian-2\r\n" * 4)

    threading.Thread(target=banner, daemon=True).start()
    try:
        with pytest.raises(CalibError, match=r"did not answer as a Dask scheduler \(\w+"):
            _client(f"tcp://127.0.0.1:{server.getsockname()[1]}", None)
    finally:
        server.close()
