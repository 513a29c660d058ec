"""The posterior over the model's parameters theta given the measured mean angle of every condition:

    log p(theta | data) = const + log N(ybar; mu(theta), V(theta)),   V = diag(v_c) + S(theta)

for theta inside every parameter's bounds (a uniform prior), -inf outside. ybar_c is the mean of the
n_c piles measured under condition c; mu_c the surrogate's latent mean there and S its latent
covariance across the conditions (:meth:`~calib_cli.posterior.gp.GPSurrogate.predict_joint`; its
diagonal is s_gp^2(theta, c)); v_c = s_c^2 / n_c the variance of the measured mean, its variance s_c^2
moderated across the conditions (:func:`mean_variance`). S is kept whole: the
surrogate's error at one theta is shared by its conditions, and taken as independent (diagonal S) it
was charged once per condition wherever the heaps are sparse, which drew hidden-effect's posterior
onto the cluster of validation heaps (surface_energy 0.013 to 0.11, the truth 0.6 outside).
With ``scatter``, each condition's measured pile variance s_c^2 (n_c >= 2 piles) is evidence too
(:func:`scatter_log_likelihood`): cohesive heaps scatter more than dry ones whose mean angle is alike.
With a second response (the heap profile's fullness, :class:`SecondResponse`), both responses' means
are stacked, each with its own surrogate, the measured means of a condition correlated as a pile's two
responses are.
It is sampled by emcee's ensemble (Foreman-Mackey et al., PASP 125, 2013) with differential-evolution
moves (ter Braak & Vrugt 2008): on both sample labs they cut the autocorrelation time of the default
stretch move three- to fourfold (hidden-effect: 24-35 steps against 113-158).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Optional

import numpy as np
import pandas as pd

from ..errors import CalibError
from ..surrogate.inversion import IDENTIFIABLE_FRACTION

#: with at least this many piles a condition's own sd stands alone; with fewer it is pooled with the
#: simulated pile-to-pile scatter (three piles' sd is off by 50 % one time in four)
OWN_SD_PILES = 5
#: the weight of the simulated scatter in that pooling, in degrees of freedom: as if it were the sd of
#: five piles (it is the simulated rig's scatter, not the lab's: it should not swamp the lab's own)
POOL_DOF = 4
#: emcee's rule: an autocorrelation time estimate is trusted on chains at least this many times longer
CHAIN_TAUS = 50


def moderated_variances(s2, dof) -> Optional[tuple[np.ndarray, float, float]]:
    """Each condition's pile variance moderated across the conditions (limma's empirical Bayes, Smyth,
    Stat. Appl. Genet. Mol. Biol. 3, 2004, section 6): the s_c^2 (dof d_c) are taken as scaled
    chi-squares about variances drawn from s0^2 d0 / chi^2_d0, whose d0 and s0^2 are fitted by moments of
    e_c = log s_c^2 - psi(d_c/2) + log(d_c/2) (mean log s0^2 - psi(d0/2) + log(d0/2), variance
    mean psi'(d_c/2) + psi'(d0/2)); each condition's posterior variance is then

        s~_c^2 = (d0 s0^2 + d_c s_c^2) / (d0 + d_c)   (d0 = inf, variances no more spread than chance: s0^2).

    Returns (s~^2, d0, s0^2); conditions with d_c = 0 or s_c^2 = 0 take s0^2 and do not fit it. None with
    fewer than 3 conditions to fit from."""
    from scipy.optimize import brentq
    from scipy.special import digamma, polygamma

    s2, dof = np.asarray(s2, float), np.asarray(dof, float)
    ok = (dof > 0) & np.isfinite(s2) & (s2 > 0)
    if ok.sum() < 3:
        return None
    e = np.log(s2[ok]) - digamma(dof[ok] / 2) + np.log(dof[ok] / 2)
    excess = float(np.var(e, ddof=1) - np.mean(polygamma(1, dof[ok] / 2)))
    # psi'(x) falls from 1e12 at 1e-6 to 1e-6 at 1e6, the root's bracket: an excess below that is no spread
    # beyond chance (d0 infinite)
    d0 = np.inf if excess <= polygamma(1, 1e6) else 2.0 * brentq(lambda x: polygamma(1, x) - excess, 1e-6, 1e6)
    s0_2 = float(np.exp(e.mean() if np.isinf(d0) else e.mean() + digamma(d0 / 2) - np.log(d0 / 2)))
    own = np.where(ok, s2, 0.0)
    d = np.where(ok, dof, 0.0)
    post = np.full(len(s2), s0_2) if np.isinf(d0) else (d0 * s0_2 + d * own) / (d0 + d)
    return post, float(d0), s0_2


def mean_variance(sd, n, noise_sd: float) -> np.ndarray:
    """v_c = s~_c^2 / n_c, the variance of a measured mean, s~_c^2 the condition's pile variance moderated
    across the conditions (:func:`moderated_variances`): the sd of ten piles is more than a quarter off
    its truth about three times in ten, and taken alone a chance-low one makes its mean look sharper
    than it is (and the surrogate look unsure there). With fewer than 3 conditions of two or more
    piles: s^2 = s_c^2 when n_c >= OWN_SD_PILES, else ((n_c - 1) s_c^2 + POOL_DOF noise_sd^2) /
    (n_c - 1 + POOL_DOF) (one pile: the simulated scatter)."""
    sd, n = np.asarray(sd, float), np.asarray(n, float)
    dof = np.maximum(n - 1, 0)
    own = np.where(dof > 0, np.nan_to_num(sd) ** 2, 0.0)
    moderated = moderated_variances(own, dof)
    if moderated is not None:
        return moderated[0] / n
    pooled = (dof * own + POOL_DOF * noise_sd ** 2) / (dof + POOL_DOF)
    return np.where(n >= OWN_SD_PILES, own, pooled) / n


@dataclass
class PosteriorResult:
    """Posterior draws ``samples_`` (one column per sampled parameter), their ``log_prob_``, the mean
    acceptance fraction ``acceptance_`` of the walkers, the integrated autocorrelation time per
    parameter ``autocorr_time_`` (steps), and the ``discard_`` burn-in steps and ``thin_`` kept."""

    bounds: dict[str, tuple[float, float]]
    n_walkers: int
    n_steps: int
    samples_: pd.DataFrame
    log_prob_: np.ndarray
    acceptance_: float
    autocorr_time_: pd.Series
    discard_: int
    thin_: int
    threshold: float = IDENTIFIABLE_FRACTION
    fixed: dict[str, float] = field(default_factory=dict)

    def summary(self) -> pd.DataFrame:
        """Per parameter: mean, median, q05, q95 (the 90 % interval), the prior's low and high,
        rel_width = (q95 - q05) / (high - low), identified = rel_width <= ``threshold`` (invert's
        IDENTIFIABLE_FRACTION: pinned to a fifth of its range), the autocorrelation time, the
        effective number of draws n_walkers (n_steps - discard) / tau, chain_ok = n_steps >= 50 tau
        (emcee's rule for a trusted tau), and the acceptance fraction."""
        rows = []
        for p, (lo, hi) in self.bounds.items():
            tau = float(self.autocorr_time_[p])
            rows.append({**_interval(p, self.samples_[p].to_numpy(), lo, hi, self.threshold), "autocorr_time": tau,
                         "n_eff": self.n_walkers * (self.n_steps - self.discard_) / tau,
                         "chain_ok": bool(self.n_steps >= CHAIN_TAUS * tau), "acceptance": self.acceptance_})
        return pd.DataFrame(rows)


def _interval(p: str, s: np.ndarray, lo: float, hi: float, threshold: float) -> dict:
    """A parameter's summary row from its draws ``s``: mean, median, the 90 % interval, its width over the
    prior range [lo, hi] and whether that is narrow enough to call it identified."""
    q05, q50, q95 = np.quantile(s, [0.05, 0.5, 0.95])
    rel = (q95 - q05) / (hi - lo)
    return {"parameter": p, "mean": float(s.mean()), "median": float(q50), "q05": float(q05), "q95": float(q95),
            "low": lo, "high": hi, "rel_width": float(rel), "identified": bool(rel <= threshold)}


def averaged_draws(on: pd.DataFrame, off: pd.DataFrame, p_off: float, seed: int = 0) -> pd.DataFrame:
    """Draws of the posterior averaged over an effect on and off (Bayesian model averaging): a share
    ``p_off`` of them from the posterior with the effect switched off (``off``, its parameter at the
    neutral value), the rest from the one with it free (``on``), as many as ``on`` holds. Column
    ``off`` says which."""
    rng = np.random.default_rng(seed)
    n = len(on)
    k = int(round(np.clip(p_off, 0.0, 1.0) * n))
    take = lambda df, m: df.iloc[rng.choice(len(df), m, replace=m > len(df))] if m else df.iloc[:0]  # noqa: E731
    return pd.concat([take(on, n - k).assign(off=False), take(off, k).assign(off=True)], ignore_index=True)


def summarise(draws: pd.DataFrame, bounds: Mapping[str, tuple[float, float]], chains: pd.DataFrame,
              threshold: float = IDENTIFIABLE_FRACTION) -> pd.DataFrame:
    """:meth:`PosteriorResult.summary` of other draws (an averaged posterior's): their quantiles, the chains'
    diagnostics (autocorrelation time, effective draws, acceptance) from ``chains``, a summary."""
    diag = chains.set_index("parameter")
    return pd.DataFrame([{**_interval(p, draws[p].to_numpy(float), lo, hi, threshold),
                          **{c: diag.loc[p, c] for c in ("autocorr_time", "n_eff", "chain_ok", "acceptance")}}
                         for p, (lo, hi) in bounds.items()])


def savage_dickey(draws, value: float, low: float, high: float, width: float = 0.02) -> float:
    """The Bayes factor of theta = ``value`` (an effect switched off) against theta free under its uniform
    prior on [low, high], by the Savage-Dickey ratio: the posterior density at the value over the prior's,

        B01 = p(value | data) / p(value) ~= P(theta in w) / (|w| / (high - low)),

    w the window of ``width`` times the range about the value, cut at the bounds (a histogram bin: the
    density at a bound is what a 90 % interval cannot show, since its 5 % quantile always lies above
    the bound). B01 > 3 favours the effect off, B01 < 1/10 calls for it (Jeffreys' scale)."""
    draws = np.asarray(draws, float)
    half = width * (high - low) / 2
    a, b = max(low, value - half), min(high, value + half)
    return float(np.mean((draws >= a) & (draws <= b)) / ((b - a) / (high - low)))


#: the window of :func:`savage_dickey`, as a fraction of the prior's range
SD_WINDOW = 0.02


def bayes_factor_off(draws, value: float, low: float, high: float, n_eff: float,
                     width: float = SD_WINDOW) -> tuple[float, bool]:
    """:func:`savage_dickey`'s B01 and whether it is an upper bound. The draws resolve a density only
    down to a few draws in the window: where none falls there, B01 is below the rule of three's 95 %
    bound on the window's probability, 3 / n_eff, over the window's prior share (n_eff the effective
    number of draws, :meth:`PosteriorResult.summary`), never 0."""
    bf = savage_dickey(draws, value, low, high, width)
    if bf > 0:
        return bf, False
    half = width * (high - low) / 2
    return _bound(n_eff, np.size(draws), (min(high, value + half) - max(low, value - half)) / (high - low)), True


def _bound(n_eff: float, draws: int, prior: float) -> float:
    """The rule of three's 95 % bound on a Bayes factor none of ``draws`` fell in the window of: 3 / n_eff over
    the window's ``prior`` probability."""
    if not np.isfinite(n_eff) or n_eff <= 0:  # no autocorrelation estimate: one draw in 50 (never 0, never
        n_eff = max(1.0, draws / 50.0)  # the all-draws bound, which would claim more than they hold)
    return float(3.0 / n_eff / prior)


def bayes_factor_equal(draws, tied, box: tuple[float, float], tied_box: tuple[float, float], n_eff: float,
                       width: float = SD_WINDOW) -> tuple[float, bool]:
    """The Bayes factor of theta = theta_t (a wall's value the grains' own: the effect off, theta_t uniform on
    ``tied_box``) against the two free and uniform, by the generalised Savage-Dickey ratio on their
    difference d = theta - theta_t (Verdinelli and Wasserman 1995):

        B01 = p(d = 0 | data) / p(d = 0) * |box n tied_box| / |tied_box|,
        p(d = 0) = |box n tied_box| / (|box| |tied_box|),

    the posterior density the share of draws with |d| within ``width`` times ``box``'s range about 0 over that
    window's prior probability (the two uniform priors' convolution over it). The last factor is the grains'
    prior under "off" over theirs given d = 0 (uniform on the overlap): 1 where ``box`` holds ``tied_box``;
    where it does not, B01 is exact as long as the data leave no weight on the grains' values beyond
    ``box``. NaN where the boxes do not overlap; an upper bound from the effective draws (as
    :func:`bayes_factor_off`) where no draw falls in the window."""
    d = np.asarray(draws, float) - np.asarray(tied, float)
    (a, b), (c, e) = box, tied_box
    overlap = min(b, e) - max(a, c)
    if not (b > a and e > c and overlap > 0):  # "equal" lies outside the prior
        return math.nan, False
    half = width * (b - a) / 2
    grid = np.linspace(-half, half, 201)
    density = np.clip(np.minimum(b, e + grid) - np.maximum(a, c + grid), 0, None) / ((b - a) * (e - c))
    prior = float(np.sum((density[1:] + density[:-1]) / 2 * np.diff(grid))) * (e - c) / overlap
    share = float(np.mean(np.abs(d) <= half))
    return (share / prior, False) if share > 0 else (_bound(n_eff, d.size, prior), True)


def mvn_logpdf(r: np.ndarray, V: np.ndarray) -> np.ndarray:
    """log N(r; 0, V) of b residual vectors r (b, m) with their covariances V (b, m, m), by Cholesky."""
    L = np.linalg.cholesky(V)
    z = np.linalg.solve(L, r[:, :, None])[:, :, 0]
    return -0.5 * np.sum(z ** 2, axis=1) - np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1) \
        - 0.5 * r.shape[1] * np.log(2 * np.pi)


def scatter_log_likelihood(log_var: np.ndarray, log_var_cov: np.ndarray, s2, n) -> np.ndarray:
    """The log likelihood of the measured pile variances s_c^2 (from n_c piles) of C conditions given
    the simulated piles' log sigma_c^2 (b, C) at b parameter sets and its covariance U (b, C, C) from
    the scatter model: (n - 1) s^2 / sigma^2 is chi^2 with k = n - 1 degrees of freedom, so log s^2 has
    mean log sigma^2 + psi(k/2) - log(k/2) and variance psi'(k/2) (psi the digamma function), taken as
    normal, the conditions' shared model error kept whole (as S is for the means):

        log s^2 ~ N(log sigma^2 + psi(k/2) - log(k/2), diag(psi'(k/2)) + U)

    Returns (b,); a condition with one pile or an sd of 0 is left out."""
    from scipy.special import digamma, polygamma

    s2, k = np.asarray(s2, float), np.asarray(n, float) - 1.0
    ok = (k >= 1) & np.isfinite(s2) & (s2 > 0)
    if not ok.any():
        return np.zeros(len(log_var))
    k = k[ok]
    r = np.log(s2[ok]) - (log_var[:, ok] + digamma(k / 2) - np.log(k / 2))
    return mvn_logpdf(r, log_var_cov[:, ok][:, :, ok] + np.diag(polygamma(1, k / 2)))


@dataclass(frozen=True)
class SecondResponse:
    """A second measured response of every condition (the heap profile's fullness), with its own
    surrogate ``gp`` over the same inputs: the measured ``mean``, ``sd`` and ``n`` in the angle's
    condition order, and ``rho`` the correlation of a pile's two responses within a condition (the
    measured means then correlate as rho sqrt(v_angle v_second); where a photograph gave an angle but no
    fullness the two means' piles differ and this slightly overstates their covariance)."""

    gp: object
    mean: np.ndarray
    sd: np.ndarray
    n: np.ndarray
    rho: float = 0.0


@dataclass(frozen=True)
class ColumnShare:
    """How many of each condition's measured piles stood as columns (``k`` of ``n``, the angle's condition
    order), and the simulated heaps' chance of it (``model``, a :class:`~calib_cli.posterior.gp.ColumnModel`):
    the binomial log likelihood sum_c k_c log p_c(theta) + (n_c - k_c) log(1 - p_c(theta)) joins the
    posterior's. A dry model whose fills never stand cannot give a lab's columns; one whose fills often
    stand cannot give a lab's none."""

    model: object
    k: np.ndarray
    n: np.ndarray
    #: conditions measured where every pile stood (no angle, so not among the C): their condition variables'
    #: values and their piles, each of which stood: sum_e n_e log p_e(theta) joins too
    stood: Mapping[str, np.ndarray] = field(default_factory=dict)
    stood_n: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def log_likelihood(self, X: np.ndarray, X_stood: Optional[np.ndarray] = None) -> np.ndarray:
        """(b,) at b parameter sets under the C conditions (X: (b, C, inputs)) and those where every pile
        stood (``X_stood``: (b, E, inputs))."""
        b, C, k = X.shape
        p = self.model.probability(X.reshape(-1, k)).reshape(b, C)
        out = np.sum(self.k * np.log(p) + (self.n - self.k) * np.log1p(-p), axis=1)
        if X_stood is not None and X_stood.shape[1]:
            out = out + np.log(self.model.probability(X_stood.reshape(-1, k)).reshape(b, -1)) @ self.stood_n
        return out


def _inputs(gp, t: np.ndarray, names: list[str], fixed: Mapping[str, float], cond_vals: Mapping[str, np.ndarray],
            C: int) -> np.ndarray:
    """(walkers, C, inputs) in ``gp.inputs_`` order: each walker's parameters under every condition."""
    X = np.empty((len(t), C, len(gp.inputs_)))
    for k, c in enumerate(gp.inputs_):
        X[:, :, k] = fixed[c] if c in fixed else t[:, names.index(c), None] if c in names else cond_vals[c][None, :]
    return X


def response_variances(gp, measured: pd.DataFrame, second: Optional[SecondResponse]) -> list[tuple]:
    """Each response's surrogate with its measured means' variances (:func:`mean_variance`): the angle's
    (``measured``'s sd and n), then the second response's where there is one."""
    out = [(gp, mean_variance(measured["sd"], measured["n"], gp.noise_sd_))]
    if second is not None:
        out.append((second.gp, mean_variance(second.sd, second.n, second.gp.noise_sd_)))
    return out


def _joint_terms(gp, second: Optional[SecondResponse], X, X2, ybar, v, v2):
    """The residual vector and its covariance of the means (one response, or both stacked: the two
    surrogates' errors apart, the measured means correlated within each condition); v and v2 the two
    responses' measured means' variances (:func:`mean_variance`)."""
    mu, cov = gp.predict_joint(X)
    r, V = ybar[None, :] - mu, cov + np.diag(v + 1e-9)  # the jitter: a measured sd of 0
    if second is None:
        return r, V
    mu2, cov2 = second.gp.predict_joint(X2)
    cross = np.diag(second.rho * np.sqrt(v * v2))
    V = np.block([[V, np.broadcast_to(cross, V.shape)], [np.broadcast_to(cross, V.shape), cov2 + np.diag(v2 + 1e-12)]])
    return np.concatenate([r, second.mean[None, :] - mu2], axis=1), V


def _log_prob_fn(gp, measured: pd.DataFrame, names: list[str], bounds, fixed: Mapping[str, float],
                 scatter: bool = False, second: Optional[SecondResponse] = None,
                 columns: Optional[ColumnShare] = None):
    """The vectorised log posterior: theta (walkers, d) -> (walkers,), one batch of GP predictions
    for every walker under every condition, with each walker's C x C covariance (2C x 2C with a
    ``second`` response; with ``scatter``, each condition's pile variance too)."""
    C, ybar = len(measured), measured["mean"].to_numpy(float)
    # once, not per call: the moderation fits its prior by a root search (~0.2 ms), and the sampler calls
    # log_prob twice a step
    (_, v), *rest = response_variances(gp, measured, second)
    v2 = rest[0][1] if rest else None
    lo, hi = np.array([bounds[p][0] for p in names]), np.array([bounds[p][1] for p in names])
    conds = {c for g in (gp, second.gp if second else gp) for c in g.inputs_ if c not in g.parameters}
    cond_vals = {c: measured[c].to_numpy(float) for c in conds}
    s2, n = measured["sd"].to_numpy(float) ** 2, measured["n"].to_numpy(float)
    scatter = scatter and gp.scatter_ is not None  # one simulated scatter: the same term at every theta

    def log_prob(theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(theta)
        out = np.full(len(theta), -np.inf)
        inside = np.all((theta >= lo) & (theta <= hi), axis=1)
        if not inside.any():
            return out
        t = theta[inside]
        X = _inputs(gp, t, names, fixed, cond_vals, C)
        X2 = _inputs(second.gp, t, names, fixed, cond_vals, C) if second else None
        out[inside] = mvn_logpdf(*_joint_terms(gp, second, X, X2, ybar, v, v2))
        if scatter:
            lv, U = gp.log_pile_variance(gp._scale(X.reshape(-1, X.shape[2])).reshape(X.shape))
            out[inside] += scatter_log_likelihood(lv, U, s2, n)
        if columns is not None:
            out[inside] += columns.log_likelihood(X, _inputs(gp, t, names, fixed, columns.stood, len(columns.stood_n))
                                                   if len(columns.stood_n) else None)
        return out

    return log_prob, lo, hi


def _start(log_prob, lo: np.ndarray, hi: np.ndarray, n_walkers: int, rng: np.random.Generator) -> np.ndarray:
    """Walkers drawn from 50 prior draws each, resampled by their posterior weight: they start in
    every mode the prior draws found, so the burn-in need not find them."""
    cand = lo + rng.random((50 * n_walkers, len(lo))) * (hi - lo)
    lp = log_prob(cand)
    w = np.exp(lp - lp.max())
    pick = rng.choice(len(cand), n_walkers, replace=False, p=w / w.sum()) if (w > 0).sum() >= n_walkers \
        else np.argsort(-lp)[:n_walkers]
    return cand[pick]


def check_sampler(parameters: int, walkers: int, steps: int) -> None:
    """Refuse an ensemble emcee cannot run: fewer walkers than twice the parameters, or under 10 steps (a
    stage calls it before its first heap or fit, not after)."""
    if walkers < 2 * parameters or steps < 10:
        raise CalibError(f"--walkers {walkers} --steps {steps}: emcee needs at least {2 * parameters} walkers (twice "
                         f"the {parameters} parameters) and 10 steps")


def calibrate_posterior(gp, measured: pd.DataFrame, bounds: Mapping[str, tuple[float, float]],
                        fixed: Optional[Mapping[str, float]] = None, n_walkers: int = 32, n_steps: int = 5000,
                        seed: int = 0, scatter: bool = False,
                        second: Optional[SecondResponse] = None,
                        columns: Optional[ColumnShare] = None) -> PosteriorResult:
    """Sample the posterior of the parameters in ``bounds`` (name -> (low, high), the uniform prior)
    given ``measured`` (one row per condition: ``mean``, ``sd``, ``n`` and the surrogate's condition
    columns), the surrogate's other parameters held at ``fixed``; with ``scatter`` the measured ``sd``
    is evidence as well as the mean (:func:`scatter_log_likelihood`); a ``second`` response's measured
    means too (:class:`SecondResponse`); ``columns``, the share of piles that stood as columns
    (:class:`ColumnShare`). The first quarter of the steps, or three autocorrelation times
    if longer (at most half), is burn-in; the rest is thinned by half the shortest autocorrelation time.
    The same seed gives the same draws."""
    import emcee

    if not isinstance(bounds, Mapping) or not isinstance(measured, pd.DataFrame):
        raise CalibError("calibrate_posterior takes bounds as {parameter: (low, high)} and measured as a frame, one "
                         "row per condition")
    conds = [c for c in gp.inputs_ if c not in gp.parameters]
    lacking = [c for c in ("mean", "sd", "n", *conds) if c not in measured.columns]
    if lacking:
        raise CalibError(f"the measured conditions lack column(s) {', '.join(lacking)}: one row per condition with "
                         "its mean, sd and n piles, and the surrogate's condition variables")
    fixed = {k: float(v) for k, v in (fixed or {}).items()}
    names = list(bounds)
    loose = [p for p in gp.parameters if p not in bounds and p not in fixed]
    if loose or set(names) - set(gp.parameters):
        raise CalibError(f"give every surrogate parameter ({', '.join(gp.parameters)}) a prior range or a fixed "
                         f"value; got bounds for {', '.join(names)} and fixed {', '.join(fixed) or 'none'}")
    check_sampler(len(names), n_walkers, n_steps)
    from threadpoolctl import threadpool_limits  # scikit-learn's own dependency

    if second is not None and not (np.size(second.mean) == np.size(second.sd) == np.size(second.n) == len(measured)):
        raise CalibError(f"the second response gives {np.size(second.mean)} condition(s), the angle {len(measured)}")
    log_prob, lo, hi = _log_prob_fn(gp, measured, names, bounds, fixed, scatter, second, columns)
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(n_walkers, len(names), log_prob, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()
    # one BLAS thread: a step's matrices are small (walkers x conditions by heaps), and on a busy two-core
    # machine waking a pool for each cost 25 times the arithmetic (7.5 s a calibration, not 0.3)
    with threadpool_limits(1, user_api="blas"):
        p0 = _start(log_prob, lo, hi, n_walkers, np.random.default_rng(seed))
        sampler.run_mcmc(p0, n_steps, progress=False)
    tau = sampler.get_autocorr_time(tol=0)
    # a chain too short to estimate it (NaN, at --steps 10): as long as the chain, so it is not trusted
    tau = np.maximum(np.where(np.isfinite(tau), tau, n_steps), 1.0)
    discard = int(min(n_steps // 2, max(n_steps // 4, np.ceil(3 * tau.max()))))
    thin = max(1, int(tau.min() / 2))
    chain = sampler.get_chain(discard=discard, thin=thin, flat=True)
    return PosteriorResult({p: (float(bounds[p][0]), float(bounds[p][1])) for p in names}, n_walkers, n_steps,
                           pd.DataFrame(chain, columns=names),
                           sampler.get_log_prob(discard=discard, thin=thin, flat=True),
                           float(np.mean(sampler.acceptance_fraction)), pd.Series(tau, index=names),
                           discard, thin, fixed=fixed)
