"""Steepest ascent toward the target angle (paper section 3.2, Table 5).

The path is a line through the centre of the screened region, in coded units,
spanning it so that the fastest-moving factor goes from -1 to +1 in ``steps``
equal steps. Its direction is

* ``gradient``: d_j = s * b_j / max|b| over the significant factors, b the
  first-order (PB) coefficients and s = sign(target - b0): the textbook steepest
  ascent (Myers & Montgomery, RSM, 5.2), moving each factor in proportion to its
  effect and toward the target;
* ``diagonal``: d_j = +1 for every significant factor, i.e. every factor from its
  low to its high level together. This is what the paper's Table 5 did (it raised
  static friction although its PB effect is negative).

``analyze`` computes the relative error |y - target| / target of each step; the
best step and its two neighbours give the bracket the Box-Behnken design spans.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import CalibError
from ..space import Factor, ParameterSpace


def direction(coefficients: dict[str, float], intercept: float, target: float, method: str) -> np.ndarray:
    b = np.array(list(coefficients.values()), dtype=float)
    if method == "diagonal":
        return np.ones_like(b)
    if method != "gradient":
        raise CalibError(f"unknown ascent method {method!r}")
    if not np.any(b):
        raise CalibError("all screening coefficients are zero: no ascent direction")
    s = 1.0 if target >= intercept else -1.0
    return s * b / np.max(np.abs(b))


def design(space: ParameterSpace, d: np.ndarray, steps: int, fixed: dict[str, float]) -> pd.DataFrame:
    """The path: ``steps`` points from centre - d/max|d| to centre + d/max|d| (coded)."""
    if steps < 3:
        raise CalibError("a steepest-ascent path needs at least 3 steps")
    d = np.asarray(d, dtype=float)
    t = np.linspace(-1.0, 1.0, steps) / np.max(np.abs(d))
    coded = t[:, None] * d[None, :]
    df = pd.DataFrame(space.to_natural(coded), columns=space.names)
    for name, v in fixed.items():
        df[name] = float(v)
    df.insert(0, "step", np.arange(1, steps + 1))
    df.insert(0, "run_id", np.arange(1, steps + 1))
    return df


@dataclass
class AscentResult:
    path: pd.DataFrame  # design columns + response + relative_error_percent + best
    best_step: int
    bracket: pd.DataFrame  # factor, low, high, center
    at_edge: bool
    target: float


def analyze(path: pd.DataFrame, factors: list[str], response: str, target: float) -> AscentResult:
    if target <= 0 or not np.isfinite(target):
        raise CalibError(f"target must be a positive angle, got {target}")
    p = path.sort_values("step").reset_index(drop=True).copy()
    p["relative_error_percent"] = 100 * np.abs(p[response] - target) / target
    err = p["relative_error_percent"].to_numpy()
    if not np.isfinite(err).any():
        raise CalibError("no step of the ascent path has a response (none formed a heap?)")
    # a step without a response (no heap) is never the best, but still bounds the bracket
    i = int(np.nanargmin(err))
    p["best"] = False
    p.loc[i, "best"] = True
    lo_i, hi_i = max(i - 1, 0), min(i + 1, len(p) - 1)
    at_edge = i in (0, len(p) - 1)
    rows = []
    for f in factors:
        a, b = float(p.loc[lo_i, f]), float(p.loc[hi_i, f])
        low, high = min(a, b), max(a, b)
        if not high > low:
            raise CalibError(f"factor {f!r} does not move along the path; it cannot span a bracket")
        rows.append({"factor": f, "low": low, "high": high, "center": float(p.loc[i, f])})
    return AscentResult(p, int(p.loc[i, "step"]), pd.DataFrame(rows), at_edge, float(target))


def screening_repeats(path: pd.DataFrame, screening: pd.DataFrame, effects: pd.DataFrame, sd: float,
                      factors: list[str], response: str) -> pd.DataFrame:
    """Ascent steps that repeat screening runs in every factor the path moves, checked against the
    screening's own first-order model (paper section 3.1; Myers & Montgomery 5.2).

    A step and the m screening runs at the same moved factors may still differ in the others (the
    path holds those at fixed levels), so the expected difference is sum_k b_k (c_k,step - mean c_k,runs)
    over the screening's coefficients b_k per coded unit, c = (2x - low - high) / (high - low); a
    factor the path lacks counts as its mid level. z = (observed - expected) / (sd sqrt(1 + 1/m)),
    sd the screening's residual standard deviation. |z| > 3 says the two stages do not agree: they
    were probably not simulated (or measured) with the same setup.
    Rows: step, runs (the screening's run_id, else 1-based rows), n, angle, screening_angle, expected, z."""
    cols = ["step", "runs", "n", "angle", "screening_angle", "expected", "z"]
    rows = []
    if not len(screening) or not np.isfinite(sd) or sd <= 0:
        return pd.DataFrame(rows, columns=cols)
    ids = screening["run_id"].to_numpy() if "run_id" in screening.columns else np.arange(1, len(screening) + 1)
    eff = effects.set_index("factor")
    screened = {f: Factor(f, float(eff.loc[f, "low"]), float(eff.loc[f, "high"])) for f in eff.index}

    def coded(df: pd.DataFrame, f: str) -> np.ndarray:
        return screened[f].to_coded(df[f]) if f in df.columns else np.zeros(len(df))

    for _, step in path.iterrows():
        if not np.isfinite(step[response]):
            continue
        same = np.ones(len(screening), bool)
        for f in factors:
            same &= np.isclose(screening[f].to_numpy(float), float(step[f]), rtol=1e-9, atol=1e-12)
        if not same.any():
            continue
        runs = screening[same]
        one = path.loc[[step.name]]
        expected = sum(float(eff.loc[f, "coefficient"]) * (coded(one, f)[0] - coded(runs, f).mean())
                       for f in eff.index)
        obs = float(step[response]) - float(runs[response].mean())
        m = int(same.sum())
        rows.append({"step": int(step["step"]), "runs": [int(i) for i in ids[same]], "n": m,
                     "angle": float(step[response]), "screening_angle": float(runs[response].mean()),
                     "expected": expected, "z": (obs - expected) / (sd * np.sqrt(1 + 1 / m))})
    return pd.DataFrame(rows, columns=cols)
