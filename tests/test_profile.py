"""profile.huber_line: statsmodels' RLM (HuberT, MAD scale) written out without BLAS, equal to it to rounding."""

import warnings
from pathlib import Path

import numpy as np
import pytest
import statsmodels.api as sm
from hypothesis import given, settings
from hypothesis import strategies as st

from calib_cli import artifacts as art
from calib_cli import profile
from calib_cli.dem.angle import repose_angle_coords
from calib_cli.imaging.measure import measure_image
from calib_cli.imaging.synth import SynthOptions, synth_heap


def statsmodels_rlm(r, h):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a perfect fit warns (scale 0)
        return sm.RLM(h, sm.add_constant(r), M=sm.robust.norms.HuberT()).fit().params


@settings(max_examples=300, deadline=None)
@given(n=st.integers(3, 400), slope=st.floats(-3, 3), noise=st.sampled_from([0.0, 1e-4, 2e-3, 0.05]),
       outliers=st.integers(0, 8), rounding=st.sampled_from([None, 3, 4]), seed=st.integers(0, 2**31))
def test_huber_line_equals_statsmodels(n, slope, noise, outliers, rounding, seed):
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.0, 0.05, n)
    h = 0.03 + slope * r + rng.normal(0.0, noise, n) if noise else 0.03 + slope * r
    h[rng.integers(0, n, min(outliers, n))] += rng.normal(0.0, 0.01, min(outliers, n))
    if rounding:  # pixel-like quantised heights: ties in the MAD's median
        h = np.round(h, rounding)
    np.testing.assert_allclose(profile.huber_line(r, h), statsmodels_rlm(r, h), rtol=1e-9, atol=1e-12)


EXAMPLE = Path(__file__).resolve().parents[1] / "sample_runs/smoke/simulate/runs/example/state.parquet"


def test_heap_and_image_angles_agree_with_statsmodels(monkeypatch):
    """The real callers: the coordinate angle of a simulated heap (committed example state)
    and the image angle of synthetic photographs agree to rounding with either fit."""
    state = art.read_table(EXAMPLE)
    pos, rad = state[["x", "y", "z"]].to_numpy(), state["radius"].to_numpy()
    images = [synth_heap(a, SynthOptions(), seed=s) for a, s in ((25, 0), (38, 1))]
    ours = [repose_angle_coords(pos, rad)] + [measure_image(im) for im in images]
    monkeypatch.setattr(profile, "huber_line", statsmodels_rlm)
    ref = [repose_angle_coords(pos, rad)] + [measure_image(im) for im in images]
    close = dict(rel=0, abs=1e-9)  # degrees
    assert ours[0].angle == pytest.approx(ref[0].angle, **close) and ours[0].sd == pytest.approx(ref[0].sd, **close)
    for a, b in zip(ours[1:], ref[1:]):
        assert (a.repose_angle, a.angle_left, a.angle_right) == pytest.approx(
            (b.repose_angle, b.angle_left, b.angle_right), **close)


def test_exact_line_and_degenerate_input():
    r = np.linspace(0.0, 0.04, 9)
    c0, c1 = profile.huber_line(r, 0.03 - 0.7 * r)
    assert c1 == pytest.approx(-0.7, abs=1e-12) and c0 == pytest.approx(0.03, abs=1e-12)
    fit = profile.fit_flank(r, np.full(9, np.nan), 0.03)
    assert not fit.ok


# ------------------------------------------------------------------ the profile's fullness
S = np.linspace(-100.0, 100.0, 801)


def test_the_fullness_of_a_cone_a_dome_and_a_concave_heap_is_their_area_ratio():
    """A cone's straight flanks 1; a parabola H (1 - (s/a)^2) 4/3 at any level; a concave H (1 - |s|/a)^2
    2 [(1 - l^1.5)/3 - l (1 - sqrt l)] / ((1 - l)(1 - sqrt l)) (0.8528 at l = 0.15)."""
    l = profile.FULLNESS_LEVEL
    assert profile.fullness(S, np.clip(50 - np.abs(S), 0, None)) == pytest.approx(1.0, abs=1e-9)
    assert profile.fullness(S, 50 * np.clip(1 - (S / 60) ** 2, 0, None)) == pytest.approx(4 / 3, abs=1e-4)
    concave = 2 * ((1 - l ** 1.5) / 3 - l * (1 - l ** 0.5)) / ((1 - l) * (1 - l ** 0.5))
    assert profile.fullness(S, 50 * np.clip(1 - np.abs(S) / 60, 0, None) ** 2) == pytest.approx(concave, abs=1e-3)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.01, 1e4), st.floats(0.01, 1e4), st.floats(-50, 50))
def test_the_fullness_is_free_of_scale_and_position(ks, kh, shift):
    """A photograph's pixels and a simulation's metres, stretched apart, give the same number."""
    h = 50 * np.clip(1 - (S / 60) ** 2, 0, None) ** 0.7
    assert profile.fullness(ks * (S + shift), kh * h) == pytest.approx(profile.fullness(S, h), rel=1e-9)


def test_a_grain_beyond_the_toe_is_not_the_heap_and_a_flank_that_never_falls_gives_nan():
    cone = np.clip(50 - np.abs(S), 0, None)
    grain = cone + np.where(np.abs(S - 80) < 3, 12.0, 0.0)  # a grain rolled away, above the 15 % level
    assert profile.fullness(S, grain) == pytest.approx(1.0, abs=1e-9)
    assert np.isnan(profile.fullness(S, np.clip(80 - np.abs(S - 60), 0, None)))  # cut by the frame's side
    assert np.isnan(profile.fullness(S[:2], cone[:2])) and np.isnan(profile.fullness(S, np.zeros_like(S)))


def test_a_photographed_cone_measures_a_fullness_of_one_and_a_rounded_apex_more():
    """Through the image pipeline: a synthetic cone's silhouette (6 px grains, noise) 0.99; its apex
    rounded over 40 px (a flat-topped heap of the same flanks, fuller than a cone of its height) 1.10."""
    cone = measure_image(synth_heap(38, SynthOptions(noise_sd=6), seed=1))
    rounded = measure_image(synth_heap(38, SynthOptions(apex_round_px=40), seed=1))
    assert profile.fullness(cone.profile_s, cone.profile_h) == pytest.approx(1.0, abs=0.02)
    assert profile.fullness(rounded.profile_s, rounded.profile_h) > 1.06


# ------------------------------------------------------------------ the band fullness: shapes another rig gives
def test_the_band_fullness_reads_straight_flanks_as_one_whatever_the_top():
    """A cone and a truncated cone (a fill that never reached an apex) give 1; fullness reads the flat
    top as convexity (1.23 for a top at 80 % of the cone's height). Convex and concave flanks keep their
    sign: a parabola 1.056, a concave heap 0.895 (the band leaves out the apex, where a dome bends most)."""
    cone = np.clip(50 - np.abs(S), 0, None)
    for top in (50, 44, 40, 35):
        assert profile.band_fullness(S, np.minimum(cone, top)) == pytest.approx(1.0, abs=1e-4), top
    assert profile.fullness(S, np.minimum(cone, 40)) == pytest.approx(1.227, abs=1e-3)
    dome = 50 * np.clip(1 - (S / 60) ** 2, 0, None)
    assert profile.band_fullness(S, dome) == pytest.approx(1.0556, abs=1e-3)
    assert profile.band_fullness(S, 50 * np.clip(1 - np.abs(S) / 60, 0, None) ** 2) == pytest.approx(0.8946, abs=2e-3)


def test_a_skirt_of_single_grains_below_the_band_and_grains_beyond_the_toe_move_neither_response():
    """A layer of grains one tenth of the heap's height spread 30 units past the toe (a skirt), and a grain
    rolled away: both responses unchanged. A skirt reaching above 15 % of the height would move both."""
    cone = np.clip(50 - np.abs(S), 0, None)
    skirt = np.maximum(cone, np.where(np.abs(S) < 80, 5.0, 0.0))
    grain = cone + np.where(np.abs(S - 80) < 3, 12.0, 0.0)
    for shape in (skirt, grain):
        assert profile.band_fullness(S, shape) == pytest.approx(1.0, abs=1e-9)
        assert profile.fullness(S, shape) == pytest.approx(1.0, abs=1e-9)
    thick = np.maximum(cone, np.where(np.abs(S) < 80, 10.0, 0.0))
    assert profile.band_fullness(S, thick) < 0.95


def test_the_stub_of_a_collapsed_column_is_no_heap_profile():
    """A column's stub standing on a low heap sets the height both responses scale by: neither reads the
    heap under it (0.75-0.77, a concave heap), which is why a pile that stands in one view is a column in
    all (measure-angle's pile column) rather than a profile to fit."""
    stub = np.maximum(0.7 * np.clip(50 - np.abs(S), 0, None), np.where(np.abs(S) < 6, 50.0, 0.0))
    assert profile.band_fullness(S, stub) < 0.8 and profile.fullness(S, stub) < 0.8


@settings(max_examples=30, deadline=None)
@given(st.floats(0.01, 1e4), st.floats(0.01, 1e4), st.floats(-50, 50))
def test_the_band_fullness_is_free_of_scale_and_position(ks, kh, shift):
    h = np.minimum(50 * np.clip(1 - (S / 60) ** 2, 0, None) ** 0.7, 42.0)
    assert profile.band_fullness(ks * (S + shift), kh * h) == pytest.approx(profile.band_fullness(S, h), rel=1e-9)
