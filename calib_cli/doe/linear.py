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


def _check_design(y: np.ndarray, A: np.ndarray) -> None:
    """Refuse what OLS cannot answer: too few runs, non-finite values, no variation, aliased terms."""
    n, p = A.shape
    if n <= p:
        raise CalibError(f"{n} runs cannot fit a model with {p} parameters (need more runs than parameters)")
    if not np.all(np.isfinite(y)) or not np.all(np.isfinite(A)):
        raise CalibError("responses or factors contain NaN or infinite values")
    if np.ptp(y) == 0:  # no variation: every F and R2 would divide by zero
        raise CalibError(f"all {n} responses equal {y[0]:g}: no effect can be estimated from them")
    if np.linalg.matrix_rank(A) < p:
        raise CalibError("the design cannot separate the model terms (singular design matrix)")


def _anova_row(src, ss, df, denom, denom_df) -> list:
    ms = ss / df if df else np.nan
    F = ms / denom if denom > 0 and df else np.nan
    pv = float(stats.f.sf(F, df, denom_df)) if np.isfinite(F) else np.nan
    return [src, ss, df, ms, F, pv]


def _lack_of_fit_rows(y: np.ndarray, pts: np.ndarray, ss_res: float, df_res: int) -> list[list]:
    """Lack of fit against pure error from replicated points (Montgomery, Design and Analysis of
    Experiments, 6.7): SS_res = SS_lof + SS_pe."""
    g = _replicate_groups(pts)
    ss_pe = float(sum(np.sum((y[g == i] - y[g == i].mean()) ** 2) for i in np.unique(g)))
    df_pe = int(len(y) - len(np.unique(g)))
    df_lof = df_res - df_pe
    if df_pe < 1 or df_lof < 1:
        raise CalibError("lack of fit needs replicated points and more distinct points than parameters")
    ms_pe = ss_pe / df_pe
    return [_anova_row("Lack of fit", ss_res - ss_pe, df_lof, ms_pe, df_pe), ["Pure error", ss_pe, df_pe, ms_pe, np.nan, np.nan]]


def _fit_stats(res, y: np.ndarray, p: int, mse: float, ss_tot: float, anova: pd.DataFrame, lof: dict) -> dict:
    """Design-Expert's fit statistics: R2 (adjusted, predicted from PRESS), adequate precision, CV."""
    n = len(y)
    fitted = np.asarray(res.fittedvalues)
    h = np.asarray(res.get_influence().hat_matrix_diag)
    if np.any(h >= 1 - 1e-12):
        press = np.nan  # a run that determines its own prediction: PRESS undefined
    else:
        press = float(np.sum((res.resid / (1 - h)) ** 2))
    return {
        "n": n, "p": p, "df_resid": int(round(res.df_resid)),
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


def fit_linear(
    y: np.ndarray,
    X: np.ndarray,
    terms: Sequence[str],
    points: np.ndarray | None = None,
    lack_of_fit: bool = False,
) -> LinearFit:
    """Fit ``y = X b`` (X without intercept column; an intercept is added) with its ANOVA.

    ``points`` are the design points (coded factors) used to find replicates for
    the pure-error / lack-of-fit split; ``lack_of_fit`` adds those rows.
    """
    y = np.asarray(y, dtype=float)
    X = np.asarray(X, dtype=float)
    n, k = X.shape
    A = np.column_stack([np.ones(n), X])
    _check_design(y, A)
    import statsmodels.api as sm  # here, not at the top: start-up of the commands that fit nothing

    res = sm.OLS(y, A).fit()
    names = ["Intercept", *terms]
    mse = float(res.mse_resid)
    df_res = int(round(res.df_resid))
    ss_res = float(res.ssr)
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    rows = [_anova_row("Model", ss_tot - ss_res, k, mse, df_res)]
    for name, t in zip(terms, np.asarray(res.tvalues)[1:]):
        rows.append(_anova_row(name, float(t**2 * mse), 1, mse, df_res))
    rows.append(["Residual", ss_res, df_res, mse, np.nan, np.nan])
    lof = {"lack_of_fit_F": np.nan, "lack_of_fit_p": np.nan}
    if lack_of_fit:
        extra = _lack_of_fit_rows(y, X if points is None else np.asarray(points, dtype=float), ss_res, df_res)
        rows += extra
        lof = {"lack_of_fit_F": extra[0][4], "lack_of_fit_p": extra[0][5]}
    rows.append(["Cor total", ss_tot, n - 1, np.nan, np.nan, np.nan])
    anova = pd.DataFrame(rows, columns=ANOVA_COLUMNS)
    anova["df"] = anova["df"].astype(int)
    stats_ = _fit_stats(res, y, k + 1, mse, ss_tot, anova, lof)
    return LinearFit(list(terms), pd.Series(res.params, index=names), pd.Series(res.bse, index=names), anova,
                     stats_, np.asarray(res.fittedvalues), np.asarray(res.resid), res)
