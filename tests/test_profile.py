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
