"""Which conditions to measure next: rank the conditions a rig can make by what one more measured
condition is expected to teach, about the parameters and about the missing effects.

About the parameters (expected shrinkage), a preposterior over the posterior's draws theta_s: a
condition c measured with n piles of scatter s gives a mean y ~ N(mu(theta, c), u_c^2), u_c^2 = s^2 / n,
mu the surrogate's mean. Its own variance is not counted as the measurement's: it shrinks by
simulating, not by measuring (where it is large the reason says to simulate there first). For outcomes y_k drawn as a draw's prediction plus
that noise, the draws reweighted by N(y_k; mu(theta_s, c), u_c^2) are the posterior after measuring
c; each parameter's interval is expected to shrink by 1 - E_k[width_k] / width, and the
information gain is 1/2 log(1 + Var_s mu(theta_s, c) / u_c^2) nats (exact for a Gaussian
predictive). Unlike a linearisation at the posterior mean it sees a posterior with two modes: a
condition where they predict different angles tells them apart.

About a missing effect e (expected separation). Its signature g_e over the measured conditions is
what the current parameters cannot absorb once projected off their sensitivities J (the score test
of ``calib diagnose``); at a step D of its parameter the test's expected statistic is

    lambda = D^2 g_perp^T W g_perp,    g_perp = g - J (J^T W J)^-1 J^T W g,   W = diag(1/u^2),

and adding c raises it by d lambda: how much more clearly the effect stands apart from what the
parameters absorb. A confound is a pair (effect, parameter) whose signatures are collinear on the
measured conditions (|weighted correlation| near 1); the condition that lowers it most breaks it.

Sensitivities at an unmeasured condition are simulated there when asked (diagnose's own finite
differences at c, ``suggest-conditions --simulate``); else they come from the measured ones (a linear
fit in the condition variables that vary among them): interpolated within their range, extrapolated
beyond it (shown, not ranked), and unknown along a variable the measurements never varied.
"""

from __future__ import annotations

import itertools
import math
import shlex
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..discrepancy.stats import confound, project_out
from ..errors import CalibError
from ..parameters import check

#: the rig's variables a rig file may list, with the heap-test variable each sets
RIG_VARIABLES = ("cylinder_diameter_mm", "fill_height_mm", "lift_speed_mm_s")


@dataclass(frozen=True)
class Rig:
    """What a rig can make: values per variable, grain size fractions (d_min, d_max) and piles a condition."""

    values: dict[str, tuple[float, ...]]
    sizes: tuple[tuple[float, float], ...]
    piles: int = 10

    def conditions(self) -> pd.DataFrame:
        """Every combination, one row each, with a condition_id in the lab's naming (d4-5_D40_H100)."""
        names = list(self.values)
        rows = []
        for (dmin, dmax), combo in itertools.product(self.sizes, itertools.product(*self.values.values())):
            row = {"particle_d_min_mm": dmin, "particle_d_max_mm": dmax, **dict(zip(names, combo))}
            rows.append(row)
        df = pd.DataFrame(rows)
        single = {k for k, v in self.values.items() if len(v) == 1 and k == "lift_speed_mm_s"}
        df.insert(0, "condition_id", [_cid(r, single) for r in rows])
        twice = df["condition_id"][df["condition_id"].duplicated()]
        if len(twice):  # the names are the photographs' file names: two conditions cannot share one
            raise CalibError(f"the rig's conditions {twice.iloc[0]} are two that its name rounds alike: give values "
                             "that differ in their first six digits")
        return df


def _cid(r: dict, single: set[str]) -> str:
    """The lab's naming (d4-5_D40_H100); a variable the rig holds at one value is left out."""
    out = f"d{r['particle_d_min_mm']:g}-{r['particle_d_max_mm']:g}"
    for k, tag in (("cylinder_diameter_mm", "D"), ("fill_height_mm", "H"), ("lift_speed_mm_s", "V")):
        if k in r and k not in single:
            out += f"_{tag}{r[k]:g}"
    return out


def parse_rig(d: dict, where: str = "rig file") -> Rig:
    """A rig from its TOML table (docs/cli.md): ``particle_sizes_mm = [[4, 5], [5, 6]]``, lists of
    ``cylinder_diameter_mm``, ``fill_height_mm``, ``lift_speed_mm_s``, and ``piles``."""
    rig = d.get("rig", d)
    if "rig" in d and set(d) - {"rig"}:  # beside [rig], a key or table no rig reads would be dropped in silence
        raise CalibError(f"{where}: {', '.join(sorted(set(d) - {'rig'}))} outside the [rig] table: put every key "
                         "under [rig]")
    if not isinstance(rig, dict):
        raise CalibError(f"{where}: 'rig' must be a table ([rig] with particle_sizes_mm, ...), got {rig!r}")
    unknown = sorted(set(rig) - {*RIG_VARIABLES, "particle_sizes_mm", "piles"})
    if unknown:
        raise CalibError(f"{where}: unknown key(s) {', '.join(unknown)}; a rig lists particle_sizes_mm, "
                         f"{', '.join(RIG_VARIABLES)} and piles")
    sizes = _rig_sizes(rig.get("particle_sizes_mm", []), where)
    values = {}
    for k in (k for k in RIG_VARIABLES if k in rig):
        vs = rig[k] if isinstance(rig[k], list) else [rig[k]]
        if not vs:
            raise CalibError(f"{where}: {k} needs at least one value")
        values[k] = tuple(check(k, v, f"{where}, {k}") for v in vs)
        if len(set(values[k])) < len(values[k]):
            raise CalibError(f"{where}: {k} lists a value twice ({', '.join(f'{v:g}' for v in values[k])})")
    piles = rig.get("piles", 10)
    if isinstance(piles, bool) or not isinstance(piles, int) or not 1 <= piles <= 10_000:  # as --piles
        raise CalibError(f"{where}: piles must be a whole number from 1 to 10000, got {piles!r}")
    return Rig(values, sizes, piles)


def _rig_sizes(pairs, where: str) -> tuple[tuple[float, float], ...]:
    """particle_sizes_mm as (d_min, d_max) pairs, each size checked as a condition's (:func:`check`)."""
    if not isinstance(pairs, list) or not pairs or any(not isinstance(p, list) or len(p) != 2 for p in pairs):
        raise CalibError(f"{where}: particle_sizes_mm must list at least one pair [d_min, d_max], got {pairs!r}")
    sizes = tuple((check("particle_d_min_mm", a, f"{where}, particle_sizes_mm"),
                   check("particle_d_max_mm", b, f"{where}, particle_sizes_mm")) for a, b in pairs)
    if len(set(sizes)) < len(sizes):
        raise CalibError(f"{where}: particle_sizes_mm lists a pair twice")
    if any(a > b for a, b in sizes):
        raise CalibError(f"{where}: particle_sizes_mm must list pairs [d_min, d_max] with d_min <= d_max")
    return sizes


# ------------------------------------------------------------------ sensitivities at new conditions
def varying(conds: pd.DataFrame, variables) -> list[str]:
    """The condition variables that take more than one value among ``conds``."""
    return [v for v in variables if v in conds and conds[v].nunique() > 1]


def extrapolate(measured: pd.DataFrame, sens: pd.DataFrame, candidates: pd.DataFrame, variables) -> tuple[
        pd.DataFrame, np.ndarray, np.ndarray]:
    """Each sensitivity column at each candidate, from a linear fit in the variables that vary among
    the measured conditions (least squares; their mean where none varies). Returns the values,
    ``known`` (False where the candidate sets a variable the measurements never varied: nothing says
    how the sensitivities move along it until it is simulated) and ``extrapolated`` (outside the
    measured range of a variable they did vary)."""
    vary = varying(measured, variables)
    X = np.column_stack([np.ones(len(measured))] + [measured[v].to_numpy(float) for v in vary])
    coef, *_ = np.linalg.lstsq(X, sens.to_numpy(float), rcond=None)
    Xc = np.column_stack([np.ones(len(candidates))] + [candidates[v].to_numpy(float) for v in vary])
    known = np.ones(len(candidates), bool)
    extrapolated = np.zeros(len(candidates), bool)
    for v in (v for v in variables if v in candidates and v in measured):
        x, lo, hi = candidates[v].to_numpy(float), measured[v].min(), measured[v].max()
        outside = (x < lo - 1e-9) | (x > hi + 1e-9)
        if v in vary:
            extrapolated |= outside
        else:
            known &= ~outside
    return pd.DataFrame(Xc @ coef, columns=sens.columns, index=candidates.index), known, extrapolated


# ------------------------------------------------------------------ expected gains
def parameter_gain(mu: np.ndarray, draws: np.ndarray, u2, outcomes: int = 64,
                   seed: int = 0) -> tuple[float, np.ndarray]:
    """One candidate's expected information gain (nats) and each parameter's expected interval
    shrinkage (module docstring): ``mu`` the surrogate's angle at each posterior draw (S,), or its m
    responses (S, m: the angle and the profile's fullness), ``draws`` the draws (S, k), ``u2`` the
    variance of the new condition's measured mean, or the (m, m) covariance of its measured means.
    The gain is 1/2 log det(I + U^-1 Cov_s mu) (one response: 1/2 log(1 + Var_s mu / u2))."""
    mu, draws = np.asarray(mu, float), np.asarray(draws, float)
    M = mu.reshape(len(mu), -1)
    U = np.asarray(u2, float) if np.ndim(u2) == 2 else np.diag(np.atleast_1d(np.asarray(u2, float)))
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(U)) and np.all(np.diag(U) > 0)):
        return np.nan, np.full(draws.shape[1], np.nan)
    L = np.linalg.cholesky(U)
    rng = np.random.default_rng(seed)
    width0 = _widths(draws, np.full(len(M), 1.0 / len(M)))
    widths = []
    for s in rng.integers(0, len(M), outcomes):
        y = M[s] + L @ rng.normal(0.0, 1.0, M.shape[1])
        z = np.linalg.solve(L, (y - M).T)
        logw = -0.5 * np.sum(z * z, axis=0)
        w = np.exp(logw - logw.max())
        widths.append(_widths(draws, w / w.sum()))
    shrink = 1.0 - np.mean(widths, axis=0) / np.where(width0 > 0, width0, np.nan)
    return information_gain(M, U), np.clip(shrink, 0.0, 1.0)


def information_gain(M: np.ndarray, U: np.ndarray) -> float:
    """1/2 log det(I + U^-1 Cov_s M) nats: what measuring responses of covariance U (m, m) teaches about
    draws whose predicted responses are M (S, m) (exact for a Gaussian predictive)."""
    Li = np.linalg.inv(np.linalg.cholesky(U))
    C = Li @ np.atleast_2d(np.cov(M.T, bias=True)) @ Li.T
    return 0.5 * float(np.linalg.slogdet(np.eye(len(C)) + C)[1])


def gain_spread(mu: np.ndarray, F: np.ndarray, U: np.ndarray, ranked: np.ndarray) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How far the surrogate's own uncertainty leaves each candidate's information gain: its 5th and 95th
    percentiles, and the probability that its gain is the largest among the ``ranked`` candidates (NaN
    elsewhere), and what measuring it may lose against the best of them (the 90th percentile of the best
    gain less its own, nats). ``mu``: the surrogate's mean responses at the posterior's draws (n, S) or (n, S, m);
    ``F``: K joint realisations of the latent responses at a subset of those draws (K, n, s[, m]) where
    the realisations were drawn (NaN elsewhere). A realisation's responses vary more over the draws than
    the function they stand for (its roughness is the process's prior's), so its own gain runs high; its
    deviation from the realisations' mean is carried onto the mean's: Cov_k = Cov_S(mu) + Cov_s(F_k) -
    mean_k Cov_s(F_k) (S all the draws, s the subset), clipped to its non-negative part, gain_k = 1/2 log
    det(I + U^-1 Cov_k). On two stand-in labs (``benchmarks/gain_spread.py``) the 90 % range held the true
    gain in 91-100 % of the cases, and the realisations' own gains ran 0.03-0.41 nats above it."""
    mu = np.asarray(mu, float).reshape(*np.shape(mu)[:2], -1)
    F = np.asarray(F, float).reshape(*np.shape(F)[:3], -1)
    if F.shape[1] != mu.shape[0] or F.shape[3] != mu.shape[2]:
        raise CalibError(f"gain_spread: realisations of shape {F.shape} do not match the means' {mu.shape} "
                         "(candidates and responses)")
    K, n = F.shape[0], mu.shape[0]
    Li = np.linalg.inv(np.linalg.cholesky(np.asarray(U, float)))
    G = np.full((K, n), np.nan)
    for j in range(n):
        if not (np.all(np.isfinite(mu[j])) and np.all(np.isfinite(F[:, j]))):
            continue
        covs = np.array([np.atleast_2d(np.cov(F[k, j].T, bias=True)) for k in range(K)])
        shifted = np.atleast_2d(np.cov(mu[j].T, bias=True)) - covs.mean(axis=0)
        for k in range(K):
            w = np.linalg.eigvalsh(Li @ (shifted + covs[k]) @ Li.T)
            G[k, j] = 0.5 * float(np.sum(np.log1p(np.clip(w, 0.0, None))))
    q05, q95 = (np.full(n, np.nan), np.full(n, np.nan))
    ok = np.isfinite(G).all(axis=0)
    q05[ok], q95[ok] = np.quantile(G[:, ok], [0.05, 0.95], axis=0)
    p_best, regret = np.full(n, np.nan), np.full(n, np.nan)
    live = np.asarray(ranked, bool) & ok
    if live.any():
        best = np.flatnonzero(live)[np.argmax(G[:, live], axis=1)]
        p_best[live] = np.bincount(best, minlength=n)[live] / K
        regret[live] = np.quantile(G[:, live].max(axis=1, keepdims=True) - G[:, live], 0.9, axis=0)
    return q05, q95, p_best, regret


def _widths(draws: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Each column's weighted 90 % interval width (5th to 95th weighted percentile)."""
    out = []
    for col in draws.T:
        order = np.argsort(col)
        cdf = np.cumsum(w[order])
        lo, hi = np.searchsorted(cdf, [0.05, 0.95])
        out.append(col[order][min(hi, len(col) - 1)] - col[order][min(lo, len(col) - 1)])
    return np.array(out)


def separation(J: np.ndarray, g: np.ndarray, u: np.ndarray, step: float) -> float:
    """The score test's expected statistic for an effect of signature g at a step of its parameter:
    lambda = step^2 g_perp^T W g_perp (module docstring)."""
    gp, w = project_out(u, np.asarray(J, float).reshape(len(g), -1), np.asarray(g, float))
    return float(step**2 * np.sum(w * gp * gp))


# ------------------------------------------------------------------ the ranking
@dataclass
class Evidence:
    """What the ranking reads: the measured conditions with the sensitivities diagnose simulated there
    (``J``: per calibrated parameter, ``G``: per candidate effect), the uncertainty of each measured
    mean, the pile scatter a new condition is measured with, and the posterior's draws."""

    measured: pd.DataFrame
    J: pd.DataFrame  # diagnose's, per measured condition; columns: the model's parameters
    G: pd.DataFrame  # diagnose's; columns: the candidate effects
    u: np.ndarray  # the uncertainty of each measured mean (deg)
    scatter: float  # pile-to-pile sd (deg)
    params: list[str]  # the posterior's parameters, the columns of draws
    draws: np.ndarray  # posterior draws (S, k)
    steps: dict[str, float]  # each effect's probe step (Effect.step)
    #: the variance of the simulated mean a residual is also uncertain by (compare's share of u^2):
    #: the score test's weights count it, so a new condition's separation must too
    sim_var: float = 0.0
    #: with the profile as a second response: a photograph's fullness sd, and its correlation with the
    #: angle within a condition
    profile_scatter: float = float("nan")
    profile_rho: float = 0.0

    def mean_cov(self, piles: int) -> np.ndarray:
        """The covariance of a new condition's measured mean angle (and mean fullness) over ``piles``."""
        if not np.isfinite(self.profile_scatter):
            return np.array([[self.scatter ** 2]]) / piles
        c = self.profile_rho * self.scatter * self.profile_scatter
        return np.array([[self.scatter ** 2, c], [c, self.profile_scatter ** 2]]) / piles

    def draws_frame(self) -> pd.DataFrame:
        return pd.DataFrame(self.draws, columns=self.params)


def rank_conditions(ev: Evidence, candidates: pd.DataFrame, mu: np.ndarray, vp: np.ndarray, piles: int,
                    variables, simulated: pd.DataFrame | None = None, F: np.ndarray | None = None) -> pd.DataFrame:
    """One row per candidate (not yet measured): the expected information gain about the parameters
    (nats) and each one's interval shrinkage, from the surrogate's angle at every posterior draw
    ``mu`` (candidates, draws; or (candidates, draws, 2) with the profile's fullness as well, measured
    with ``ev.mean_cov``, and then ``info_gain_angle_nats``, the angle's alone) and its own variance
    ``vp`` at the candidates; each candidate effect's
    separation gain, from diagnose's sensitivities simulated at the candidate (``simulated``: rows as
    ``candidates``, diagnose's columns d_<parameter> and candidate_<effect>, and se_candidate_<effect>
    the signature's standard error, whose expected share D^2 se^2 / u^2 is taken off; NaN where not
    simulated) or else carried from the measured conditions (:func:`extrapolate`; NaN where they
    cannot be), each weighed with the new residual's variance as diagnose will weigh it (the measured
    mean's plus ``ev.sim_var``). The sensitivities used are columns too (``d_*``, ``candidate_*``). Sorted by the sum of the two ranks
    (information, best separation); a separation extrapolated beyond the measured range is shown but
    not ranked (a straight line through a few noisy sensitivities is a guess out there), and so is an
    information gain where ``candidates``' column ``beyond_heaps`` is set (beyond the simulated heaps'
    range the gain is the surrogate's own extrapolation). With ``F``, the surrogate's realisations
    (:func:`gain_spread`), each gain's 90 % range over them (``info_gain_q05``, ``info_gain_q95``) and its
    chance of being the largest ranked one (``p_best_gain``)."""
    u2 = np.full(len(candidates), ev.scatter**2 / piles)
    U = ev.mean_cov(piles)
    pairs = [parameter_gain(m, ev.draws, U) for m in mu]
    gains = np.array([g for g, _ in pairs])
    shrink = np.array([s for _, s in pairs]).reshape(len(candidates), len(ev.params))
    out = candidates.assign(info_gain_nats=gains, surrogate_sd=np.sqrt(np.asarray(vp, float)))
    if np.ndim(mu) == 3:  # the profile too: what the angle alone would teach, beside it
        out["info_gain_angle_nats"] = [information_gain(m[:, :1], U[:1, :1]) if np.all(np.isfinite(m)) else np.nan
                                       for m in mu]
    if F is not None:
        out["info_gain_q05"], out["info_gain_q95"], out["p_best_gain"], out["gain_regret_q90"] = gain_spread(
            mu, F, U, ~_beyond(out) & np.isfinite(gains))
    for k, p in enumerate(ev.params):
        out[f"shrink_{p}"] = shrink[:, k]
    Jc, known, extrapolated = extrapolate(ev.measured, ev.J, candidates, variables)
    Gc, _, _ = extrapolate(ev.measured, ev.G, candidates, variables)
    sim = np.zeros(len(candidates), bool)
    if simulated is not None and len(ev.J.columns):
        cols = [f"d_{p}" for p in ev.J.columns] + [f"candidate_{e}" for e in ev.G.columns]
        sim = simulated.reindex(columns=cols).notna().all(axis=1).to_numpy()
        Jc.loc[sim, :] = simulated.loc[sim, cols[:len(ev.J.columns)]].to_numpy()
        Gc.loc[sim, :] = simulated.loc[sim, cols[len(ev.J.columns):]].to_numpy()
    known, extrapolated = known | sim, extrapolated & ~sim
    out = out.assign(known=known, extrapolated=extrapolated, simulated=sim)
    for p in ev.J.columns:
        out[f"d_{p}"] = np.where(known, Jc[p].to_numpy(float), np.nan)
    for e in ev.G.columns:
        out[f"candidate_{e}"] = np.where(known, Gc[e].to_numpy(float), np.nan)
    J0, u0 = ev.J.to_numpy(float), np.asarray(ev.u, float)
    for e in ev.G.columns:
        g0 = ev.G[e].to_numpy(float)
        base = separation(J0, g0, u0, ev.steps[e])
        # a simulated signature's own scatter adds se^2 to its square on average: taken off, so that a
        # noisy finite difference does not pass for a separation (all of it: the projection keeps less)
        se = simulated[f"se_candidate_{e}"].to_numpy(float) if simulated is not None and \
            f"se_candidate_{e}" in simulated else np.zeros(len(candidates))
        w2 = u2 + ev.sim_var  # the new residual's variance, as diagnose's test will weigh it
        noise = np.where(sim, ev.steps[e] ** 2 * np.nan_to_num(se) ** 2 / w2, 0.0)
        out[f"separation_{e}"] = [
            max(separation(np.vstack([J0, Jc.iloc[i].to_numpy(float)]), np.append(g0, Gc[e].iloc[i]),
                           np.append(u0, math.sqrt(w2[i])), ev.steps[e]) - base - noise[i], 0.0) if known[i]
            else np.nan for i in range(len(candidates))]
    seps = out[[f"separation_{e}" for e in ev.G.columns]]
    top = seps.fillna(-np.inf).to_numpy().argmax(axis=1) if len(seps.columns) else np.zeros(len(out), int)
    out["best_separation"] = seps.max(axis=1) if len(seps.columns) else np.nan
    out["best_effect"] = [list(ev.G.columns)[k] if np.isfinite(b) else ""
                          for k, b in zip(top, out["best_separation"])]
    ranked_gain, ranked_sep = _ranked(out)
    order = ranked_gain.rank(ascending=False, na_option="bottom") + ranked_sep.rank(ascending=False,
                                                                                   na_option="bottom")
    return out.assign(_order=order).sort_values("_order", kind="stable").drop(columns="_order").reset_index(drop=True)


def _beyond(table: pd.DataFrame) -> np.ndarray:
    """Per candidate, whether it sets a condition variable beyond the simulated heaps' range (its gain the
    surrogate's extrapolation); False throughout in a ranking written before the column existed."""
    return table["beyond_heaps"].fillna("").astype(bool).to_numpy() if "beyond_heaps" in table \
        else np.zeros(len(table), bool)


def _ranked(table: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """The information gains and separations that rank a candidate: NaN where the surrogate extrapolates
    (a gain beyond the heaps, a separation from extrapolated sensitivities) or cannot tell."""
    return table["info_gain_nats"].where(~_beyond(table)), table["best_separation"].where(~table["extrapolated"])


def any_ranked(table: pd.DataFrame) -> bool:
    """Whether any candidate's gain or separation is ranked; if none is, the table keeps the rig's order."""
    return any(s.notna().any() for s in _ranked(table))


#: heaps ``suggest-conditions --heaps`` is advised to spread over the posterior at a candidate: on the hidden-cohesion
#: lab 12 took the surrogate's sd at the best two to 1.4-1.6 and 1.3 deg (a measured mean's 1.3), on the control to
#: 0.48 and 0.44 (0.5); docs/method.md
REGION_HEAPS = 12


def to_simulate(table: pd.DataFrame, n: int = 2) -> list[str]:
    """The ``n`` candidates whose information gain is largest among those not ranked because it lies beyond
    the simulated heaps' range: where heaps (``suggest-conditions --simulate ID --heaps N``) would first
    turn a guess into a ranking."""
    guess = table[_beyond(table) & np.isfinite(table["info_gain_nats"].astype(float))]
    return guess.sort_values("info_gain_nats", ascending=False, kind="stable")["condition_id"].astype(str).head(n).tolist()


#: what measuring the largest ranked gain may lose against the best (nats, 90 %) above which the ranking says
#: the best is not settled: a tenth of a nat is a parameter's interval about 10 % less narrowed
SETTLED_NATS = 0.1


def unsettled(table: pd.DataFrame, at_least: float = 0.05) -> tuple[str, list[tuple[str, float, float]]] | None:
    """Where the surrogate's uncertainty leaves the best condition open: the candidate with the largest
    ranked gain where what measuring it may lose against the best (``gain_regret_q90``) is above SETTLED_NATS,
    and (condition_id, chance of the largest gain, loss) of the leader and of each other candidate with at least
    ``at_least`` of that chance whose own loss is at most SETTLED_NATS more than the leader's, likeliest first
    (one that may be best but may also lose much more is not a safe choice); None where it is settled or no
    spread was computed."""
    if not {"gain_regret_q90", "p_best_gain"} <= set(table.columns) or not table["gain_regret_q90"].notna().any():
        return None
    ranked = table[table["gain_regret_q90"].notna()]
    lead = ranked.loc[ranked["info_gain_nats"].astype(float).idxmax()]
    if not lead["gain_regret_q90"] > SETTLED_NATS:
        return None
    close = (ranked["condition_id"] == lead["condition_id"]) | (
        (ranked["p_best_gain"] >= at_least) & (ranked["gain_regret_q90"] <= lead["gain_regret_q90"] + SETTLED_NATS))
    t = ranked[close].sort_values("p_best_gain", ascending=False, kind="stable")
    return str(lead["condition_id"]), list(zip(t["condition_id"].astype(str), t["p_best_gain"].astype(float),
                                                t["gain_regret_q90"].astype(float)))


def unsettled_words(table: pd.DataFrame) -> str:
    """The sentence that says which candidates are in contention for the largest gain (:func:`unsettled`), or
    "" where the surrogate settles it. More heaps there narrow it slowly (docs/method.md): what helps is
    knowing which will do about as well."""
    open_ = unsettled(table)
    if not open_:
        return ""
    lead, close = open_
    p_lead, lose = next((p, r) for cid, p, r in close if cid == lead)
    head = (f"the surrogate's own uncertainty leaves open which condition teaches the most: {lead} has the largest "
            f"gain (chance {p_lead:.2f} of being the best) but may teach up to {lose:.2f} nats less than the best "
            "(90th percentile)")
    others = [f"{cid} (chance {p:.2f})" for cid, p, _ in close if cid != lead]
    if not others:
        return head
    listed = others[:3] + ([f"{len(others) - 3} more"] if len(others) > 3 else [])
    names = listed[0] if len(listed) == 1 else ", ".join(listed[:-1]) + " and " + listed[-1]
    return (f"{head}; {names} may be the best too, and each of these {len(close)} may lose up to "
            f"{max(r for *_, r in close):.2f} nats (90th percentile): choose among them by what the rig makes "
            "most easily")


def simulate_command(command: str, table: pd.DataFrame, fallback: str) -> str:
    """The command that would rank ``table``'s best unranked candidates (:func:`to_simulate`), or "" where
    there are none: ``command`` (the ranking's own, ``calib suggest-conditions ...``; else ``fallback``) with
    the candidates it simulated already and these in one ``--simulate`` (those are cached), and ``--heaps``
    (REGION_HEAPS more than the most any of these has, ``region_heaps``; one named before keeps its own, the
    design being nested)."""
    ids = to_simulate(table)
    if not ids:
        return ""
    args = shlex.split(command) if command else []
    if args[:2] != ["calib", "suggest-conditions"]:
        args = shlex.split(fallback)
    kept, named, skip = [], [], False
    for a, nxt in zip(args, [*args[1:], ""]):
        if skip:
            skip = False
        elif a in ("--simulate", "--heaps"):
            named += nxt.split(",") if a == "--simulate" else []
            skip = True
        elif a.startswith(("--simulate=", "--heaps=")):
            named += a.partition("=")[2].split(",") if a.startswith("--simulate=") else []
        elif a != "--force":  # the heaps are new inputs: the ranking reruns without it
            kept.append(a)
    every = list(dict.fromkeys([n.strip() for n in named if n.strip()] + ids))
    return shlex.join([*kept, "--simulate", ",".join(every), "--heaps", str(heaps_for(table, ids))])


def heaps_for(table: pd.DataFrame, ids) -> int:
    """The ``--heaps`` that adds REGION_HEAPS at each of ``ids``: more than the most any has of the current
    posterior's design (``region_heaps``)."""
    had = table.loc[table["condition_id"].astype(str).isin(list(ids)), "region_heaps"] if "region_heaps" in table \
        else pd.Series(dtype=float)
    return REGION_HEAPS + int(np.nan_to_num(had.max())) if len(had) else REGION_HEAPS


#: the expected rise of the score test's statistic below which a condition does not separate an effect
#: (one unit of chi-square: the test's own scale)
SEPARATES = 1.0


def unsettling(sep: float) -> str:
    """What follows an effect's best condition where even that one would not separate it (below SEPARATES)."""
    return "" if sep >= SEPARATES else ": below one unit, so no condition the rig offers is expected to settle it"


def best_per_effect(table: pd.DataFrame) -> list[tuple[str, str, float, str]]:
    """For each candidate effect of a ranking, (effect, condition_id, separation, "simulated" or
    "interpolated"): the condition that would best tell it from what the parameters absorb, among those
    whose sensitivities are not extrapolated, whether or not it ranks in the top."""
    out = []
    for col in (c for c in table.columns if c.startswith("separation_")):
        sep = table[col].where(~table["extrapolated"]) if "extrapolated" in table else table[col]
        if sep.notna().any():
            best = table.loc[sep.idxmax()]
            out.append((col.removeprefix("separation_"), str(best["condition_id"]), float(sep.max()),
                        "simulated" if best.get("simulated", False) else "interpolated"))
    return out


def explain(ev: Evidence, row: pd.Series, effect: str, variables, words: dict[str, str] | None = None) -> str:
    """A plain-language reason for a candidate: the variable it moves furthest from the measured
    conditions, the parameter the effect is most confounded with there, and how each one's
    sensitivity at the candidate (``row``'s d_<parameter>, candidate_<effect>) compares with its mean
    over the measured conditions: what breaks the confound is that the two do not scale alike."""
    vary = varying(ev.measured, variables)
    if not vary:
        return "the measured conditions vary no variable: any new condition adds a first contrast"
    span = {v: (row[v] - ev.measured[v].mean()) / (ev.measured[v].max() - ev.measured[v].min()) for v in vary}
    var = max(span, key=lambda k: abs(span[k]))
    param, corr = confound(ev.J.to_numpy(float), ev.G[effect].to_numpy(float), ev.u, list(ev.J.columns))
    name = (words or {}).get(var, var.replace("_", " "))
    head = (f"a {name} of {row[var]:g} separates {effect.replace('_', ' ')} from "
            f"{param.replace('_', ' ') if param else 'the parameters'}")
    if not param:
        return head
    ratios = [_ratio(row.get(f"candidate_{effect}"), ev.G[effect]), _ratio(row.get(f"d_{param}"), ev.J[param])]
    how = ("simulated there" if row.get("simulated") else
           "extrapolated from the measured conditions" if row.get("extrapolated") else
           "interpolated between the measured conditions")
    return (f"{head} (signatures {corr:.0%} alike on the measured conditions): there the effect's sensitivity is "
            f"{ratios[0]} its mean on the measured conditions, {param.replace('_', ' ')}'s {ratios[1]} ({how})")


def _ratio(value, measured: pd.Series) -> str:
    """``value`` as a multiple of the measured conditions' mean sensitivity ("1.8x"), or "unknown"."""
    m = float(np.mean(measured))
    if value is None or not np.isfinite(value) or abs(m) < 1e-12:
        return "unknown against"
    return f"{value / m:.2g}x"


def region_design(summary: pd.DataFrame, points: int, seed: int = 0, first_id: int = 1,
                  nested: bool = False) -> pd.DataFrame:
    """``points`` parameter points spread over the posterior's 90 % box (each parameter's q05 to q95 in
    ``summary``): a Latin hypercube (scipy's, seeded), so that every interval is cut into ``points``
    slices each sampled once; ``nested``: the first ``points`` of a scrambled Sobol sequence, so that a
    larger design keeps a smaller one's points (more heaps add to those simulated, not beside them).
    Where the posterior lies is where the surrogate must be sure; heaps simulated there, at the measured
    conditions, teach it (docs/tutorial-hidden-effect.md, section 10). Columns ``run_id`` (from
    ``first_id``) and one per parameter, as ``simulate-heap --design`` reads."""
    import warnings

    from scipy.stats import qmc

    if points < 2:
        raise CalibError(f"a posterior-region design needs at least 2 points, got {points}")
    lo, hi = summary["q05"].to_numpy(float), summary["q95"].to_numpy(float)
    if nested:
        with warnings.catch_warnings():  # a count not a power of 2 loses Sobol's balance, not its spread
            warnings.simplefilter("ignore", UserWarning)
            u = qmc.Sobol(d=len(summary), scramble=True, seed=seed).random(points)
    else:
        u = qmc.LatinHypercube(d=len(summary), seed=seed).random(points)
    x = lo + u * (hi - lo)
    return pd.DataFrame({"run_id": np.arange(first_id, first_id + points),
                         **{p: x[:, k] for k, p in enumerate(summary["parameter"])}})
