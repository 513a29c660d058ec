"""Stage locks name the version of the code that computed them (calib_cli.stages.common.CODE_VERSIONS).

The guard: the paper's committed chain (sample_runs/paper, every stage but the report, no simulation)
is recomputed from its committed inputs, and every table each committed lock lists must come out as
committed while the stage's version is the one the lock recorded. A change that moves a stage's
outputs must raise its version and regenerate the committed runs (make paper); one that forgets
either fails here, naming the stage.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd

from calib_cli import artifacts as art
from calib_cli.stages import common, doe, invert, measure, surrogate

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "sample_runs" / "paper"
DATA = ROOT / "sample_data" / "paper"


def _moved_tables(committed: Path, recomputed: Path) -> list[str]:
    """The tables a committed lock lists that the recomputed run directory holds with other values."""
    lock = json.loads(committed.read_text())
    moved = []
    for rel in lock["outputs"]:
        if not rel.endswith(".parquet"):
            continue  # figures: their bytes follow matplotlib's version, not the stage's arithmetic
        a, b = pd.read_parquet(committed.parent / rel), pd.read_parquet(recomputed.parent / rel)
        try:
            # the values to 1e-6: a network trained on another CPU's BLAS differs in the last digits
            pd.testing.assert_frame_equal(a, b, check_exact=False, rtol=1e-6, atol=1e-9)
        except AssertionError:
            moved.append(rel)
    return moved


def test_a_stage_whose_outputs_move_is_flagged(tmp_path):
    """The comparison can fail: a table with one value changed is reported, an equal one is not."""
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
    df = pd.DataFrame({"x": [1.0, 2.0]})
    art.write_table(tmp_path / "a" / "t.parquet", df)
    art.write_table(tmp_path / "b" / "t.parquet", df.assign(x=[1.0, 2.001]))
    (tmp_path / "a" / "s.lock.json").write_text(json.dumps({"outputs": {"t.parquet": "h"}}))
    assert _moved_tables(tmp_path / "a" / "s.lock.json", tmp_path / "b" / "s.lock.json") == ["t.parquet"]
    assert _moved_tables(tmp_path / "a" / "s.lock.json", tmp_path / "a" / "s.lock.json") == []


def test_a_raised_stage_version_makes_its_lock_stale(tmp_path, monkeypatch):
    """A lock written at version 1 is not up to date for code at version 2: the stage runs again."""
    run = tmp_path / "run"
    shutil.copytree(PAPER, run)
    assert doe.pb_design(run).skipped
    monkeypatch.setitem(common.CODE_VERSIONS, "pb", 2)
    res = doe.pb_design(run)
    assert not res.skipped
    assert json.loads((run / "pb" / "design.lock.json").read_text())["code"] == 2


def test_the_papers_chain_recomputes_as_committed_at_each_stages_version(tmp_path):
    run = tmp_path / "paper"
    shutil.copytree(PAPER, run)
    quiet = {"say": lambda *a, **k: None}
    measure.measure_angle(run, angles=DATA / "table1_angles.csv", force=True, **quiet)
    doe.pb_design(run, force=True)
    doe.pb_analyze(run, responses=DATA / "table3_pb.csv", force=True)
    doe.ascent_design(run, force=True)
    doe.ascent_analyze(run, responses=DATA / "table5_ascent.csv", force=True, **quiet)
    doe.bbd_design(run, force=True)
    doe.bbd_analyze(run, responses=DATA / "table7_bbd.csv", force=True)
    surrogate.fit_surrogate(run, force=True, **quiet)
    invert.invert(run, force=True, **quiet)
    locks = sorted(PAPER.rglob(f"*{art.LOCK_SUFFIX}"))
    assert len(locks) == 9
    problems = []
    for lock in locks:
        group = lock.parent.name
        made_at, now = json.loads(lock.read_text()).get("code", 1), common.CODE_VERSIONS[group]
        if made_at != now:
            problems.append(f"{group}: committed at code version {made_at}, the code is at {now}: regenerate "
                            "the sample runs (make paper)")
            continue
        moved = _moved_tables(lock, run / lock.relative_to(PAPER))
        if moved:
            problems.append(f"{group}: {', '.join(moved)} moved at code version {now}: raise "
                            f"CODE_VERSIONS[{group!r}] and regenerate the sample runs")
    assert not problems, "\n".join(problems)


def test_every_stage_a_stage_function_opens_has_a_version_and_no_version_is_orphaned():
    """The stage folders the stage functions open (``stage(run, "<folder>", ...)`` in calib_cli/stages) are
    exactly CODE_VERSIONS' keys, each a version >= 1: a new stage cannot go unversioned."""
    import re

    source = "".join(p.read_text() for p in (ROOT / "calib_cli" / "stages").glob("*.py"))
    opened = set(re.findall(r'\bstage\(run, "([a-z_]+)"', source)) | set(re.findall(r'\bversion="([a-z_-]+)"', source))
    assert opened == set(common.CODE_VERSIONS)
    assert all(isinstance(v, int) and v >= 1 for v in common.CODE_VERSIONS.values())
