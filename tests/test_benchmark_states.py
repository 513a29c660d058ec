"""benchmarks/heap_states.py: the throughput benchmarks time heaps in contact, not fresh fills."""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import heap_states as hs  # noqa: E402

from calib_cli.dem.heap import PRESETS, HeapTest  # noqa: E402


def _touching(s) -> float:
    """Contacts a grain: listed pairs whose spheres overlap."""
    return hs.per_grain(s)[1]


def test_a_settled_state_is_in_contact_where_a_fresh_fill_is_not():
    settled = hs.systems_from(hs.settled_states("smoke", [0, 1]), "smoke", 3)
    fresh = hs.fresh_systems("smoke", 1)[0]
    fresh.advance(200)  # as the benchmarks stepped fresh fills before timing them
    assert _touching(fresh) < 0.1
    assert all(_touching(s) > 1.0 for s in settled)
    assert all(s.walls.lift_start < s.t for s in settled)  # the cylinder is lifting
    # a batch larger than the fills settled repeats them, each copy its own arrays
    np.testing.assert_array_equal(settled[0].particles.pos, settled[2].particles.pos)
    settled[2].advance(10)
    assert not np.array_equal(settled[0].particles.pos, settled[2].particles.pos)


def test_the_gpu_engine_lifts_a_settled_fill_as_the_protocol_does():
    """The GPU engine's settle loop (under numba's simulator here), from a fill the CPU settled: the
    protocol's lift goes on, the neighbour list and histories come back for the checkpoint."""
    pre = PRESETS["smoke"]
    t = HeapTest(hs.PARAMS, pre.condition, pre.numerics, 0)
    hs._settle_cpu([t], 0.0)
    onward = HeapTest(hs.PARAMS, pre.condition, replace(pre.numerics, chunk=2), 0).restore(t.state())
    start, steps = onward.system.t, onward.system.n_steps
    hs._settle_gpu([onward], lift=start - onward.t_settled + 3.5 * onward.system.dt)
    assert onward.system.n_steps == steps + 4 and onward.stage == "lift"
    state = onward.state()
    assert len(state["pi"]) > onward.system.n and np.abs(state["ht"]).sum() > 0
