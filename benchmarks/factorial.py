"""Shared by the factorial benchmarks (shape_effect.py, rolling_law.py)."""

from __future__ import annotations

import numpy as np


def effects(cells, y):
    """Two-level factorial from heap angles y[cell, seed]: (cell means, coefficients per coded unit
    - half the change from low to high, as the paper's Eq. 7 -, pooled within-cell sd, their SE)."""
    X = np.array(cells, float)
    m = np.nanmean(y, axis=1)
    sd = float(np.sqrt(np.nanmean(np.nanvar(y, axis=1, ddof=1))))
    return m, X.T @ m / len(cells), sd, sd / np.sqrt(y.size)
