"""Residuals against uncertainty, and the score (Lagrange-multiplier) test of missing effects.

Residual r_c = measured_c - simulated_c per condition, with the combined standard uncertainty
u_c = sqrt(s_m^2/n_m,c + s_s^2/n_s,c); z_c = r_c / u_c; a condition fails when |z_c| > 2.
s_m^2 and s_s^2 are the pile-to-pile variances pooled over the conditions
(sum (n_c - 1) sd_c^2 / sum (n_c - 1)): with 2-3 heaps per condition a per-condition sd is
itself so uncertain that a chance small one makes a condition "fail" (measured: with 3 + 2
heaps per condition and no true misfit, 15 % of conditions fail at |z| > 2 with per-condition
sds, 6 % with pooled ones - tests/test_discrepancy.py). Pooling assumes the scatter does not
change much between conditions; ``pool=False`` uses each condition's own sd.

For a candidate effect with sensitivity g (d angle / d parameter per condition, from a step
away from neutral) and the model's own sensitivities J (one column per calibrated
parameter), the part of g the current parameters cannot absorb is
g_perp = g - J (J' W J)^-1 J' W g, W = diag(1/u^2). The score statistic
LM = (g_perp' W r)^2 / (g_perp' W g_perp) is chi-square with 1 df under "the effect is absent";
the explained fraction LM / (r' W r) is the share of the weighted misfit that adding the
effect (and re-fitting the current parameters, to first order) would remove.

The projection assumes the current parameters can move freely. When the calibration sits at
the edge of its range (say rolling friction at its upper bound and every residual positive),
they cannot absorb the misfit in that direction, and the free projection would explain away
exactly the evidence of a missing effect. With ``bounds`` (the feasible steps of the current
parameters and of each candidate) the statistic is the drop in weighted misfit of the
first-order refit, LR = min_beta |r - J beta|_W^2 - min_(beta, a) |r - J beta - g a|_W^2, with beta
and a inside their boxes (scipy's lsq_linear); without active bounds LR equals LM. A candidate
that can only move one way from neutral (cohesion: g >= 0) is on the boundary of its range
under the null, so LR follows the 50:50 mixture of chi2(0) and chi2(1) (Self & Liang 1987):
p = sf_chi2_1(LR) / 2. Active bounds on the current parameters make the null distribution a
more general chi-bar-square; chi2(1) is then an approximation.

The test takes the sensitivities as exact, but each is a difference of heap means and carries
the pile-to-pile scatter: se_c = sqrt(s^2/n_a + s^2/n_b) / step (s pooled over the conditions).
A signature no larger than that noise ranks noise (seen: wall friction ranked last, p 0.76,
with 2 heaps a step, first, p 3e-5, with 6). :func:`signature_noise` tests g = 0 with
X^2 = sum (g_c / se_c)^2 ~ chi2(n_conditions); a candidate whose signature is not resolved at
the significance level has an unreliable rank, whatever its p-value says.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats


def _pooled_var(sd, n) -> np.ndarray:
    """The variance pooled over the conditions with n > 1, for every condition (NaN if none)."""
    sd, n = np.asarray(sd, float), np.asarray(n, float)
    ok = (n > 1) & np.isfinite(sd)
    if not ok.any():
        return np.full(len(sd), np.nan)
    return np.full(len(sd), float(np.sum((n[ok] - 1) * sd[ok] ** 2) / np.sum(n[ok] - 1)))


def per_condition(rows: pd.DataFrame, ids) -> pd.DataFrame:
    """Mean, sd (ddof 1) and n of the simulated ``repose_angle`` per ``condition_id``, in the order of ``ids``
    (a condition without a heap gets NaN)."""
    g = rows.groupby(rows["condition_id"].astype(str))["repose_angle"]
    return pd.DataFrame({"mean": g.mean(), "sd": g.std(ddof=1), "n": g.count()}).reindex(
        pd.Index([str(i) for i in ids], name="condition_id"))


def difference_se(a: pd.DataFrame, b: pd.DataFrame, step: float) -> np.ndarray:
    """Standard error per condition of (mean_a - mean_b) / step, from two :func:`per_condition`
    frames, with the variance pooled over both and over the conditions (NaN where unknown)."""
    sd = np.concatenate([a["sd"].to_numpy(float), b["sd"].to_numpy(float)])
    n = np.concatenate([a["n"].to_numpy(float), b["n"].to_numpy(float)])
    v = _pooled_var(sd, n)[0] if len(sd) else np.nan
    na, nb = a["n"].to_numpy(float), b["n"].to_numpy(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.sqrt(v / na + v / nb) / abs(step)
    return np.where((na > 0) & (nb > 0), se, np.nan)


def signature_noise(g, se) -> tuple[float, float]:
    """(X^2, p) of the test that a sensitivity g with standard errors se is zero: X^2 = sum (g/se)^2,
    chi2 with one degree of freedom per condition with a finite se (p = NaN if none)."""
    g, se = np.asarray(g, float), np.asarray(se, float)
    ok = np.isfinite(g) & np.isfinite(se) & (se > 0)
    if not ok.any():
        return float("nan"), float("nan")
    x2 = float(np.sum((g[ok] / se[ok]) ** 2))
    return x2, float(stats.chi2.sf(x2, int(ok.sum())))


def residual_table(measured, measured_sd, measured_n, simulated, simulated_sd, simulated_n,
                   pool: bool = True) -> pd.DataFrame:
    m, s = np.asarray(measured, float), np.asarray(simulated, float)
    nm, ns = np.asarray(measured_n, float), np.asarray(simulated_n, float)
    vm = _pooled_var(measured_sd, nm) if pool else np.asarray(measured_sd, float) ** 2
    vs = _pooled_var(simulated_sd, ns) if pool else np.asarray(simulated_sd, float) ** 2
    if pool and not np.isfinite(vs).any():  # one heap a condition: the lab's pile scatter stands in for theirs
        vs = vm                             # (else the simulated mean counted as exact, u too small)
    um2 = np.where(nm > (0 if pool else 1), vm / np.maximum(nm, 1), np.nan)
    us2 = np.where(ns > (0 if pool else 1), vs / np.maximum(ns, 1), np.nan)
    u = np.sqrt(np.nan_to_num(um2, nan=0.0) + np.nan_to_num(us2, nan=0.0))
    u = np.where(u > 0, u, np.nan)
    r = m - s
    z = r / u
    return pd.DataFrame({"residual": r, "uncertainty": u, "z": z, "fails": np.abs(np.nan_to_num(z)) > 2.0,
                         "measured_share": np.nan_to_num(um2, nan=0.0) / u**2})


def summary(res: pd.DataFrame, n_params: int) -> dict:
    """RMSE, chi2/dof, conditions and failures of a residual table (:func:`residual_table`).

    chi2/dof = sum z_c^2 / nu, nu = C - min(C, p) * mean(w_c), w_c = u_m,c^2 / u_c^2 the measured mean's
    share of the residual's variance: the expected sum of z^2 at a point fitted to the C measured means by p
    parameters (linearised least squares, leverage min(C, p) shared evenly) and simulated afresh. Only the
    measured part of a residual is shrunk by the fit; the fresh heaps' scatter is not, so C - p (the right
    count only when the simulated means are exact) made a model that fits read 2-3 times too high with four
    heaps a condition."""
    r, z = res["residual"].to_numpy(float), res["z"].to_numpy(float)
    ok = np.isfinite(z)
    n = int(ok.sum())
    dof = n - min(n, n_params) * float(np.mean(res["measured_share"].to_numpy(float)[ok])) if n else 0.0
    fin = np.isfinite(r)  # a condition where no heap formed has no residual (the report names it)
    return {"rmse": float(np.sqrt(np.mean(r[fin] ** 2))) if fin.any() else float("nan"),
            "chi2_dof": float(np.sum(z[ok] ** 2) / dof) if dof > 1e-9 else float("nan"),
            "n_conditions": len(r), "n_fail": int(res["fails"].sum())}


def _box_misfit(r, w, A, lo, hi) -> tuple[float, np.ndarray]:
    """(min |r - A x|_W^2 over lo <= x <= hi, the minimiser)."""
    if A.shape[1] == 0:
        return float(np.sum(w * r * r)), np.zeros(0)
    from scipy.optimize import lsq_linear

    sw = np.sqrt(w)
    x = lsq_linear(sw[:, None] * A, sw * r, bounds=(lo, hi), method="bvls").x
    e = r - A @ x
    return float(np.sum(w * e * e)), x


def score_effects(r, u, J, G: dict[str, np.ndarray], bounds=None,
                  cand_bounds: dict[str, tuple[float, float]] | None = None) -> pd.DataFrame:
    """Rank candidate effects (columns of G) by the score test against residuals r.

    ``bounds``: (lo, hi) arrays of the steps each current parameter (column of J) can still take
    within its range; ``cand_bounds[name]``: the (lo, hi) step range of a candidate's parameter
    from its start. Given either, the bounded statistic of the module docstring is used.
    """
    r, u = np.asarray(r, float), np.asarray(u, float)
    w = 1.0 / np.where(np.isfinite(u) & (u > 0), u, np.nanmedian(u)) ** 2
    J = np.atleast_2d(np.asarray(J, float)).reshape(len(r), -1) if np.size(J) else np.zeros((len(r), 0))
    if bounds is not None or cand_bounds is not None:
        return _bounded_scores(r, w, J, G, bounds, cand_bounds or {})
    total = float(np.sum(w * r * r))
    rows = []
    for name, g in G.items():
        g = np.asarray(g, float)
        if J.shape[1]:
            A = J.T @ (w[:, None] * J)
            gp = g - J @ np.linalg.lstsq(A, J.T @ (w * g), rcond=None)[0]
        else:
            gp = g
        den = float(np.sum(w * gp * gp))
        lm = float(np.sum(w * gp * r) ** 2 / den) if den > 1e-12 * max(float(np.sum(w * g * g)), 1e-300) else 0.0
        rows.append({"effect": name, "score": lm, "p_value": float(stats.chi2.sf(lm, 1)),
                     "explained_fraction": lm / total if total > 0 else 0.0,
                     "direction": float(np.sign(np.sum(w * gp * r)))})
    return pd.DataFrame(rows).sort_values("score", ascending=False).reset_index(drop=True)


def _bounded_scores(r, w, J, G, bounds, cand_bounds) -> pd.DataFrame:
    k = J.shape[1]
    lo, hi = (np.full(k, -np.inf), np.full(k, np.inf)) if bounds is None else (
        np.asarray(bounds[0], float), np.asarray(bounds[1], float))
    total = float(np.sum(w * r * r))
    chi0, _ = _box_misfit(r, w, J, lo, hi)
    rows = []
    for name, g in G.items():
        g = np.asarray(g, float)
        a_lo, a_hi = cand_bounds.get(name, (-np.inf, np.inf))
        chi1, x = _box_misfit(r, w, np.column_stack([J, g]), np.append(lo, a_lo), np.append(hi, a_hi))
        lr = max(chi0 - chi1, 0.0)
        p = float(stats.chi2.sf(lr, 1))
        if a_lo == 0.0 or a_hi == 0.0:  # one-sided: the null sits on the boundary (chi-bar mixture)
            p *= 0.5
        rows.append({"effect": name, "score": lr, "p_value": p,
                     "explained_fraction": lr / total if total > 0 else 0.0,
                     "direction": float(np.sign(x[-1]))})
    # by p-value: a one-sided candidate's is halved, so its score alone would rank it below a two-sided one
    # that the data support less (ties, as p = 0 in double precision, by score)
    return (pd.DataFrame(rows).sort_values(["p_value", "score"], ascending=[True, False], kind="stable")
            .reset_index(drop=True))


def at_bounds(theta: dict, ranges: dict[str, tuple[float, float]], tol: float = 0.02) -> dict[str, str]:
    """Parameters within ``tol`` of their range's edge: {name: "low" | "high"}."""
    out = {}
    for k, (a, b) in ranges.items():
        if k in theta and b > a:
            x = (theta[k] - a) / (b - a)
            if x <= tol:
                out[k] = "low"
            elif x >= 1 - tol:
                out[k] = "high"
    return out


def project_out(u, J, g):
    """g less what the columns of J absorb under weights w = 1/u^2, g - J (J' W J)^-1 J' W g, and w."""
    w = 1.0 / np.asarray(u, float) ** 2
    if J.shape[1] == 0:
        return g, w
    return g - J @ np.linalg.lstsq(J.T @ (w[:, None] * J), J.T @ (w * g), rcond=None)[0], w


def confounded(u, J, G: dict[str, np.ndarray], threshold: float = 0.9) -> list[tuple[str, str]]:
    """Pairs of candidates whose projected signatures are collinear (|weighted corr| > threshold):
    the data cannot tell them apart, whatever their scores."""
    J = np.atleast_2d(np.asarray(J, float)).reshape(len(u), -1) if np.size(J) else np.zeros((len(u), 0))
    proj = {k: project_out(u, J, np.asarray(g, float)) for k, g in G.items()}
    names, out = list(proj), []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            (ga, w), (gb, _) = proj[a], proj[b]
            if _alike(w, ga, gb) > threshold:
                out.append((a, b))
    return out


def _alike(w, a, b) -> float:
    """|weighted correlation| of a and b about zero, |a' W b| / sqrt(a' W a b' W b) (0 if either is 0)."""
    den = math.sqrt(float(np.sum(w * a * a)) * float(np.sum(w * b * b)))
    return abs(float(np.sum(w * a * b))) / den if den > 0 else 0.0


def confound(J: np.ndarray, g: np.ndarray, u: np.ndarray, names) -> tuple[str, float]:
    """The parameter whose sensitivity is most collinear with g (weighted), and |corr|."""
    w = 1.0 / np.asarray(u, float) ** 2
    best, top = "", 0.0
    for k, name in enumerate(names):
        c = _alike(w, np.asarray(J, float)[:, k], np.asarray(g, float))
        if c > top:
            best, top = name, c
    return best, top


def trends(res: pd.DataFrame, variables: pd.DataFrame) -> pd.DataFrame:
    """Slope of the residual against each condition variable (OLS), with its p-value."""
    rows = []
    r = res["residual"].to_numpy(float)
    for c in variables.columns:
        x = pd.to_numeric(variables[c], errors="coerce").to_numpy(float)
        if np.isfinite(x).sum() < 3 or np.ptp(x[np.isfinite(x)]) == 0:
            continue
        lr = stats.linregress(x, r)
        rows.append({"variable": c, "slope": float(lr.slope), "p_value": float(lr.pvalue), "r": float(lr.rvalue)})
    return pd.DataFrame(rows, columns=["variable", "slope", "p_value", "r"])
