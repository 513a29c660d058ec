"""calib_cli.conditions: the range test every stage applies before trusting a surrogate at a condition."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from calib_cli.conditions import outside_range


def test_outside_range_forgives_float_noise_and_places_no_nan():
    assert outside_range([50.0, 100.0, 75.0], 50.0, 100.0).tolist() == [False, False, False]
    assert outside_range([100.0 + 1e-8, 49.999999, np.nan, 150.0], 50.0, 100.0).tolist() == [False, True, True, True]
    assert not outside_range(0.5 + 5e-10, 0.1, 0.5) and outside_range(0.5 + 2e-9, 0.1, 0.5)


@settings(max_examples=200, deadline=None)
@given(lo=st.floats(-1e3, 1e3), width=st.floats(0, 1e3), f=st.floats(0, 1))
def test_outside_range_holds_every_value_of_its_range(lo, width, f):
    hi = lo + width
    x = min(max(lo + f * width, lo), hi)
    assert not outside_range(x, lo, hi) and outside_range(hi + 1e-6 * max(width, 1.0), lo, hi)
