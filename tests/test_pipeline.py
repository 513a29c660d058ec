"""Declared pipelines (stages/*.toml, `calib run`): file checks, the shipped chains, a run and its rerun."""

import json
import os
import shlex
import shutil
import subprocess

import pytest
from typer.testing import CliRunner

from calib_cli import artifacts as art
from calib_cli.cli import app, command_root
from calib_cli.cli.pipeline import UP_TO_DATE, execute, load_pipeline, parse_vars, plan
from calib_cli.errors import CalibError
from conftest import ROOT

ROOT_CMD = command_root()  # the `calib` command line a pipeline checks and runs its steps with

runner = CliRunner()

# What each chain target of the Makefile ran before its chains became pipeline files (`make -n` of the
# Makefile of 838c284, whose settings paths already were stages/settings/): a shipped pipeline must
# not drift from it. The lab targets also exported CALIB_REUSE (below). hidden-effect and control-lab:
# what they run since the calibration in rounds replaced their Box-Behnken chain. compare: `--seeds table` since
# the default seeding became the condition's values (the row's, which these runs were made with, before).
OLD_MAKEFILE = {
    "paper": """
calib init --run sample_runs/paper --settings stages/settings/paper.toml
calib measure-angle --run sample_runs/paper --angles sample_data/paper/table1_angles.csv
calib pb design --run sample_runs/paper
calib pb analyze --run sample_runs/paper --responses sample_data/paper/table3_pb.csv
calib ascent design --run sample_runs/paper
calib ascent analyze --run sample_runs/paper --responses sample_data/paper/table5_ascent.csv
calib bbd design --run sample_runs/paper
calib bbd analyze --run sample_runs/paper --responses sample_data/paper/table7_bbd.csv
calib fit-surrogate --run sample_runs/paper
calib invert --run sample_runs/paper
calib report --run sample_runs/paper
""",
    "smoke": """
calib init --run sample_runs/smoke --settings stages/settings/smoke.toml
calib measure-angle --run sample_runs/smoke --images sample_data/photos --conditions sample_data/photos/conditions.csv
calib pb design --run sample_runs/smoke
calib simulate-heap --run sample_runs/smoke --design sample_runs/smoke/pb/design.parquet --preset smoke --workers 2
calib pb analyze --run sample_runs/smoke
calib ascent design --run sample_runs/smoke
calib simulate-heap --run sample_runs/smoke --design sample_runs/smoke/ascent/design.parquet --preset smoke --workers 2
calib ascent analyze --run sample_runs/smoke
calib bbd design --run sample_runs/smoke
calib simulate-heap --run sample_runs/smoke --design sample_runs/smoke/bbd/design.parquet --preset smoke --workers 2
calib bbd analyze --run sample_runs/smoke
calib fit-surrogate --run sample_runs/smoke
calib invert --run sample_runs/smoke --validate 3 --preset smoke --workers 2
calib compare --run sample_runs/smoke --seeds table --repeats 3 --preset smoke --workers 2
calib report --run sample_runs/smoke
""",
    "calibration": """
calib init --run sample_runs/calibration --settings stages/settings/calibration.toml
calib measure-angle --run sample_runs/calibration --images sample_data/calibration --conditions sample_data/calibration/conditions.csv
calib pb design --run sample_runs/calibration
calib simulate-heap --run sample_runs/calibration --design sample_runs/calibration/pb/design.parquet --conditions sample_runs/calibration/measure/conditions.parquet --preset default --workers 2 
calib pb analyze --run sample_runs/calibration
calib ascent design --run sample_runs/calibration
calib simulate-heap --run sample_runs/calibration --design sample_runs/calibration/ascent/design.parquet --conditions sample_runs/calibration/measure/conditions.parquet --preset default --workers 2 
calib ascent analyze --run sample_runs/calibration
calib bbd design --run sample_runs/calibration
calib simulate-heap --run sample_runs/calibration --design sample_runs/calibration/bbd/design.parquet --conditions sample_runs/calibration/measure/conditions.parquet --preset default --workers 2 
calib bbd analyze --run sample_runs/calibration
calib fit-surrogate --run sample_runs/calibration
calib invert --run sample_runs/calibration --validate 5 --preset default --workers 2
calib compare --run sample_runs/calibration --seeds table --repeats 3 --preset default --workers 2
calib report --run sample_runs/calibration
""",
    "calibration-spring": """
calib init --run sample_runs/calibration-spring --settings stages/settings/calibration.toml
calib measure-angle --run sample_runs/calibration-spring --images sample_data/calibration --conditions sample_data/calibration/conditions.csv
calib pb design --run sample_runs/calibration-spring
calib simulate-heap --run sample_runs/calibration-spring --design sample_runs/calibration-spring/pb/design.parquet --conditions sample_runs/calibration-spring/measure/conditions.parquet --preset default --workers 2 --set rolling_spring=1
calib pb analyze --run sample_runs/calibration-spring
calib ascent design --run sample_runs/calibration-spring
calib simulate-heap --run sample_runs/calibration-spring --design sample_runs/calibration-spring/ascent/design.parquet --conditions sample_runs/calibration-spring/measure/conditions.parquet --preset default --workers 2 --set rolling_spring=1
calib ascent analyze --run sample_runs/calibration-spring
calib bbd design --run sample_runs/calibration-spring
calib simulate-heap --run sample_runs/calibration-spring --design sample_runs/calibration-spring/bbd/design.parquet --conditions sample_runs/calibration-spring/measure/conditions.parquet --preset default --workers 2 --set rolling_spring=1
calib bbd analyze --run sample_runs/calibration-spring
calib fit-surrogate --run sample_runs/calibration-spring
calib invert --run sample_runs/calibration-spring --validate 5 --preset default --workers 2
calib compare --run sample_runs/calibration-spring --seeds table --repeats 3 --preset default --workers 2
calib report --run sample_runs/calibration-spring
""",
    "hidden-effect": """
calib synth-lab --out sample_runs/hidden-effect/lab --set static_friction=0.45 --set rolling_friction=0.15 --set restitution=0.3 --set surface_energy=0.6 --hidden cohesion --sizes 4-5,5-6 --cylinders 40 --fills 50,75,100 --repeats 10 --preset default --workers 2
calib init --run sample_runs/hidden-effect --settings stages/settings/hidden-effect.toml
calib measure-angle --run sample_runs/hidden-effect --images sample_runs/hidden-effect/lab --conditions sample_runs/hidden-effect/lab/conditions.csv
calib calibrate --run sample_runs/hidden-effect --at-revision 0 --budget 72 --preset default --workers 2
calib compare --run sample_runs/hidden-effect --seeds table --at-revision 0 --repeats 4 --preset default --workers 2
calib diagnose --run sample_runs/hidden-effect --at-revision 0 --repeats 2 --preset default --workers 2
calib model add cohesion --run sample_runs/hidden-effect --at-revision 0
calib calibrate --run sample_runs/hidden-effect --at-revision 1 --budget 250 --side-views --preset default --workers 2
calib compare --run sample_runs/hidden-effect --seeds table --at-revision 1 --repeats 4 --preset default --workers 2
calib suggest-conditions --run sample_runs/hidden-effect --rig sample_data/rig.toml --top 3
calib report --run sample_runs/hidden-effect
""",
    "control-lab": """
calib synth-lab --out sample_runs/control-lab/lab --set static_friction=0.45 --set rolling_friction=0.15 --set restitution=0.3 --set surface_energy=0 --hidden none --sizes 4-5,5-6 --cylinders 40 --fills 50,75,100 --repeats 10 --preset default --workers 2
calib init --run sample_runs/control-lab --settings stages/settings/hidden-effect.toml
calib measure-angle --run sample_runs/control-lab --images sample_runs/control-lab/lab --conditions sample_runs/control-lab/lab/conditions.csv
calib calibrate --run sample_runs/control-lab --at-revision 0 --budget 72 --preset default --workers 2
calib compare --run sample_runs/control-lab --seeds table --at-revision 0 --repeats 4 --preset default --workers 2
calib diagnose --run sample_runs/control-lab --at-revision 0 --repeats 2 --preset default --workers 2
calib model add cohesion --run sample_runs/control-lab --at-revision 0
calib calibrate --run sample_runs/control-lab --at-revision 1 --budget 250 --side-views --preset default --workers 2
calib compare --run sample_runs/control-lab --seeds table --at-revision 1 --repeats 4 --preset default --workers 2
calib suggest-conditions --run sample_runs/control-lab --rig sample_data/rig.toml --top 3
calib report --run sample_runs/control-lab
""",
    "hidden-wall": """
calib synth-lab --out sample_runs/hidden-wall/lab --set static_friction=0.45 --set rolling_friction=0.15 --set restitution=0.3 --set surface_energy=0 --set wall_static_friction=0.2 --hidden wall_friction --sizes 4-5,5-6 --cylinders 40 --fills 50,75,100 --repeats 10 --preset default --workers 2
calib init --run sample_runs/hidden-wall --settings stages/settings/hidden-effect.toml
calib measure-angle --run sample_runs/hidden-wall --images sample_runs/hidden-wall/lab --conditions sample_runs/hidden-wall/lab/conditions.csv
calib bbd design --run sample_runs/hidden-wall
calib simulate-heap --run sample_runs/hidden-wall --design sample_runs/hidden-wall/bbd/design.parquet --conditions sample_runs/hidden-wall/measure/conditions.parquet --preset default --workers 2
calib fit-surrogate --run sample_runs/hidden-wall --from-simulations bbd
calib invert --run sample_runs/hidden-wall --validate 4 --refine 2 --preset default --workers 2
calib compare --run sample_runs/hidden-wall --seeds table --repeats 8 --preset default --workers 2
calib diagnose --run sample_runs/hidden-wall --repeats 6 --preset default --workers 2
calib model add wall_friction --run sample_runs/hidden-wall
calib bbd design --run sample_runs/hidden-wall -s 'bbd.factors=["static_friction","rolling_friction","wall_static_friction"]' -s factors.wall_static_friction.low=0.2 -s factors.wall_static_friction.high=0.4
calib simulate-heap --run sample_runs/hidden-wall --design sample_runs/hidden-wall/bbd/design.parquet --conditions sample_runs/hidden-wall/measure/conditions.parquet --preset default --workers 2
calib fit-surrogate --run sample_runs/hidden-wall --from-simulations bbd -s 'bbd.factors=["static_friction","rolling_friction","wall_static_friction"]' -s factors.wall_static_friction.low=0.2 -s factors.wall_static_friction.high=0.4
calib invert --run sample_runs/hidden-wall --validate 4 --refine 2 --preset default --workers 2 -s 'bbd.factors=["static_friction","rolling_friction","wall_static_friction"]' -s factors.wall_static_friction.low=0.2 -s factors.wall_static_friction.high=0.4
calib compare --run sample_runs/hidden-wall --seeds table --set restitution=0.3 --repeats 8 --preset default --workers 2
calib report --run sample_runs/hidden-wall
""",
    "hidden-floor": """
calib synth-lab --out sample_runs/hidden-floor/lab --set static_friction=0.45 --set rolling_friction=0.15 --set restitution=0.3 --set surface_energy=0 --set wall_rolling_friction=0.4 --hidden wall_rolling --sizes 4-5,5-6 --cylinders 40 --fills 50,75,100 --repeats 10 --preset default --workers 2
calib init --run sample_runs/hidden-floor --settings stages/settings/hidden-effect.toml
calib measure-angle --run sample_runs/hidden-floor --images sample_runs/hidden-floor/lab --conditions sample_runs/hidden-floor/lab/conditions.csv
calib bbd design --run sample_runs/hidden-floor
calib simulate-heap --run sample_runs/hidden-floor --design sample_runs/hidden-floor/bbd/design.parquet --conditions sample_runs/hidden-floor/measure/conditions.parquet --preset default --workers 2
calib fit-surrogate --run sample_runs/hidden-floor --from-simulations bbd
calib invert --run sample_runs/hidden-floor --validate 4 --refine 2 --preset default --workers 2
calib compare --run sample_runs/hidden-floor --seeds table --repeats 8 --preset default --workers 2
calib diagnose --run sample_runs/hidden-floor --repeats 6 --preset default --workers 2
calib model add wall_rolling --run sample_runs/hidden-floor
calib bbd design --run sample_runs/hidden-floor -s 'bbd.factors=["static_friction","rolling_friction","wall_rolling_friction"]' -s factors.wall_rolling_friction.low=0.1 -s factors.wall_rolling_friction.high=0.5
calib simulate-heap --run sample_runs/hidden-floor --design sample_runs/hidden-floor/bbd/design.parquet --conditions sample_runs/hidden-floor/measure/conditions.parquet --preset default --workers 2
calib fit-surrogate --run sample_runs/hidden-floor --from-simulations bbd -s 'bbd.factors=["static_friction","rolling_friction","wall_rolling_friction"]' -s factors.wall_rolling_friction.low=0.1 -s factors.wall_rolling_friction.high=0.5
calib invert --run sample_runs/hidden-floor --validate 4 --refine 2 --preset default --workers 2 -s 'bbd.factors=["static_friction","rolling_friction","wall_rolling_friction"]' -s factors.wall_rolling_friction.low=0.1 -s factors.wall_rolling_friction.high=0.5
calib compare --run sample_runs/hidden-floor --seeds table --set restitution=0.3 --repeats 8 --preset default --workers 2
calib report --run sample_runs/hidden-floor
""",
    "default-bbd": """
calib init --run sample_runs/default-bbd --settings stages/settings/paper.toml
calib measure-angle --run sample_runs/default-bbd --angles sample_data/paper/table1_angles.csv
calib pb design --run sample_runs/default-bbd
calib pb analyze --run sample_runs/default-bbd --responses sample_data/paper/table3_pb.csv
calib ascent design --run sample_runs/default-bbd
calib ascent analyze --run sample_runs/default-bbd --responses sample_data/paper/table5_ascent.csv
calib bbd design --run sample_runs/default-bbd
calib simulate-heap --run sample_runs/default-bbd --design sample_runs/default-bbd/bbd/design.parquet --preset default --workers 2
calib bbd analyze --run sample_runs/default-bbd
calib report --run sample_runs/default-bbd
""",
    "default-bbd-half-g": """
calib init --run sample_runs/default-bbd-half-g --settings stages/settings/paper.toml
calib measure-angle --run sample_runs/default-bbd-half-g --angles sample_data/paper/table1_angles.csv
calib pb design --run sample_runs/default-bbd-half-g
calib pb analyze --run sample_runs/default-bbd-half-g --responses sample_data/paper/table3_pb.csv
calib ascent design --run sample_runs/default-bbd-half-g
calib ascent analyze --run sample_runs/default-bbd-half-g --responses sample_data/paper/table5_ascent.csv
calib bbd design --run sample_runs/default-bbd-half-g -s 'bbd.ranges.surface_energy=[0.4375,0.8125]'
calib simulate-heap --run sample_runs/default-bbd-half-g --design sample_runs/default-bbd-half-g/bbd/design.parquet --preset default --workers 2
calib bbd analyze --run sample_runs/default-bbd-half-g
calib report --run sample_runs/default-bbd-half-g
""",
    "default-bbd-stiff": """
calib init --run sample_runs/default-bbd-stiff --settings stages/settings/paper.toml
calib measure-angle --run sample_runs/default-bbd-stiff --angles sample_data/paper/table1_angles.csv
calib pb design --run sample_runs/default-bbd-stiff
calib pb analyze --run sample_runs/default-bbd-stiff --responses sample_data/paper/table3_pb.csv
calib ascent design --run sample_runs/default-bbd-stiff
calib ascent analyze --run sample_runs/default-bbd-stiff --responses sample_data/paper/table5_ascent.csv
calib bbd design --run sample_runs/default-bbd-stiff
calib simulate-heap --run sample_runs/default-bbd-stiff --design sample_runs/default-bbd-stiff/bbd/design.parquet --preset default --workers 2 --shear-modulus 5e8 
calib bbd analyze --run sample_runs/default-bbd-stiff
calib report --run sample_runs/default-bbd-stiff
""",
    "default-bbd-50mpa": """
calib init --run sample_runs/default-bbd-50mpa --settings stages/settings/paper.toml
calib measure-angle --run sample_runs/default-bbd-50mpa --angles sample_data/paper/table1_angles.csv
calib pb design --run sample_runs/default-bbd-50mpa
calib pb analyze --run sample_runs/default-bbd-50mpa --responses sample_data/paper/table3_pb.csv
calib ascent design --run sample_runs/default-bbd-50mpa
calib ascent analyze --run sample_runs/default-bbd-50mpa --responses sample_data/paper/table5_ascent.csv
calib bbd design --run sample_runs/default-bbd-50mpa
calib simulate-heap --run sample_runs/default-bbd-50mpa --design sample_runs/default-bbd-50mpa/bbd/design.parquet --preset default --workers 2 --shear-modulus 5e7 
calib bbd analyze --run sample_runs/default-bbd-50mpa
calib report --run sample_runs/default-bbd-50mpa
""",
    "default-bbd-150mpa": """
calib init --run sample_runs/default-bbd-150mpa --settings stages/settings/paper.toml
calib measure-angle --run sample_runs/default-bbd-150mpa --angles sample_data/paper/table1_angles.csv
calib pb design --run sample_runs/default-bbd-150mpa
calib pb analyze --run sample_runs/default-bbd-150mpa --responses sample_data/paper/table3_pb.csv
calib ascent design --run sample_runs/default-bbd-150mpa
calib ascent analyze --run sample_runs/default-bbd-150mpa --responses sample_data/paper/table5_ascent.csv
calib bbd design --run sample_runs/default-bbd-150mpa
calib simulate-heap --run sample_runs/default-bbd-150mpa --design sample_runs/default-bbd-150mpa/bbd/design.parquet --preset default --workers 2 --shear-modulus 1.5e8 --repeats 2
calib bbd analyze --run sample_runs/default-bbd-150mpa
calib report --run sample_runs/default-bbd-150mpa
""",
    "default-bbd-walls": """
calib init --run sample_runs/default-bbd-walls --settings stages/settings/paper.toml
calib measure-angle --run sample_runs/default-bbd-walls --angles sample_data/paper/table1_angles.csv
calib pb design --run sample_runs/default-bbd-walls
calib pb analyze --run sample_runs/default-bbd-walls --responses sample_data/paper/table3_pb.csv
calib ascent design --run sample_runs/default-bbd-walls
calib ascent analyze --run sample_runs/default-bbd-walls --responses sample_data/paper/table5_ascent.csv
calib bbd design --run sample_runs/default-bbd-walls
calib simulate-heap --run sample_runs/default-bbd-walls --design sample_runs/default-bbd-walls/bbd/design.parquet --preset default --workers 2 --shear-modulus 5e8 --set wall_static_friction=0.5 --set wall_rolling_friction=0.1
calib bbd analyze --run sample_runs/default-bbd-walls
calib report --run sample_runs/default-bbd-walls
""",
}
REUSE = {"control-lab": "sample_runs/hidden-effect", "hidden-wall": "sample_runs/hidden-effect",
         "hidden-floor": "sample_runs/hidden-effect"}


def calib(*args):
    return runner.invoke(app, [str(a) for a in args])


def one_error(r, *fragments):
    """Exit 2 with one error line holding every fragment, and no traceback or internal error."""
    assert r.exit_code == 2, r.output
    errors = [line for line in r.output.splitlines() if "error" in line]
    assert len(errors) == 1 and errors[0].startswith("error: "), r.output
    assert "internal error" not in r.output and "Traceback" not in r.output
    for f in fragments:
        assert f in errors[0], errors[0]
    return errors[0]


@pytest.fixture
def at_root(monkeypatch):
    """The shipped pipelines' paths are relative to the repository root, as `make` runs them."""
    monkeypatch.chdir(ROOT)


def make_call(target):
    """The `calib run` line that `make -n TARGET` shows, as arguments after `calib`."""
    out = subprocess.run(["make", "-s", "-n", target, "CALIB=calib"], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout
    lines = [shlex.split(line) for line in out.splitlines() if line.startswith("calib run ")]
    assert len(lines) == 1, out  # one line per chain target
    return lines[0][1:]


def test_ctrl_c_between_two_steps_is_an_interrupted_pipeline_not_an_error(tmp_path, at_root):
    from calib_cli.cli.pipeline import PipelineInterrupted

    def stop(i, res):
        raise KeyboardInterrupt

    with pytest.raises(PipelineInterrupted) as e:
        execute(plan(load_pipeline(write(tmp_path, GOOD), tmp_path / "run", root=ROOT_CMD)), on_done=stop)
    assert e.value.step.name == "init" and (tmp_path / "run" / "settings.toml").is_file()


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
@pytest.mark.parametrize("target", sorted(OLD_MAKEFILE))
def test_shipped_pipeline_runs_what_the_makefile_ran(target, at_root):
    args = make_call(target)
    r = runner.invoke(app, [*args, "--dry-run"])
    assert r.exit_code == 0, r.output
    lines = [line for line in r.output.splitlines() if line and not line.startswith("#")]
    env = dict(line.removeprefix("export ").split("=", 1) for line in lines if line.startswith("export "))
    commands = [shlex.split(line, comments=True) for line in lines if not line.startswith("export ")]
    assert commands == [shlex.split(line) for line in OLD_MAKEFILE[target].strip().splitlines()]
    assert env == ({"CALIB_REUSE": REUSE[target]} if target in REUSE else {})


def test_every_pipeline_file_loads(at_root):
    for path in sorted((ROOT / "stages").glob("*.toml")):
        p = plan(load_pipeline(path.relative_to(ROOT), "somewhere", root=ROOT_CMD))
        assert p.steps and all(s.outputs for s in p.steps)
        inside = [x for x in p.external if x.startswith("somewhere/")]
        assert all(os.path.exists(x) for x in p.external if x not in inside), p.external
        # only revision 1 of a lab reads what another pipeline (stages/lab.toml) wrote into the run
        assert not inside or path.name in ("lab-rev1.toml", "rounds-rev1.toml"), inside


GOOD = '''
[vars]
data = "sample_data/paper"
extra = []

[[step]]
name = "init"
command = ["init", "--run", "{run}"]
settings = "stages/settings/paper.toml"
outputs = ["{run}/settings.toml"]
'''


def write(tmp_path, text, name="p.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, args, fragments", [
    ("[[step]]\nname = 'a'\noutputs = ['x']\n", [], ["step a", "lacks command"]),
    ("[[step]]\nname = 'a'\ncommand = ['pb', 'design', '--run', '{run}']\n", [], ["step a", "lacks outputs"]),
    ("[[step]]\ncommand = ['report', '--run', '{run}']\noutputs = ['x']\n", [], ["step 1", "lacks name"]),
    ("[[step]]\nname = 'a'\ncommand = ['pb', 'desgn']\noutputs = ['x']\n", [], ["unknown command 'calib pb desgn'"]),
    ("[[step]]\nname = 'a'\ncommand = ['fly', '--run', '{run}']\noutputs = ['x']\n", [], ["unknown command"]),
    ("[[step]]\nname = 'a'\ncommand = ['pb', 'design', '--runn', '{run}']\noutputs = ['x']\n", [],
     ["step a", "calib pb design", "--runn"]),
    ("[[step]]\nname = 'a'\ncommand = ['run', 'x.toml', '--run', '{run}']\noutputs = ['x']\n", [],
     ["cannot run another pipeline"]),
    ("[[step]]\nname = 'a'\ncommand = ['report', '--run', '{rnu}']\noutputs = ['x']\n", [],
     ["unknown variable {rnu}"]),
    ("[vars]\nextra = []\n[[step]]\nname = 'a'\ncommand = ['report', '--run', '{run}/{extra}']\noutputs = ['x']\n",
     [], ["{extra} is a list"]),
    ("[[step]]\nname = 'a'\ncommand = ['report', '--run', '{run}']\noutputs = ['x']\nbogus = 1\n", [],
     ["unknown key(s) bogus"]),
    ("[[step]]\nname = 'a'\ncommand = ['report', '--run', 3]\noutputs = ['x']\n", [], ["strings only"]),
    ("[[step]]\nname = 'a'\ncommand = ['report', '--run', '{run}']\noutputs = ['x']\n" * 2, [],
     ["two steps are named 'a'"]),
    ("[[step]]\nname = 'a'\ncommand = ['report', '--run', '{run}']\ninputs = ['{run}/b']\noutputs = ['{run}/a']\n"
     "[[step]]\nname = 'b'\ncommand = ['report', '--run', '{run}']\noutputs = ['{run}/b']\n", [],
     ["step 'a' reads", "only the later step 'b' writes"]),
    ("[[step]]\nname = 'a'\ncommand = ['report', '--run', '{run}']\ninputs = ['{run}/a']\noutputs = ['{run}/a']\n",
     [], ["only itself writes"]),
    ("[[step]]\ninclude = 'p.toml'\n", [], ["included by itself"]),
    ("[[step]\n", [], ["not valid TOML"]),
    ("title = 'x'\n", [], ["unknown key(s) title"]),
    (GOOD, ["--var", "dta=x"], ["unknown variable(s) dta"]),
    (GOOD, ["--var", "data"], ["not KEY=VALUE"]),
    (GOOD, ["--var", "run=x"], ["'run' is the run directory"]),
    (GOOD.replace("stages/settings/paper.toml", "nowhere.toml"), [], ["step 'init' reads nowhere.toml",
                                                                      "does not exist"]),
    ("[[step]]\nname = 'a'\ncommand = ['init', '--run', '{run}', '--help']\noutputs = ['x']\n", [],
     ["step a", "is given --help, which runs nothing"]),
    # what os.environ, the file system or tomllib would raise on (exit 70 before)
    ('[env]\n"A=B" = "x"\n' + GOOD.split("\n", 4)[-1], [], ["[env] name 'A=B' is not an environment variable's"]),
    ('[env]\nA = "x\\u0000y"\n' + GOOD.split("\n", 4)[-1], [], ["[env] A holds a NUL character"]),
    ('[[step]]\ninclude = "a\\u0000b.toml"\n', [], ["pipeline file not found"]),
    (f"[[step]]\ninclude = '{'a' * 300}.toml'\n", [], ["cannot be read", "File name too long"]),
    ("description = { a = 1 }\n" + GOOD.split("\n", 4)[-1], [], ["description must be a string, got dict"]),
    ("[[step]]\ninclude = 'inner.toml'\nvars = { data = { a = 1 } }\n", [], ["variable data", "got {'a': 1}"]),
    ("[[step]]\nname = 'a'\ncommand = ['report', '--run', \"{run}\\u0000\"]\noutputs = ['x']\n", [],
     ["step a", "holds a NUL character"]),
])
def test_a_bad_pipeline_is_one_error_line(tmp_path, at_root, text, args, fragments):
    (tmp_path / "inner.toml").write_text(GOOD)
    path = write(tmp_path, text)
    one_error(calib("run", path, "--run", tmp_path / "run", *args), *fragments)
    assert not (tmp_path / "run").exists()  # checked before anything ran


def test_an_included_files_description_is_checked_as_the_top_files(tmp_path, at_root):
    (tmp_path / "inner.toml").write_text("description = 3\n" + GOOD.split("\n", 4)[-1])
    path = write(tmp_path, "[[step]]\ninclude = 'inner.toml'\n")
    one_error(calib("run", path, "--run", tmp_path / "run"), "inner.toml: description must be a string, got int")
    assert not (tmp_path / "run").exists()


def test_the_pipeline_holds_its_run_directory_from_its_first_step_to_its_last(tmp_path, at_root):
    """A second command (another pipeline with other variables) cannot write the run between two steps: the
    lock is taken before the first step and names this pipeline."""
    run, seen = tmp_path / "run", []
    execute(plan(load_pipeline(write(tmp_path, GOOD), run, root=ROOT_CMD)),
            on_start=lambda i, step: seen.append((run / ".lock").read_text()))
    assert seen and seen[0].startswith(f"pid {os.getpid()}:")


def test_an_edited_settings_file_of_the_pipeline_replaces_the_run_s_copy_a_hand_edit_does_not(tmp_path, at_root):
    """`calib run` again after an edit redoes what changed, the settings file included; an edit made to the
    run's own copy is not overwritten without --force."""
    settings = tmp_path / "mine.toml"
    shutil.copy("stages/settings/paper.toml", settings)
    path = write(tmp_path, GOOD.replace("stages/settings/paper.toml", str(settings)))
    run = tmp_path / "run"
    assert calib("run", path, "--run", run).exit_code == 0
    settings.write_text(settings.read_text().replace("alpha = 0.05", "alpha = 0.01", 1))
    r = calib("run", path, "--run", run)
    assert r.exit_code == 0 and "1 ran" in r.output, r.output
    assert (run / "settings.toml").read_text() == settings.read_text()
    with open(run / "settings.toml", "a") as f:
        f.write("# my note\n")
    settings.write_text(settings.read_text().replace("alpha = 0.01", "alpha = 0.02", 1))
    one_error(calib("run", path, "--run", run), "exists and differs from --settings: give --force")
    assert (run / "settings.toml").read_text().endswith("# my note\n")


def test_an_override_under_a_table_the_settings_declare_is_set_in_it(tmp_path):
    """-s pb.alpha=0.1 beside the file's [pb] table, and -s target=33 where the file sets target: TOML cannot
    take them as dotted keys in front, so the file is written out whole with them set, its text kept below."""
    from calib_cli.settings import load_settings

    run = tmp_path / "run"
    r = calib("init", "--run", run, "--settings", ROOT / "stages/settings/paper.toml", "-s", "pb.alpha=0.1",
              "-s", "target=33")
    assert r.exit_code == 0, r.output
    s = load_settings([run / "settings.toml"])
    assert s["pb"]["alpha"] == 0.1 and s["target"] == 33 and s["bbd"] == load_settings(
        [ROOT / "stages/settings/paper.toml"])["bbd"]
    assert "# the settings file as given:" in (run / "settings.toml").read_text()


def test_a_missing_pipeline_file_is_one_error_line(tmp_path):
    one_error(calib("run", tmp_path / "nope.toml", "--run", tmp_path / "run"), "pipeline file not found")


def test_a_failing_step_is_named_and_the_steps_before_it_stay_done(tmp_path, at_root):
    text = GOOD + ('[[step]]\nname = "measure"\ncommand = ["measure-angle", "--run", "{run}", "--angles", '
                   '"{run}/missing.csv"]\noutputs = ["{run}/measure/conditions.parquet"]\n')
    r = calib("run", write(tmp_path, text), "--run", tmp_path / "run")
    line = one_error(r, "step 'measure' (calib measure-angle --run", "missing.csv", "rerun to resume")
    assert "1 of 2 steps" in r.output and (tmp_path / "run" / "settings.toml").is_file(), line


def test_a_step_that_does_not_write_its_declared_output_fails(tmp_path, at_root):
    text = GOOD.replace('outputs = ["{run}/settings.toml"]', 'outputs = ["{run}/settings.toml", "{run}/other"]')
    one_error(calib("run", write(tmp_path, text), "--run", tmp_path / "run"),
              "step 'init'", "without writing its declared output(s)", "other")


def test_variables_lists_and_optional_groups(tmp_path, at_root):
    text = GOOD + ('[[step]]\nname = "sim"\ncommand = ["simulate-heap", "--run", "{run}", "{extra}", '
                   '{ when = "g", args = ["--shear-modulus", "{g}"] }]\noutputs = ["{run}/simulate"]\n')
    text = text.replace('extra = []', 'extra = []\ng = ""')
    p = tmp_path / "p.toml"
    p.write_text(text)
    assert plan(load_pipeline(p, "R", root=ROOT_CMD)).commands()[1] == ["simulate-heap", "--run", "R"]
    got = plan(load_pipeline(p, "R", {"extra": "--repeats 2 --set 'a=1 2'", "g": "5e8"}, root=ROOT_CMD)).commands()[1]
    assert got == ["simulate-heap", "--run", "R", "--repeats", "2", "--set", "a=1 2", "--shear-modulus", "5e8"]
    with pytest.raises(CalibError, match="unknown variable"):
        load_pipeline(p, "R", {"nope": "1"}, root=ROOT_CMD)


def tree(d):
    return {p.relative_to(d): art.file_hash(p) for p in sorted(d.rglob("*")) if p.is_file()}


def test_paper_pipeline_runs_then_is_up_to_date(tmp_path, at_root):
    run = tmp_path / "paper"
    r = calib("run", "stages/paper.toml", "--run", run)
    assert r.exit_code == 0, r.output
    assert "11 of 11 steps, 11 ran, 0 up to date" in r.output
    committed = json.loads((ROOT / "sample_runs/paper/bbd/analyze.lock.json").read_text())
    lock = json.loads((run / "bbd" / "analyze.lock.json").read_text())
    assert lock["fingerprint"] == committed["fingerprint"]  # the same stage as `make paper` ran
    assert lock["command"] == f"calib bbd analyze --run {run} --responses sample_data/paper/table7_bbd.csv"
    before = tree(run)
    result = execute(plan(load_pipeline("stages/paper.toml", run, root=ROOT_CMD)))
    assert [s.status for s in result.steps] == [UP_TO_DATE] * 11
    assert "11 of 11 steps, 0 ran, 11 up to date" in result.summary()
    assert tree(run) == before
    r = calib("run", "stages/paper.toml", "--run", run)
    assert r.exit_code == 0 and "0 ran, 11 up to date" in r.output and tree(run) == before


def test_an_interrupted_pipeline_resumes(tmp_path, at_root, monkeypatch):
    run = tmp_path / "paper"
    commit = art.Stage.commit

    def interrupt(self):
        if self.group == "bbd":
            raise KeyboardInterrupt
        return commit(self)

    monkeypatch.setattr(art.Stage, "commit", interrupt)
    r = calib("run", "stages/paper.toml", "--run", run)
    assert r.exit_code == 130 and "interrupted in step 'bbd-design'" in r.output, r.output
    assert "6 of 11 steps" in r.output and not (run / "bbd").exists()
    monkeypatch.setattr(art.Stage, "commit", commit)
    result = execute(plan(load_pipeline("stages/paper.toml", run, root=ROOT_CMD)))
    assert [s.status for s in result.steps] == [UP_TO_DATE] * 6 + ["ran"] * 5


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
@pytest.mark.parametrize("target", sorted(OLD_MAKEFILE))
def test_committed_run_holds_its_pipelines_settings_file(target, at_root):
    """`calib init` in a shipped pipeline is a no-op on the committed run directory of its target:
    RUN/settings.toml is the pipeline's settings file byte for byte, so the stages stay up to date."""
    args = make_call(target)
    variables = parse_vars([args[i + 1] for i, a in enumerate(args) if a == "--var"])
    init = next(s for s in plan(load_pipeline(args[1], args[3], variables, root=ROOT_CMD)).steps if s.argv[0] == "init")
    run, settings = init.argv[init.argv.index("--run") + 1], init.argv[init.argv.index("--settings") + 1]
    assert (ROOT / run / "settings.toml").read_bytes() == (ROOT / settings).read_bytes()


def test_includes_agree_on_the_environment_and_hand_down_their_variables_typed(tmp_path, at_root):
    """Two includes setting one [env] name to two values are refused (every step runs under one environment, so
    one would be dropped unsaid); a string variable handed down to a file whose own is a list is split as --var
    would split it; a description's line breaks stay inside the dry run's comment line."""
    step = "[[step]]\nname = '{name}'\ncommand = ['init', '--run', '{{run}}']\noutputs = ['{{run}}/settings.toml']\n"
    write(tmp_path, '[env]\nCALIB_REUSE = "runs/A"\n' + step.format(name="a"), "a.toml")
    write(tmp_path, '[env]\nCALIB_REUSE = "runs/B"\n' + step.format(name="b"), "b.toml")
    top = write(tmp_path, "[[step]]\ninclude = 'a.toml'\n[[step]]\ninclude = 'b.toml'\n")
    one_error(calib("run", top, "--run", tmp_path / "run", "--dry-run"), "CALIB_REUSE differs", "'runs/B'")
    write(tmp_path, "[vars]\nextra = []\n[[step]]\nname = 'i'\ncommand = ['init', '--run', '{run}', '{extra}']\n"
          "outputs = ['{run}/settings.toml']\n", "inner.toml")
    top = write(tmp_path, 'description = """two\necho INJECTED"""\n[vars]\nextra = "--settings stages/settings/paper.toml"\n'
                "[[step]]\ninclude = 'inner.toml'\n")
    r = calib("run", top, "--run", tmp_path / "run", "--dry-run")
    assert r.exit_code == 0, r.output
    assert "init --run" in r.output and "--settings stages/settings/paper.toml" in r.output
    assert not any(line.startswith("echo") for line in r.output.splitlines())
    assert "(two echo INJECTED)" in r.output


def test_a_pipeline_nested_too_deep_to_parse_is_one_error_line(tmp_path, at_root):
    """tomllib recurses per nesting level: past the interpreter's limit its RecursionError was exit 70. The
    limit is set here, since a test worker may run with a raised one."""
    import sys

    path = write(tmp_path, "description = " + "[" * 3000 + "]" * 3000 + "\n" + GOOD.split("\n", 4)[-1])
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(1000)
    try:
        r = calib("run", path, "--run", tmp_path / "run")
    finally:
        sys.setrecursionlimit(limit)
    one_error(r, "nests", "too deep")
