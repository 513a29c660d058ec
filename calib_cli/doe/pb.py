"""Plackett-Burman screening (paper section 3.1, Tables 2-4).

``design`` samples a two-level PB design (pyDOE3) with the factors in the first
columns and the spare columns as dummies; ``analyze`` fits the main-effects model
``y = b0 + sum_j b_j x_j`` in coded units. The dummy columns are pooled into the
residual, as Design-Expert does for Table 4 (4 factors, 12 runs -> 7 residual df).
Effect of factor j = mean(y | x_j=+1) - mean(y | x_j=-1) = 2 b_j.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from ..errors import CalibError
from ..space import ParameterSpace
from .linear import LinearFit, fit_linear
from .sizes import check_runs


def design(space: ParameterSpace, runs: int = 12) -> tuple[pd.DataFrame, np.ndarray]:
    """A ``runs``-run PB design: (natural-unit table with ``run_id`` and dummies, coded array)."""
    k = len(space)
    check_runs(runs, k)
    import pyDOE3  # here, not at import: it costs every CLI command 0.6 s

    coded = pyDOE3.pbdesign(runs - 1)
    if coded.shape[0] != runs:
        raise CalibError(f"no {runs}-run Plackett-Burman design is available")
    nat = space.to_natural(coded[:, :k])
    df = pd.DataFrame(nat, columns=space.names)
    for j in range(k, coded.shape[1]):
        df[f"dummy_{j - k + 1}"] = coded[:, j]
    df.insert(0, "run_id", np.arange(1, runs + 1))
    return df, coded[:, :k]


@dataclass
class PBResult:
    """Screening result: main effects, ANOVA, which factors go forward."""

    space: ParameterSpace
    fit: LinearFit
    effects: pd.DataFrame
    alpha: float

    @property
    def significant(self) -> list[str]:
        e = self.effects
        return list(e.loc[e["significant"]].sort_values("rank")["factor"])

    @property
    def anova(self) -> pd.DataFrame:
        return self.fit.anova


def analyze(data: pd.DataFrame, space: ParameterSpace, response: str = "repose_angle",
            alpha: float = 0.05) -> PBResult:
    """Main-effects ANOVA of a two-level screening design (Table 3 -> Table 4)."""
    coded = space.to_coded(data[space.names].to_numpy(dtype=float))
    if not np.allclose(np.abs(coded), 1.0, atol=1e-6):
        raise CalibError("a Plackett-Burman analysis needs every factor at exactly two levels (its low and high)")
    y = data[response].to_numpy(dtype=float)
    fit = fit_linear(y, coded, space.names)
    a = fit.anova.set_index("source")
    ss_total = float(a.loc["Cor total", "sum_sq"])
    rows = []
    for f in space.factors:
        b = float(fit.coef[f.name])
        rows.append({
            "factor": f.name, "symbol": f.symbol, "unit": f.unit, "low": f.low, "high": f.high,
            "coefficient": b, "effect": 2 * b,
            "sum_sq": float(a.loc[f.name, "sum_sq"]),
            "contribution_percent": 100 * float(a.loc[f.name, "sum_sq"]) / ss_total,
            "F": float(a.loc[f.name, "F"]), "p_value": float(a.loc[f.name, "p_value"]),
        })
    eff = pd.DataFrame(rows)
    eff["significant"] = eff["p_value"] < alpha
    eff["rank"] = eff["sum_sq"].rank(ascending=False, method="first").astype(int)
    return PBResult(space, fit, eff, alpha)
