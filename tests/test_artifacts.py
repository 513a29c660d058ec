import json
import os

import numpy as np
import pandas as pd
import pytest

from calib_cli import artifacts as art
from calib_cli.errors import CalibError


def test_write_read_with_provenance(tmp_path):
    df = pd.DataFrame({"a": [1.0, 2.0], "b": ["x", "y"]})
    p = tmp_path / "t.parquet"
    art.write_table(p, df, {"stage": "s", "inputs": {"x": "1"}})
    pd.testing.assert_frame_equal(art.read_table(p), df)
    assert art.read_provenance(p)["stage"] == "s"
    assert [f for f in os.listdir(tmp_path)] == ["t.parquet"]  # no temporary left behind


def test_read_table_errors(tmp_path):
    with pytest.raises(CalibError, match="not found"):
        art.read_table(tmp_path / "nope.parquet")
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"garbage")
    with pytest.raises(CalibError, match="not a readable Parquet"):
        art.read_table(bad)
    art.write_table(tmp_path / "ok.parquet", pd.DataFrame({"a": [1]}))
    with pytest.raises(CalibError, match="lacks column"):
        art.read_table(tmp_path / "ok.parquet", columns=["b"])


def test_hash_is_stable_and_order_free():
    assert art.hash_obj({"a": 1, "b": [1.0, 2]}) == art.hash_obj({"b": [1.0, 2], "a": 1})
    assert art.hash_obj({"a": 1}) != art.hash_obj({"a": 2})


def _stage(tmp_path, settings, inp=None):
    return art.Stage(tmp_path, "g", "s", inputs={"in": inp} if inp else {}, settings=settings)


def test_stage_skip_force_and_invalidation(tmp_path):
    inp = tmp_path / "in.csv"
    inp.write_text("a\n1\n")
    st = _stage(tmp_path, {"k": 1}, inp)
    assert not st.up_to_date()
    with st.commit() as out:
        out.table("o.parquet", pd.DataFrame({"a": [1]}))
    assert _stage(tmp_path, {"k": 1}, inp).up_to_date()
    assert not _stage(tmp_path, {"k": 2}, inp).up_to_date()  # settings changed
    inp.write_text("a\n2\n")
    assert not _stage(tmp_path, {"k": 1}, inp).up_to_date()  # input changed
    inp.write_text("a\n1\n")
    (tmp_path / "g" / "o.parquet").unlink()
    assert not _stage(tmp_path, {"k": 1}, inp).up_to_date()  # output removed


def test_failed_stage_leaves_run_dir_unchanged(tmp_path):
    st = _stage(tmp_path, {"k": 1})
    with st.commit() as out:
        out.table("o.parquet", pd.DataFrame({"a": [1]}))
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    st2 = _stage(tmp_path, {"k": 2})
    with pytest.raises(RuntimeError):
        with st2.commit() as out:
            out.table("o.parquet", pd.DataFrame({"a": [2]}))
            raise RuntimeError("boom")
    after = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert before == after

def test_a_folder_where_an_output_goes_or_a_file_where_the_stage_folder_goes_is_one_line(tmp_path):
    """A later output that is a folder (posterior/corner.png made a folder) stopped the commit half-way, after
    the earlier outputs were replaced and with a pending lock left that every reader then refused; a file
    where the stage's folder goes was exit 70. Both are refused before anything moves."""
    st = _stage(tmp_path, {"k": 1})
    with st.commit() as out:
        out.table("a.parquet", pd.DataFrame({"a": [1]}))
        out.text("b.txt", "one")
    (tmp_path / "g" / "b.txt").unlink()
    (tmp_path / "g" / "b.txt").mkdir()
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    with pytest.raises(CalibError, match=r"g/b.txt is a folder where calib writes a file: move it aside"):
        with _stage(tmp_path, {"k": 2}).commit() as out:
            out.table("a.parquet", pd.DataFrame({"a": [2]}))
            out.text("b.txt", "two")
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    assert not list((tmp_path / "g").glob("*pending*")) and not list((tmp_path / "g").glob(".s.staging-*"))
    other = tmp_path / "other"
    other.mkdir()
    (other / "g").write_text("x")
    with pytest.raises(CalibError, match=r"other/g is a file where calib keeps a folder of outputs"):
        with _stage(other, {"k": 1}).commit() as out:
            out.table("a.parquet", pd.DataFrame({"a": [1]}))
    assert (other / "g").read_text() == "x"



@pytest.mark.parametrize("text", ["[1]", '"str"', "5", '{"outputs": 5}', "{not json"])
def test_a_lock_of_another_shape_is_out_of_date_and_replaced(tmp_path, text):
    """A lock edited into valid JSON of another shape reads as no lock: the stage recomputes (it crashed)."""
    st = _stage(tmp_path, {"k": 1})
    with st.commit() as out:
        out.table("o.parquet", pd.DataFrame({"a": [1]}))
    st.lock_path.write_text(text)
    assert st.read_lock() is None and not st.up_to_date()
    with st.commit() as out:
        out.table("o.parquet", pd.DataFrame({"a": [1]}))
    assert st.up_to_date()


def test_stale_outputs_removed_and_lock_records_hashes(tmp_path):
    st = _stage(tmp_path, {"k": 1})
    with st.commit() as out:
        out.table("a.parquet", pd.DataFrame({"a": [1]}))
        out.text("b.txt", "b")
    st = _stage(tmp_path, {"k": 2})
    with st.commit() as out:
        out.table("a.parquet", pd.DataFrame({"a": [2]}))
    assert not (tmp_path / "g" / "b.txt").exists()
    lock = json.loads((tmp_path / "g" / "s.lock.json").read_text())
    assert set(lock["outputs"]) == {"a.parquet"}
    assert lock["outputs"]["a.parquet"] == art.file_hash(tmp_path / "g" / "a.parquet")


@pytest.mark.parametrize("kill_at", ["unlink", "lock"])
def test_a_kill_mid_publish_leaves_no_output_that_no_lock_lists(tmp_path, monkeypatch, kill_at):
    """A stale output (the old lock's, not written again) is gone before the new lock stands: a kill between
    the two left it listed by no lock, so it passed for a committed output. Killed at the stale file's unlink or
    at the lock's rename, every file in the stage folder is one some lock (or the pending one) lists."""
    import os
    from pathlib import Path

    st = _stage(tmp_path, {"k": 1})
    with st.commit() as out:
        out.table("a.parquet", pd.DataFrame({"a": [1]}))
        out.text("b.txt", "b")
    real_unlink, real_replace = Path.unlink, os.replace

    def unlink(self, *a, **k):
        if kill_at == "unlink" and self.name == "b.txt":
            raise KeyboardInterrupt
        return real_unlink(self, *a, **k)

    def replace(src, dst):
        if kill_at == "lock" and str(dst).endswith("s.lock.json"):
            raise KeyboardInterrupt
        return real_replace(src, dst)

    monkeypatch.setattr(Path, "unlink", unlink)
    monkeypatch.setattr(os, "replace", replace)
    st = _stage(tmp_path, {"k": 2})
    with pytest.raises(KeyboardInterrupt):
        with st.commit() as out:
            out.table("a.parquet", pd.DataFrame({"a": [2]}))
    monkeypatch.undo()
    listed = set()
    for lock in (tmp_path / "g").glob("*.json"):
        listed |= set(json.loads(lock.read_text())["outputs"])
    files = {p.name for p in (tmp_path / "g").iterdir() if p.is_file() and not p.name.endswith(".json")}
    assert files <= listed, files - listed
    if (tmp_path / "g" / "b.txt").exists():  # the old lock still stands and vouches for it
        art.check_committed(tmp_path / "g" / "b.txt")


def test_read_responses_validation(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("a,repose_angle\n1,30\n2,31\n")
    assert art.read_responses(p, ["a"], "repose_angle")["repose_angle"].tolist() == [30, 31]
    p.write_text("a,repose_angle\n1,30\n2,\n")
    with pytest.raises(CalibError, match="missing or non-numeric.*row 2"):
        art.read_responses(p, ["a"], "repose_angle")
    for bad in ("-5", "0", "95"):  # a repose angle outside (0, 90) deg: a typo, not a heap
        p.write_text(f"a,repose_angle\n1,30\n2,{bad}\n")
        with pytest.raises(CalibError, match=r"must lie in \(0, 90\) deg \(row 2"):
            art.read_responses(p, ["a"], "repose_angle")
    p.write_text("a,repose_angle\n1,30\n2,31\n1,30\n2,31\n")  # pasted twice: no information, but runs counted
    with pytest.raises(CalibError, match="row 3 repeats row 1 in every column, and every other row repeats one"):
        art.read_responses(p, ["a"], "repose_angle")
    said = []  # centre points alike to the digits given (whole degrees) are runs of the design: said, kept
    p.write_text("a,repose_angle\n1,30\n2,31\n1,30\n1,30\n3,33\n")
    assert len(art.read_responses(p, ["a"], "repose_angle", warn=said.append)) == 5
    assert len(said) == 1 and "row 3 repeats row 1 in every column, and 1 more row(s)" in said[0]
    p.write_text("a,repose_angle\n1,30\n2,31\n1,30.5\n")  # a repeat with its own angle is a replicate
    assert len(art.read_responses(p, ["a"], "repose_angle")) == 3
    p.write_text("static_friction,repose_angle\n0.4,30\n-3,31\n")  # a factor's value as --set takes it
    with pytest.raises(CalibError, match=r"static_friction = -3 \(responses file .*, row 2\) is outside"):
        art.read_responses(p, ["static_friction"], "repose_angle")
    p.write_text("a,angle\n1,30\n")
    with pytest.raises(CalibError, match="lacks column.*repose_angle"):
        art.read_responses(p, ["a"], "repose_angle")
    with pytest.raises(CalibError, match="not found"):
        art.read_responses(tmp_path / "x.csv", ["a"], "repose_angle")
    q = tmp_path / "r.parquet"
    q.write_bytes(b"\x00\x01junk")
    with pytest.raises(CalibError, match="could not be read"):
        art.read_responses(q, ["a"], "repose_angle")
    # Parquet works too
    art.write_table(q, pd.DataFrame({"a": [1.0, 2.0], "repose_angle": [3.0, np.float64(4)]}))
    assert len(art.read_responses(q, ["a"], "repose_angle")) == 2


def test_an_output_written_twice_fails_before_the_commit(tmp_path):
    """Two outputs of one name (e.g. the overlays of a.png and a.jpg) are refused while staging: the
    commit would move the first in and fail on the second, leaving new tables without a lock."""
    st = _stage(tmp_path, {"x": 1})
    with pytest.raises(ValueError, match="written twice"):
        with st.commit() as out:
            out.bytes("o/a.png", b"1")
            out.bytes("o/a.png", b"2")
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


def test_a_lock_edited_to_name_a_file_outside_its_stage_deletes_nothing_there(tmp_path):
    """The stale outputs a stage removes are its own: a hand-edited lock listing ../settings.toml once made the
    next commit delete the run's settings."""
    import json

    (tmp_path / "settings.toml").write_text("[heap]\n")
    st = art.Stage(tmp_path, "pb", "analyze", settings={"a": 1})
    with st.commit() as out:
        out.table("x.parquet", pd.DataFrame({"a": [1]}))
    lock = json.loads(st.lock_path.read_text())
    lock["outputs"].update({"../settings.toml": "0" * 64, str(tmp_path / "settings.toml"): "0" * 64})
    st.lock_path.write_text(json.dumps(lock))
    with art.Stage(tmp_path, "pb", "analyze", settings={"a": 2}).commit() as out:
        out.table("x.parquet", pd.DataFrame({"a": [2]}))
    assert (tmp_path / "settings.toml").read_text() == "[heap]\n"


@pytest.mark.parametrize("raw", [b"{not json", b"[1, 2]"])
def test_provenance_calib_did_not_write_is_one_line(tmp_path, raw):
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = pa.table({"a": [1]}).replace_schema_metadata({art.PROVENANCE_KEY: raw})
    pq.write_table(t, tmp_path / "x.parquet")
    with pytest.raises(CalibError, match="provenance that is not calib's"):
        art.read_provenance(tmp_path / "x.parquet")


def test_the_run_lock_is_released_when_its_setup_is_interrupted(tmp_path, monkeypatch):
    """A Ctrl-C (or a full disk) while the lock is being taken once kept it held in a notebook's process: the
    next command in that process, or another process, found the run 'in use'."""
    calls = []

    def stop(run):
        calls.append(run)
        raise KeyboardInterrupt

    monkeypatch.setattr(art, "sweep_leftovers", stop)
    with pytest.raises(KeyboardInterrupt):
        with art.run_lock(tmp_path / "run"):
            pass
    monkeypatch.undo()
    assert calls and not art._HELD
    with art.run_lock(tmp_path / "run"):  # free again
        pass


def test_a_sweep_leaves_a_folder_with_its_own_lock_alone(tmp_path):
    """A command taking RUN's lock sweeps dead writers' staging folders; a lab folder synth-lab writes under its
    own lock (RUN/lab/.lock) is not swept from outside, so a synth-lab running beside it keeps its staging."""
    run = tmp_path / "run"
    (run / "lab" / ".synth-lab.staging-abc").mkdir(parents=True)
    (run / "lab" / art.RUN_LOCK).write_text("")
    (run / "compare" / ".rev0.staging-xyz").mkdir(parents=True)
    art.sweep_leftovers(run)
    assert (run / "lab" / ".synth-lab.staging-abc").is_dir() and not (run / "compare" / ".rev0.staging-xyz").exists()


def test_photographs_a_cut_short_commit_was_writing_are_refused(tmp_path):
    """A synth-lab killed between its renames leaves two labs' photographs side by side and its pending lock:
    measure-angle, which reads photographs and a CSV (no Parquet check), refuses the folder until it reruns."""
    import json

    from typer.testing import CliRunner

    from calib_cli.cli import app

    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / ".synth-lab.pending.json").write_text(json.dumps({"stage": "lab.synth-lab", "outputs": {"a.png": "0"}}))
    r = CliRunner().invoke(app, ["measure-angle", "--run", str(tmp_path / "run"), "--images", str(lab)])
    assert r.exit_code == 2 and "is being written, or its write was interrupted" in " ".join(r.output.split())
