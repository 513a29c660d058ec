"""`calib` starts light (issue 48): importing the CLI and rendering any command's help imports none of
the heavy libraries (a second and a half of start-up before); what help shows is right: flags take no
value, --band takes the comma form it shows, model add/remove name the effects, nothing is cut at 80
columns. Not timed: benchmarks/startup.py times it."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from calib_cli.cli import app
from calib_cli.cli.names import EFFECT_NAMES, HEAP_PARAMETERS, MAX_FLANK_DIFF_DEG, MAX_RESIDUAL

HEAVY = ("pandas", "numpy", "scipy", "matplotlib", "numba", "torch", "sklearn", "cv2", "pyarrow")


def _paths(group, prefix=()):
    for name, cmd in group.commands.items():
        yield (*prefix, name)
        if hasattr(cmd, "commands"):
            yield from _paths(cmd, (*prefix, name))


ROOT = typer.main.get_command(app)
PATHS = [(), *_paths(ROOT)]


def _help(path, columns: int = 100) -> str:
    r = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": str(columns), "TERM": "dumb"})
    assert r.exit_code == 0, r.output
    return r.output


def _flat(text: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"[│╭╮╰╯─]", " ", text))


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120)


def test_importing_the_cli_and_every_help_imports_nothing_heavy():
    r = _python(f"""
        import sys
        import calib_cli.cli
        heavy = {HEAVY!r}
        print("import:", [m for m in heavy if m in sys.modules])
        import typer
        from typer.testing import CliRunner
        from calib_cli.cli import app

        def paths(group, prefix=()):
            for name, cmd in group.commands.items():
                yield (*prefix, name)
                if hasattr(cmd, "commands"):
                    yield from paths(cmd, (*prefix, name))

        for path in [(), *paths(typer.main.get_command(app))]:
            assert CliRunner().invoke(app, [*path, "--help"]).exit_code == 0, path
        assert CliRunner().invoke(app, ["--version"]).exit_code == 0
        print("help:", [m for m in heavy if m in sys.modules])
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[:2] == ["import: []", "help: []"], r.stdout


def _calib() -> list[str]:
    script = Path(sys.executable).with_name("calib")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "calib_cli"]


def test_version_and_help_exit_0_with_output():
    r = subprocess.run([*_calib(), "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.startswith("calib "), r.stdout + r.stderr
    for path in [(), ("model", "add")]:
        out = _help(path)
        assert "Usage: calib" in out and "--help" in out


@pytest.mark.parametrize("path", PATHS, ids=lambda p: " ".join(p) or "calib")
def test_flags_show_no_value_and_nothing_is_cut_at_80_columns(path):
    """typer shows a flag as `--force <bool>`, as if `--force true` were how to write it (which fails);
    a word too long for its help cell at 80 columns ends in '…'."""
    out = _help(path)
    assert "<bool>" not in out
    assert re.search(r"--help\s+Show this message", out), out
    narrow = _help(path, 80)
    assert "…" not in narrow, narrow
    assert max(map(len, narrow.splitlines())) <= 80


def test_a_flag_on_the_command_line_takes_no_value():
    out = _help(("init",))
    assert re.search(r"--force\s+Rerun even if", out), out
    r = CliRunner().invoke(app, ["init", "--run", "x", "--force", "true"])
    assert r.exit_code == 2 and "unexpected extra argument" in r.output


@pytest.mark.parametrize("args", [["--band", "0.2,0.8"], ["--band", "0.2", "0.8"], ["--band=0.2,0.8"]],
                         ids=["comma", "space", "equals-comma"])
def test_band_takes_the_comma_form_it_shows(args):
    cmd = ROOT.commands["measure-angle"]
    with cmd.make_context("measure-angle", ["--run", "x", *args, "--force"]) as ctx:
        assert ctx.params["band"] == (0.2, 0.8) and ctx.params["force"] is True
    out = _help(("measure-angle",))
    assert "<float,float>" in out and "<float,float>..." not in out


def test_band_in_the_comma_form_reaches_the_stage(tmp_path):
    (tmp_path / "a.csv").write_text("image,repose_angle\na,30\nb,31\nc,32\n")
    r = CliRunner().invoke(app, ["measure-angle", "--run", str(tmp_path / "run"), "--angles",
                                 str(tmp_path / "a.csv"), "--band", "0.9,0.1"])
    assert r.exit_code == 2 and "got (0.9, 0.1)" in r.output, r.output


def test_options_of_several_values_keep_what_is_not_theirs():
    from calib_cli.cli.common import split_commas

    params = ROOT.commands["measure-angle"].params
    assert split_commas(params, ["--band", "0.1,0.9,0.5"]) == ["--band", "0.1,0.9,0.5"]
    assert split_commas(params, ["--images", "a,b", "--", "--band", "1,2"]) == ["--images", "a,b", "--", "--band",
                                                                                  "1,2"]
    assert split_commas(params, ["--band"]) == ["--band"]


@pytest.mark.parametrize("action", ["add", "remove"])
def test_model_add_and_remove_describe_themselves_and_name_the_effects(action):
    out = _flat(_help(("model", action)))
    assert f"{action.capitalize()} an effect" in out
    for name in EFFECT_NAMES:
        assert name in out, (name, out)
    listing = _flat(_help(("model",)))
    assert f"{action} {action.capitalize()} an effect" in listing


def test_the_light_copies_equal_their_sources():
    from calib_cli.dem.heap import PARAMETERS
    from calib_cli.dem.laws import law_params
    from calib_cli.imaging.measure import ShapeLimits
    from calib_cli.model import EFFECTS

    assert EFFECT_NAMES == tuple(EFFECTS)
    assert HEAP_PARAMETERS == tuple(p for p in PARAMETERS if p not in {q.name for q in law_params()})
    assert (MAX_FLANK_DIFF_DEG, MAX_RESIDUAL) == (ShapeLimits.max_flank_diff_deg, ShapeLimits.max_residual)


def test_the_cli_reference_shows_help_text_as_written():
    """make docs: typer's generator escapes for HTML; code spans and apostrophes must read as typed."""
    from calib_cli.cli.docs import unescape_markdown

    raw = "* `--run &lt;path&gt;`: the run&#x27;s folder, RUN/rev&lt;N&gt;/ and `--var &#x27;a=1&#x27;`"
    assert unescape_markdown(raw) == "* `--run <path>`: the run's folder, RUN/rev&lt;N&gt;/ and `--var 'a=1'`"
