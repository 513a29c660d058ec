"""docs/getting-started.md's recipe for your own data runs as written, on a tiny lab: its commands, read
from the page, on four conditions of synthetic photographs (smoke-sized heaps, a budget of 64 instead of
250, the smoke preset instead of default). Slow: about 3 minutes on 2 cores."""

from __future__ import annotations

import re
import shlex

import pytest
from typer.testing import CliRunner

from calib_cli.cli import app
from conftest import ROOT

PAGE = ROOT / "docs" / "getting-started.md"


def recipe() -> list[list[str]]:
    """The commands of the page's 'With your own data' block, comments dropped, one argv each."""
    part = PAGE.read_text().split("## With your own data", 1)[1]
    block = re.search(r"```sh\n(.*?)```", part, re.S).group(1)
    lines = [ln.split("#", 1)[0].strip() for ln in block.splitlines()]
    return [shlex.split(ln)[1:] for ln in lines if ln.startswith("calib ")]


def test_the_recipe_reads_as_the_commands_it_documents():
    assert [c[0] for c in recipe()] == ["init", "measure-angle", "calibrate", "compare", "diagnose",
                                        "suggest-conditions", "report"]


@pytest.mark.slow
def test_the_recipe_runs_on_a_tiny_lab(tmp_path, monkeypatch):
    runner = CliRunner()
    lab = tmp_path / "photos"
    r = runner.invoke(app, ["synth-lab", "--out", str(lab), "--set", "static_friction=0.4", "--set",
                            "rolling_friction=0.2", "--set", "restitution=0.3", "--sizes", "6-7,7-8",
                            "--cylinders", "40,50", "--repeats", "2", "--preset", "smoke", "--workers", "2"])
    assert r.exit_code == 0, r.output
    (tmp_path / "conditions.csv").write_bytes((lab / "conditions.csv").read_bytes())
    (tmp_path / "rig.toml").write_bytes((ROOT / "sample_data" / "rig.toml").read_bytes())
    monkeypatch.chdir(tmp_path)
    tiny = {"250": "64", "default": "smoke", "stages/settings/hidden-effect.toml":
            str(ROOT / "stages" / "settings" / "hidden-effect.toml")}
    for argv in recipe():
        argv = [tiny.get(a, a) for a in argv]
        if argv[0] in ("compare", "diagnose"):
            argv += ["--preset", "smoke"]
        r = runner.invoke(app, argv)
        assert r.exit_code == 0, (argv, r.output[-2000:])
    assert (tmp_path / "myrun" / "report.html").is_file()
    assert (tmp_path / "myrun" / "diagnose" / "ranking.parquet").is_file()
