import numpy as np
import pytest
from hypothesis import given, strategies as st

from calib_cli.errors import CalibError
from calib_cli.space import Factor, ParameterSpace

finite = st.floats(-1e6, 1e6, allow_nan=False)


@given(lo=finite, width=st.floats(1e-6, 1e6), x=st.lists(st.floats(-3, 3), min_size=1, max_size=20))
def test_coded_natural_round_trip(lo, width, x):
    f = Factor("a", lo, lo + width)
    v = f.to_natural(x)
    np.testing.assert_allclose(f.to_coded(v), x, atol=1e-6 * max(1, abs(lo) / width))


def test_low_high_map_to_minus_plus_one():
    s = ParameterSpace.of([Factor("a", 0.112, 0.438), Factor("b", 0.875, 1.625)])
    np.testing.assert_allclose(s.to_coded([[0.112, 1.625], [0.275, 1.25]]), [[-1, 1], [0, 0]], atol=1e-12)
    np.testing.assert_allclose(s.to_natural([[1, -1]]), [[0.438, 0.875]])


@pytest.mark.parametrize("lo,hi", [(1, 1), (2, 1), (float("nan"), 1), (0, float("inf"))])
def test_bad_ranges_are_rejected(lo, hi):
    with pytest.raises(CalibError):
        Factor("a", lo, hi)


def test_single_level_in_data_is_an_error():
    import pandas as pd

    with pytest.raises(CalibError, match="single level"):
        ParameterSpace.from_data(pd.DataFrame({"a": [1.0, 1.0]}), ["a"])


def test_duplicate_and_unknown_names():
    with pytest.raises(CalibError):
        ParameterSpace.of([Factor("a", 0, 1), Factor("a", 0, 2)])
    with pytest.raises(CalibError, match="unknown factor"):
        ParameterSpace.of([Factor("a", 0, 1)])["b"]
