"""calib_cli.pool: the spawned side process a posterior's held-out scores run in."""

from __future__ import annotations

import os
import time

import pytest

from calib_cli.pool import beside


def test_beside_runs_the_call_in_another_process_and_gives_its_result():
    with beside(os.getpid) as pending:
        here = os.getpid()
        assert pending.result(timeout=120) != here


def test_a_stop_in_the_block_ends_the_side_process_at_once():
    """Ctrl-C (or an error) while the side process still works: it is killed, not waited for."""
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        with beside(time.sleep, 120):
            time.sleep(2.0)  # the process has started its call
            raise KeyboardInterrupt
    assert time.monotonic() - t0 < 30  # not the 120 s the call would have taken


def test_beside_without_spawn_runs_the_call_here_before_the_block():
    calls = []
    with beside(calls.append, "scored", spawn=False) as pending:
        assert calls == ["scored"]  # done before the block's own work, in this process
        assert pending.result(timeout=0) is None
