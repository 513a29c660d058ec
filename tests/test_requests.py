"""The one request builder (calib_cli/heaps/inputs.py) keeps every committed heap's seed and cache key.

Every simulating command builds its requests through `build_requests` with the seed scheme of
`seed_index`. A change of either would give the committed sample runs' heaps new hashes and
re-simulate them (hours); these tests rebuild the committed rows from the inputs each command
had and check the hashes, and check that the builder reproduces the schemes the commands used
before it existed, and that a sample run's stages stay up to date."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from calib_cli.cli import app
from calib_cli.dem.heap import HeapCondition, Numerics
from calib_cli.heaps.inputs import (build_requests, condition_from_row, content_seed, heap_preset, request_from_row,
                                    seed_index, table_conditions)
from calib_cli.heaps.keys import CACHE_SOURCE, Request, derive_seed
from calib_cli.settings import load_settings

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_RUNS = sorted(p.parents[1] for p in (ROOT / "sample_runs").glob("*/simulate/results.parquet"))
DESIGNS = ("pb", "ascent", "bbd")


def _rebuilt(run: Path, rows: pd.DataFrame, row) -> Request:
    """The request of a committed results row, rebuilt by build_requests from what its command had:
    the row's parameters and rig, the run's conditions table and settings, the command's base seed."""
    g = row.get("shear_modulus")
    pre = heap_preset(row["preset"], float(g) if g is not None and pd.notna(g) else None)
    params = {k: float(row[k]) for k in rows.columns if k in request_from_row(row).params}
    cid, design = str(row["condition_id"]), str(row["design"])
    cond = condition_from_row(pre.condition, row)
    kw = dict(numerics=pre.numerics, preset=row["preset"], design=design, model=row["model"])
    if design == "calibrate":  # calib calibrate: seeded by what the heap simulates, base seed 0
        return Request(params, cond, pre.numerics, content_seed(0, params, cond, int(row["repeat"])), row["preset"],
                       design, int(row["run_id"]), int(row["repeat"]), row["model"], cid, row.get("engine", "builtin"))
    if design == "validate":  # invert --validate: one point at the measured conditions, seeded by invert.seed
        n = rows.loc[rows["design"] == "validate", "condition_id"].nunique()
        seed = int(load_settings([run / "settings.toml"])["invert"]["seed"])
        point, from_table, by_cond = 0, n > 1, True
    elif design in DESIGNS:  # simulate-heap --design [--conditions], base seed 0
        seed, point, from_table, by_cond = 0, int(row["run_id"]), cid != "", False
    else:  # compare, diagnose (sens-*, cand-*): one point at every measured condition, seed 0
        seed, point, from_table, by_cond = 0, 0, True, True
    if cid:  # the condition's place in the run's conditions table decides its seeds
        table = pd.read_parquet(run / "measure" / "conditions.parquet")
        conds = [(c, cond if c == cid else HeapCondition()) for c, _ in table_conditions(pre.condition, table)]
    else:
        conds = [("", cond)]
    reqs = build_requests([(point, params)], conds, seed=seed, repeats=int(row["repeat"]) + 1, from_table=from_table,
                          label_by_condition=by_cond, **kw)
    got = [r for r in reqs if r.condition_id == cid and r.repeat == int(row["repeat"])]
    assert len(got) == 1
    assert got[0].run_id == int(row["run_id"]), "the results row's run id (a label the stages hash) changed"
    return got[0]


@pytest.mark.parametrize("run", SAMPLE_RUNS, ids=[p.name for p in SAMPLE_RUNS])
def test_the_builder_rebuilds_every_committed_heaps_seed_and_hash(run):
    rows = pd.read_parquet(run / "simulate" / "results.parquet")
    rows = rows[(rows["engine"] == "builtin") & (rows["source"] == CACHE_SOURCE)]
    assert len(rows)
    for _, row in rows.iterrows():
        assert request_from_row(row).hash == row["run_hash"]
        req = _rebuilt(run, rows, row)
        assert req.seed == int(row["seed"]), f"{run.name} {row['design']} run {row['run_id']}: seed changed"
        assert req.hash == row["run_hash"], f"{run.name} {row['design']} run {row['run_id']}: cache key changed"


def test_the_builder_is_the_schemes_the_commands_had():
    """The four seed schemes written out where each command built its own requests (simulate-heap,
    invert --validate, compare/diagnose, synth-lab) are one scheme of the builder."""
    num = Numerics()
    a, b = HeapCondition(), HeapCondition(lift_speed_mm_s=20.0)
    p = {"static_friction": 0.4}
    # simulate-heap: design run ids x (the rig, or a conditions table) x repeats
    for crossed in ([("", a)], [("A", a), ("B", b)]):
        old = [Request(p, c, num, derive_seed(3, rid if not cid else rid * 1000 + k + 1, r), "smoke", "bbd", rid, r,
                       "m", cid) for rid in (1, 2) for k, (cid, c) in enumerate(crossed) for r in range(2)]
        new = build_requests([(1, p), (2, p)], crossed, num, seed=3, repeats=2, preset="smoke", design="bbd",
                             model="m", from_table=crossed[0][0] != "")
        assert new == old
    # invert --validate, round k: one point, each condition its run id, one condition seeded as index 0
    for vconds in ([("A", a)], [("A", a), ("B", b)]):
        for k in (0, 1):
            old = [Request(p, c, num, derive_seed(5, i if len(vconds) > 1 else 0, r + k * 3), "smoke", "validate", i,
                           r + k * 3, condition_id=cid) for i, (cid, c) in enumerate(vconds, start=1) for r in range(3)]
            new = build_requests([(0, p)], vconds, num, seed=5, repeats=3, first_repeat=k * 3, preset="smoke",
                                 design="validate", from_table=len(vconds) > 1, label_by_condition=True)
            assert new == old
    # compare / diagnose (seed 0) and synth-lab (--seed): one point, every condition of a table
    conds = [("A", a), ("B", b)]
    old = [Request(p, c, num, derive_seed(7, i, r), "smoke", "lab", i, r, "truth", cid)
           for i, (cid, c) in enumerate(conds, start=1) for r in range(2)]
    assert build_requests([(0, p)], conds, num, seed=7, repeats=2, preset="smoke", design="lab", model="truth",
                          label_by_condition=True) == old
    assert seed_index(4, None) == 4 and seed_index(4, 2) == 4003


@pytest.mark.parametrize("args", [["compare", "--repeats", "3", "--preset", "smoke"],
                                  ["invert", "--validate", "3", "--preset", "smoke"],
                                  ["fit-surrogate"], ["bbd", "analyze"], ["measure-angle", "--images",
                                   str(ROOT / "sample_data" / "photos"), "--conditions",
                                   str(ROOT / "sample_data" / "photos" / "conditions.csv")]],
                         ids=["compare", "invert", "fit-surrogate", "bbd-analyze", "measure-angle"])
def test_the_committed_smoke_run_stays_up_to_date(tmp_path, args):
    """The smoke chain's stages, rerun on a copy of the committed run as `make smoke` runs them,
    have nothing to do: their locks (which hash the requests' results rows) are still valid."""
    run = tmp_path / "smoke"
    shutil.copytree(ROOT / "sample_runs" / "smoke", run)
    res = CliRunner().invoke(app, [*args[:2 if args[0] == "bbd" else 1], "--run", str(run),
                                   *args[2 if args[0] == "bbd" else 1:]])
    assert res.exit_code == 0, res.output
    assert "nothing to do" in res.output, res.output


@pytest.mark.parametrize("name, options", [
    ("smoke", {"preset": "smoke"}),
    ("calibration", {"preset": "default", "conditions": "measure/conditions.parquet"}),
    ("calibration-spring", {"preset": "default", "conditions": "measure/conditions.parquet",
                            "params": {"rolling_spring": 1}}),
])
def test_simulate_plans_the_committed_design_heaps(name, options):
    """simulate-heap's own plan (stages.simulate.plan_simulation, as the Makefile's commands call it)
    asks for exactly the committed design heaps, hash for hash (the index lists them as they finished)."""
    from calib_cli.stages.simulate import plan_simulation

    run = ROOT / "sample_runs" / name
    rows = pd.read_parquet(run / "simulate" / "results.parquet")
    opts = dict(options)
    if "conditions" in opts:
        opts["conditions"] = run / opts["conditions"]
    for design in DESIGNS:
        plan = plan_simulation(run, design=run / design / "design.parquet", say=lambda *a, **k: None, **opts)
        want = rows[rows["design"] == design]
        want = dict(zip(zip(want["run_id"], want["repeat"], want["condition_id"]), want["run_hash"]))
        assert {(r.run_id, r.repeat, r.condition_id): r.hash for r in plan.requests} == want, f"{name} {design}"


def test_a_candidates_heaps_are_seeded_by_its_values_not_its_place():
    """suggest-conditions' heaps at a candidate (SEEDINGS "condition") draw the same seeds whichever other
    candidates are named beside it, and a step's heaps draw the base's (common random numbers); a design's
    points ("content") draw apart; compare's and diagnose's ("table") stay by the condition's row."""
    from dataclasses import replace

    from calib_cli.discrepancy.point import SEEDINGS

    num = Numerics()
    a, b = HeapCondition(), HeapCondition(lift_speed_mm_s=20.0)
    p, q = {"static_friction": 0.4}, {"static_friction": 0.5}

    def seeds(how, points, conds):
        reqs = build_requests(points, conds, num, seed=0, repeats=2)
        reqs = [replace(r, seed=SEEDINGS[how](0, r)) for r in reqs] if SEEDINGS[how] else reqs
        return {(r.condition_id, r.params["static_friction"], r.repeat): r.seed for r in reqs}

    alone, beside = seeds("condition", [(0, p)], [("B", b)]), seeds("condition", [(0, p)], [("A", a), ("B", b)])
    assert alone[("B", 0.4, 0)] == beside[("B", 0.4, 0)] and alone[("B", 0.4, 1)] == beside[("B", 0.4, 1)]
    assert alone[("B", 0.4, 0)] != alone[("B", 0.4, 1)] and beside[("A", 0.4, 0)] != beside[("B", 0.4, 0)]
    step = seeds("condition", [(0, q)], [("B", b)])
    assert step[("B", 0.5, 0)] == alone[("B", 0.4, 0)]  # a finite difference's two ends draw alike
    design = seeds("content", [(1, p), (2, q)], [("B", b)])
    assert design[("B", 0.4, 0)] != design[("B", 0.5, 0)]
    # by the row, as compare and diagnose seed the measured table: B's heaps change with its place
    assert seeds("table", [(0, p)], [("B", b)])[("B", 0.4, 0)] != seeds("table", [(0, p)], [("A", a), ("B", b)])[
        ("B", 0.4, 0)]


#: what a heap's cache key leaves implicit (a parameter not given takes its default; walls that never take the
#: grains' value), as of the physics version named: the key holds the parameters given, not these
IMPLICIT = {"source": "77675d5eca62",
            "defaults": {"static_friction": 0.5, "rolling_friction": 0.1, "surface_energy": 0.0, "restitution": 0.2,
                         "rolling_own_spin": 0.0, "friction_net_force": 0.0, "rolling_spring": 0.0,
                         "caps_pulloff": 0.0, "surface_tension": 0.0, "contact_angle": 0.0, "liquid_volume": 0.01},
            "wall_zero": ["surface_energy", "surface_tension"]}


def test_a_changed_default_comes_with_a_raised_physics_version():
    """A heap's key names the parameters given, not the defaults the rest take: a default changed at an
    unchanged physics version would serve heaps cached with the old one. So a default may change only with
    a law's (or the kernel's) version raised, which moves the key's source, and this table with it."""
    from calib_cli.dem.heap import PARTICLE_DEFAULTS, WALL_ZERO

    now = {"source": CACHE_SOURCE, "defaults": dict(PARTICLE_DEFAULTS), "wall_zero": sorted(WALL_ZERO)}
    assert now["source"] == IMPLICIT["source"] or now == IMPLICIT, (
        "the physics version moved: set IMPLICIT to its source and the defaults it runs with")
    assert now == IMPLICIT, (
        "a heap's implicit default changed at an unchanged physics version: raise the version of the law (or "
        "the kernel) that reads it, so heaps cached with the old default are simulated again; then update IMPLICIT")
