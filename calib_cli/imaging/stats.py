"""Repeat statistics of measured angles (paper Table 1)."""

from __future__ import annotations

import numpy as np
from scipy import stats

STAT_COLUMNS = ["n", "mean", "median", "sd", "range", "cv_percent", "se", "ci95_low", "ci95_high"]


def describe(values) -> dict:
    """n, mean, median, sample sd, range, CV %, standard error, t-based 95 % CI."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    n = len(v)
    if n == 0:
        return {k: (0 if k == "n" else np.nan) for k in STAT_COLUMNS}
    mean = float(v.mean())
    sd = float(v.std(ddof=1)) if n > 1 else np.nan
    se = sd / np.sqrt(n) if n > 1 else np.nan
    half = float(stats.t.ppf(0.975, n - 1) * se) if n > 1 else np.nan
    return {"n": n, "mean": mean, "median": float(np.median(v)), "sd": sd, "range": float(np.ptp(v)),
            "cv_percent": 100 * sd / mean if n > 1 else np.nan, "se": se,
            "ci95_low": mean - half, "ci95_high": mean + half}
