"""Least-squares fit of a model that is linear in its terms, with its ANOVA.

The fitting is statsmodels' OLS; this module adds what Design-Expert reports and
statsmodels does not: per-term partial (type III) sums of squares, lack of fit
against pure error from replicated points, predicted R2 from PRESS and adequate
precision.

For a single-degree-of-freedom term j, the partial sum of squares is
``SS_j = t_j^2 * MSE`` (= b_j^2 / [(X'X)^-1]_jj), i.e. the increase of the residual
sum of squares when the term is dropped; for orthogonal designs it equals the
sequential one. Adequate precision (Design-Expert):
``(max yhat - min yhat) / sqrt(p * MSE / n)``, p the number of model parameters
(mean prediction variance = p sigma^2 / n).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import pandas as pd
from scipy import stats

from ..errors import CalibError

ANOVA_COLUMNS = ["source", "sum_sq", "df", "mean_sq", "F", "p_value"]


@dataclass
class LinearFit:
    """Results of :func:`fit_linear` (statsmodels-style: tables plus scalars)."""

    terms: list[str]
    coef: pd.Series
    std_err: pd.Series
    anova: pd.DataFrame
    stats: dict
    fitted: np.ndarray
    residuals: np.ndarray
    ols: object = field(repr=False)

    def coefficient_table(self) -> pd.DataFrame:
        t = self.coef / self.std_err
        p = 2 * stats.t.sf(np.abs(t), self.stats["df_resid"])
        return pd.DataFrame({"term": self.coef.index, "coefficient": self.coef.to_numpy(),
                             "std_err": self.std_err.to_numpy(), "t": t.to_numpy(), "p_value": p})


def _replicate_groups(X: np.ndarray, decimals: int = 9) -> np.ndarray:
    keys = [tuple(np.round(row, decimals)) for row in X]
    uniq = {k: i for i, k in enumerate(dict.fromkeys(keys))}
    return np.array([uniq[k] for k in keys])


def fit_linear(
    y: np.ndarray,
    X: np.ndarray,
    terms: Sequence[str],
    points: np.ndarray | None = None,
    lack_of_fit: bool = False,
) -> LinearFit:
    """Fit ``y = X b`` (X without intercept column; an intercept is added).

    ``points`` are the design points (coded factors) used to find replicates for
    the pure-error / lack-of-fit split; ``lack_of_fit`` adds those rows.
    """
    y = np.asarray(y, dtype=float)
    X = np.asarray(X, dtype=float)
    n, k = X.shape
    p = k + 1
    if n <= p:
        raise CalibError(f"{n} runs cannot fit a model with {p} parameters (need more runs than parameters)")
    if not np.all(np.isfinite(y)) or not np.all(np.isfinite(X)):
        raise CalibError("responses or factors contain NaN or infinite values")
    if np.ptp(y) == 0:  # no variation: every F and R2 would divide by zero
        raise CalibError(f"all {n} responses equal {y[0]:g}: no effect can be estimated from them")
    A = np.column_stack([np.ones(n), X])
    if np.linalg.matrix_rank(A) < p:
        raise CalibError("the design cannot separate the model terms (singular design matrix)")
    import statsmodels.api as sm  # here, not at the top: start-up of the commands that fit nothing

    res = sm.OLS(y, A).fit()
    names = ["Intercept", *terms]
    coef = pd.Series(res.params, index=names)
    se = pd.Series(res.bse, index=names)
    mse = float(res.mse_resid)
    df_res = int(round(res.df_resid))
    ss_res = float(res.ssr)
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    ss_model = ss_tot - ss_res

    def row(src, ss, df, denom=mse, denom_df=df_res):
        ms = ss / df if df else np.nan
        F = ms / denom if denom > 0 and df else np.nan
        pv = float(stats.f.sf(F, df, denom_df)) if np.isfinite(F) else np.nan
        return [src, ss, df, ms, F, pv]

    rows = [row("Model", ss_model, k)]
    tv = np.asarray(res.tvalues)[1:]
    for name, t in zip(terms, tv):
        rows.append(row(name, float(t**2 * mse), 1))
    rows.append([ "Residual", ss_res, df_res, mse, np.nan, np.nan])
    lof = {"lack_of_fit_F": np.nan, "lack_of_fit_p": np.nan}
    if lack_of_fit:
        pts = X if points is None else np.asarray(points, dtype=float)
        g = _replicate_groups(pts)
        ss_pe = float(sum(np.sum((y[g == i] - y[g == i].mean()) ** 2) for i in np.unique(g)))
        df_pe = int(n - len(np.unique(g)))
        df_lof = df_res - df_pe
        if df_pe < 1 or df_lof < 1:
            raise CalibError("lack of fit needs replicated points and more distinct points than parameters")
        ms_pe = ss_pe / df_pe
        lof_row = row("Lack of fit", ss_res - ss_pe, df_lof, ms_pe, df_pe)
        rows.append(lof_row)
        rows.append(["Pure error", ss_pe, df_pe, ms_pe, np.nan, np.nan])
        lof = {"lack_of_fit_F": lof_row[4], "lack_of_fit_p": lof_row[5]}
    rows.append(["Cor total", ss_tot, n - 1, np.nan, np.nan, np.nan])
    anova = pd.DataFrame(rows, columns=ANOVA_COLUMNS)
    anova["df"] = anova["df"].astype(int)

    fitted = np.asarray(res.fittedvalues)
    h = np.asarray(res.get_influence().hat_matrix_diag)
    if np.any(h >= 1 - 1e-12):
        press = np.nan  # a run that determines its own prediction: PRESS undefined
    else:
        press = float(np.sum((res.resid / (1 - h)) ** 2))
    stats_ = {
        "n": n, "p": p, "df_resid": df_res,
        "r2": float(res.rsquared), "r2_adj": float(res.rsquared_adj),
        "r2_pred": 1 - press / ss_tot if np.isfinite(press) else np.nan,
        "press": press,
        "adeq_precision": float((fitted.max() - fitted.min()) / np.sqrt(p * mse / n)) if mse > 0 else np.inf,
        "cv_percent": float(np.sqrt(mse) / y.mean() * 100),
        "std_dev": float(np.sqrt(mse)),
        "mean": float(y.mean()),
        "model_F": float(anova.loc[0, "F"]), "model_p": float(anova.loc[0, "p_value"]),
        **lof,
    }
    return LinearFit(list(terms), coef, se, anova, stats_, fitted, np.asarray(res.resid), res)
