"""Shared by the factorial benchmarks (shape_effect.py, rolling_law.py)."""

from __future__ import annotations

import warnings

import numpy as np


def effects(cells, y):
    """Main effects of a design whose coded columns are orthogonal to each other and to the
    intercept (two-level factorial, Plackett-Burman; the linear terms of a Box-Behnken, which are
    orthogonal to its quadratic terms too) from heap angles y[cell, seed]: (cell means,
    coefficients per coded unit - half the change from low to high, as the paper's Eq. 7 -,
    pooled within-cell sd, their SE)."""
    X = np.array(cells, float)
    with warnings.catch_warnings():  # a cell of one heap has no variance, one of none no mean: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmean(y, axis=1)
        sd = float(np.sqrt(np.nanmean(np.nanvar(y, axis=1, ddof=1))))
    d = (X**2).sum(axis=0)  # n for a factorial or PB, 8 for a 3-factor BBD
    return m, X.T @ m / d, sd, sd / np.sqrt(d.max() * y.shape[1])


def coded_levels(df, names) -> np.ndarray:
    """The design levels of df's columns `names` coded -1 / 0 / +1 by each column's own min and max,
    so that a design over other ranges (a scaled surface energy) matches the paper's point for point."""
    x = df[names].to_numpy(float)
    lo, hi = x.min(axis=0), x.max(axis=0)
    return np.rint(2 * (x - lo) / (hi - lo) - 1)
