"""The docs' output blocks are what their commands print on the committed sample runs (``make docs``
renders them again from the runs' files): a block that no longer matches its run fails here."""

from __future__ import annotations

from pathlib import Path

import pytest

from calib_cli.cli.docs import BLOCK, refresh

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted(p for p in (ROOT / "docs").glob("*.md") if BLOCK.search(p.read_text()))
TUTORIAL = ROOT / "docs" / "tutorial-hidden-effect.md"


def test_the_tutorial_is_a_short_walk_through_made_of_generated_blocks():
    text = TUTORIAL.read_text()
    assert len(text.splitlines()) <= 600
    assert TUTORIAL in DOCS and len(BLOCK.findall(text)) >= 8


@pytest.mark.parametrize("doc", DOCS, ids=[p.name for p in DOCS])
def test_every_output_block_matches_its_sample_run(doc):
    _, stale = refresh(doc.read_text(), ROOT)
    assert not stale, f"{doc.name}: stale output block(s) {stale}: run `make docs`"


def test_a_block_edited_by_hand_or_left_behind_by_its_run_is_stale():
    text = TUTORIAL.read_text()
    m = next(m for m in BLOCK.finditer(text) if m["spec"].startswith("compare ") and "RMSE " in m["body"])
    edited = text[:m.start("body")] + m["body"].replace("RMSE ", "RMSE 1", 1) + text[m.end("body"):]
    fixed, stale = refresh(edited, ROOT)
    assert stale == [m["spec"]] and fixed == refresh(text, ROOT)[0]
    # each block begins with the command that wrote the files it shows
    assert m["body"].startswith("$ calib compare --run sample_runs/")


def test_a_block_without_its_end_is_refused_not_merged_with_the_next():
    """A lost end line must not let one block swallow the prose and the block after it."""
    from calib_cli.errors import CalibError

    text = TUTORIAL.read_text()
    m = next(BLOCK.finditer(text))
    broken = text[:m.start("tail")] + "```\n" + text[m.end("tail"):]
    with pytest.raises(CalibError, match="end output"):
        refresh(broken, ROOT)
