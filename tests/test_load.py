"""stages.load: a finished stage's results read back from the files alone, as its function returned them."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pandas as pd
import pytest

from calib_cli.errors import CalibError
from calib_cli.stages.load import KINDS, load

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "sample_runs"


def _digest(run: Path) -> dict[str, str]:
    return {str(p.relative_to(run)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(run.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("name", ["hidden-effect", "calibration", "hidden-wall"])
def test_every_stage_a_committed_run_holds_loads_and_nothing_is_written(tmp_path, name):
    run = tmp_path / name
    shutil.copytree(RUNS / name, run)
    before = _digest(run)
    loaded = 0
    for stage, kind in KINDS.items():
        if not (run / kind.group / kind.made).is_file():
            with pytest.raises(CalibError, match=f"holds no {stage} result.*calib {kind.command}"):
                load(run, stage)
            continue
        r = load(run, stage)
        assert r.skipped and r.dir == run / kind.group
        table = r.summary()
        assert isinstance(table, pd.DataFrame) and len(table), stage
        if hasattr(r, "warnings"):
            assert all(isinstance(w, str) for w in r.warnings())
        loaded += 1
    assert loaded >= 6
    assert _digest(run) == before  # loading computes nothing and writes nothing, not even a lock


def test_the_posterior_and_an_earlier_revision_read_back():
    post = load(RUNS / "hidden-effect", "posterior").table
    committed = pd.read_parquet(RUNS / "hidden-effect" / "posterior" / "summary.parquet")
    assert post.equals(committed)
    rev0 = load(RUNS / "hidden-effect", "calibrate", revision=0)
    assert rev0.revision == 0 and set(rev0.rounds["revision"]) == {0}
    assert "surface_energy" not in set(rev0.table["parameter"])  # revision 0 is the dry model
    assert load(RUNS / "hidden-effect", "calibrate").revision == 1


def test_the_calibration_and_the_posterior_show_the_answer_alike():
    """calibrate's result and calibrate-posterior's show the same columns of the answer, not the whole file."""
    cal, post = load(RUNS / "hidden-effect", "calibrate").summary(), load(RUNS / "hidden-effect", "posterior").summary()
    pd.testing.assert_frame_equal(cal, post)
    assert list(cal.columns) == ["parameter", "median", "q05", "q95", "rel_width", "identified", "box_cut", "bf_off",
                                 "bf_upper", "autocorr_time", "chain_ok", "verdict"]
    assert (cal["box_cut"] == "").all()  # nothing pressed an edge: the verdicts stand
    assert cal.set_index("parameter").loc["surface_energy", "verdict"].endswith("the data call for it")


def test_what_a_result_warns_of_reads_back():
    """The warnings the command printed when the stage ran, from its files: the ascent's best step at the
    path's end and the surface's R2 gap on the sample calibration, the inversion's own lines."""
    cal = RUNS / "calibration"
    assert "end of the path" in load(cal, "ascent").warnings()[0]
    assert load(cal, "bbd").warnings() == ["adjusted and predicted R2 differ by more than 0.2"]
    inv = load(cal, "invert")
    assert any("not identifiable" in w for w in inv.warnings())
    ref = inv.refinement()  # the refinement's table, as the command prints it
    assert list(ref["round"]) == [0, 1, 2] and "simulated" in ref.columns


def test_loading_what_is_not_there_is_one_line(tmp_path):
    with pytest.raises(CalibError, match="is not a run directory"):
        load(tmp_path / "typo", "posterior")
    with pytest.raises(CalibError, match="no stage 'answer' to load: one of measure, "):
        load(RUNS / "hidden-effect", "answer")
    with pytest.raises(CalibError, match="revision= picks a calibration's"):
        load(RUNS / "hidden-effect", "compare", revision=0)
    with pytest.raises(CalibError, match="no calibration of model revision 5"):
        load(RUNS / "hidden-effect", "calibrate", revision=5)


def test_a_results_lines_are_plain_text_for_a_notebook():
    """conclusion() and notes() read as text (the command line's rich markup, such as [bold], only on asking)."""
    run = RUNS / "hidden-effect"
    for r in (load(run, "diagnose"), load(run, "posterior"), load(run, "suggest")):
        plain, marked = r.conclusion(), r.conclusion(markup=True)
        assert len(plain) == len(marked) and any("[bold]" in line for line in marked)
        assert not any("[bold]" in line or "[/]" in line for line in plain)
    first = load(run, "diagnose")
    assert first.conclusion()[0].startswith(f"{first.ranking['effect'].iloc[0]}: significant")
