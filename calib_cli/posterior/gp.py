"""A Gaussian-process surrogate of the repose angle over the model's parameters and the heap-test
conditions, trained on every simulated pile (one row each):

    y = f(x) + e,   f ~ GP(m, s^2 Matern_3/2(|x - x'|_l)),   e ~ N(0, sigma^2)

x holds each input scaled to [0, 1] (a parameter by its bounds, the prior range; a condition variable
by its simulated range), one length scale l per input; y is standardised by its training mean m and
sd. s, l and sigma maximise the marginal likelihood (scikit-learn). sigma is the pile-to-pile scatter
of the simulated heaps (``noise_sd_``, deg). Where the repeated piles (rows with equal inputs) show
that the scatter changes over the inputs (cohesive heaps scatter about twice as much as dry ones),
each pile's variance is sigma^2(x) + w instead, log sigma^2 a second Gaussian process over the
groups of repeated piles (:func:`scatter_model`).
:meth:`GPSurrogate.predict` gives the latent f, without the scatter of a pile:

    mean = m + k*' (K + sigma^2 I)^-1 y,   var = s^2 - k*' (K + sigma^2 I)^-1 k*
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

import numpy as np
import pandas as pd
from scipy.linalg import solve_triangular

from ..errors import CalibError

#: the length scales' range in scaled units: below a tenth of an input's range the design (whose points
#: lie further apart) cannot resolve a trend, and the fit then chases the scatter of clustered
#: validation heaps (hidden-effect: surface_energy's scale fell to 0.03 and the held-out error rose);
#: at 100 an input does not matter
LENGTH_BOUNDS = (0.1, 100.0)
#: the Matern kernel's smoothness: 3/2 (once differentiable) rather than 5/2 or the RBF, whose smoother
#: functions predicted held-out design points worse on both sample labs (5-fold RMSE, two seeds each:
#: hidden-effect 5.02 and 5.23 deg against 5.61 and 5.33 for 5/2 and 6.32 and 5.53 for the RBF;
#: control-lab 2.12 and 1.88 against 2.13 and 1.92 and 2.39 and 1.98)
NU = 1.5


#: the scatter is modelled as changing over the inputs only when a likelihood-ratio test against one
#: scatter rejects at this level, on at least this many groups of repeated piles
HETERO_P, HETERO_GROUPS = 0.01, 20
#: groups of points whose scatter :meth:`ScatterFit.log_variance_joint` predicts in one call (the sampler's
#: calls hold half its walkers, 16 by default)
GROUPS_AT_ONCE = 32


@dataclass(frozen=True)
class ScatterFit:
    """log sigma^2(x) over the scaled inputs: a Gaussian process fitted to the groups of repeated piles'
    log variances, each corrected for the chi-square's bias and weighted by its variance,

        z_j = log s_j^2 - psi(k_j/2) + log(k_j/2),   z_j ~ N(log sigma^2(x_j), psi'(k_j/2)),  k_j = n_j - 1

    (psi the digamma function), z standardised by ``z_mean``, ``z_sd``. A log-linear trend held 70 % of
    the truths of a concave scatter in the 90 % intervals of the posterior with the scatter as evidence,
    the process 84.5 % (both with the model's error taken as independent per condition; shared, 88 %:
    tests/test_posterior.py)."""

    gp: object
    z_mean: float
    z_sd: float

    def log_variance(self, Xs: np.ndarray) -> np.ndarray:
        """log sigma^2(x), the process's mean."""
        return self.z_mean + self.z_sd * self.gp.predict(np.atleast_2d(Xs))

    def variance(self, Xs: np.ndarray) -> np.ndarray:
        """sigma^2(x), deg^2 (the exponential of log sigma^2's mean)."""
        return np.exp(self.log_variance(Xs))

    def log_variance_joint(self, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """log sigma^2 at b groups of m scaled inputs (G: (b, m, k)): mean (b, m) and the process's
        covariance within each group (b, m, m), large where no repeated piles were. A group's points
        (one parameter set under m conditions) share most of it, as the angle's do."""
        b, m, k = G.shape
        mean, blocks = np.empty((b, m)), np.empty((b, m, m))
        # GROUPS_AT_ONCE groups a call: the process's covariance between all b m points, of which only the
        # diagonal blocks are kept, cost the posterior's start (1,600 groups, 9,600 points) 740 MB and 6 s a
        # fit; each element comes out the same either way (tests/test_posterior.py)
        for s in range(0, b, GROUPS_AT_ONCE):
            g = G[s:s + GROUPS_AT_ONCE]
            mu, cov = self.gp.predict(g.reshape(-1, k), return_cov=True)
            idx = np.arange(len(g))
            mean[s:s + len(g)] = mu.reshape(len(g), m)
            blocks[s:s + len(g)] = cov.reshape(len(g), m, len(g), m)[idx, :, idx, :]
        return self.z_mean + self.z_sd * mean, self.z_sd ** 2 * blocks


def _fit_log_variance(keys: np.ndarray, s2: np.ndarray, dof: np.ndarray, seed: int = 0) -> ScatterFit:
    """:class:`ScatterFit` of the groups' variances s2 (each from dof + 1 piles) at scaled inputs keys."""
    from scipy.special import digamma, polygamma
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern

    z = np.log(s2) - digamma(dof / 2) + np.log(dof / 2)
    zm, zs = float(z.mean()), float(z.std()) or 1.0
    kernel = ConstantKernel(1.0, (1e-3, 1e2)) * Matern(np.full(keys.shape[1], 0.5), LENGTH_BOUNDS, nu=NU)
    gp = GaussianProcessRegressor(kernel, alpha=polygamma(1, dof / 2) / zs ** 2, n_restarts_optimizer=2,
                                  random_state=seed)
    with warnings.catch_warnings():  # a length scale at its bound: an input the scatter does not follow
        warnings.simplefilter("ignore", ConvergenceWarning)
        gp.fit(keys, (z - zm) / zs)
    return ScatterFit(gp, zm, zs)


def scatter_model(X: np.ndarray, y: np.ndarray) -> Optional[ScatterFit]:
    """The pile-to-pile variance as a function of the scaled inputs, from the groups of repeated piles
    (rows of X alike): each group's sum of squares about its mean is sigma_j^2 chi^2(n_j - 1). Whether
    it changes at all is a likelihood-ratio test of a log-linear trend against one variance (a gamma GLM
    with log link, statsmodels, dispersion fixed at 2 with weights n_j - 1: s_j^2 is gamma with mean
    sigma_j^2 and dispersion 2 / (n_j - 1)); when it rejects at HETERO_P (chi-square, one degree of
    freedom per input) on at least HETERO_GROUPS groups, the returned :class:`ScatterFit` follows the
    groups' log variances; else None (one sigma, learned with the GP)."""
    import statsmodels.api as sm
    from scipy.stats import chi2

    keys, inv = np.unique(np.round(X, 9), axis=0, return_inverse=True)
    inv = inv.ravel()
    n = np.bincount(inv)
    mean = np.bincount(inv, weights=y) / n
    ss = np.bincount(inv, weights=(y - mean[inv]) ** 2)
    rep = (n > 1) & (ss > 0)
    if rep.sum() < max(HETERO_GROUPS, 3 * (X.shape[1] + 1)):
        return None
    dof, s2 = n[rep] - 1.0, ss[rep] / (n[rep] - 1.0)
    family = sm.families.Gamma(sm.families.links.Log())
    designs = (np.ones((rep.sum(), 1)), sm.add_constant(keys[rep], has_constant="add"))
    with warnings.catch_warnings():  # inputs collinear among the repeated groups: any solution fits alike
        warnings.simplefilter("ignore")
        try:
            fits = [sm.GLM(s2, exog, family=family, var_weights=dof).fit(scale=2.0) for exog in designs]
            lr = 2.0 * (fits[1].llf - fits[0].llf)
        except (ValueError, np.linalg.LinAlgError):
            # IRLS diverged (pairs of piles, whose one degree of freedom makes some s^2 near 0): the same
            # likelihood maximised another way
            lr = _log_variance_lr(designs, s2, dof)
    if not chi2.sf(lr, X.shape[1]) < HETERO_P:
        return None
    return _fit_log_variance(keys[rep], s2, dof)


def _log_variance_lr(designs, s2: np.ndarray, dof: np.ndarray) -> float:
    """The same likelihood ratio as the gamma GLM's, its two fits by Newton-type minimisation in scipy:
    s^2 is gamma with shape k/2 and mean exp(x b), whose log likelihood, up to a constant,
    -sum (k/2)(x b + s^2 exp(-x b)), is concave in b (one maximum; IRLS's divergence is its own)."""
    from scipy.optimize import minimize

    half = dof / 2

    def fit(A: np.ndarray) -> float:
        def f(b):
            xb = A @ b
            e = s2 * np.exp(-xb)
            return float(np.sum(half * (xb + e))), A.T @ (half * (1.0 - e))

        b0, *_ = np.linalg.lstsq(A, np.log(s2), rcond=None)
        return -minimize(f, b0, jac=True, method="BFGS").fun

    return 2.0 * (fit(designs[1]) - fit(designs[0]))


def informative_conditions(rows: pd.DataFrame, candidates: Sequence[str]) -> list[str]:
    """The candidate condition columns that vary among ``rows`` and are not linear in the ones before
    (d_max = d_min + 1 adds nothing; a fill height proportional to the diameter would make a fit
    singular): what every surrogate over conditions learns from (``fit-surrogate``, the posterior)."""
    keep, basis = [], np.ones((len(rows), 1))
    for c in candidates:
        if c in rows.columns and rows[c].nunique() > 1:
            trial = np.column_stack([basis, rows[c].to_numpy(float)])
            if np.linalg.matrix_rank(trial) > basis.shape[1]:
                keep.append(c)
                basis = trial
    return keep


#: each response's mean over a heap's side views in its results row (``side_views`` of them measured)
VIEWS_OF = {"repose_angle": "angle_views", "fullness": "fullness_views"}
#: the fewest groups of repeated piles from which the share of a pile's variance the views keep is set
VIEW_GROUPS = 10


def views_of(rows: pd.DataFrame, response: str) -> Optional[np.ndarray]:
    """Each row's mean of ``response`` over its side views, for :meth:`GPSurrogate.fit`: the row's one
    view where none measured (``side_views`` 0), NaN where the heap was simulated before its views were
    recorded (then the fit learns from one view a heap); None for a response without views."""
    col = VIEWS_OF.get(response)
    if col is None or col not in rows.columns or "side_views" not in rows.columns:
        return None
    n = rows["side_views"].to_numpy(float)
    return np.where(n >= 1, rows[col].to_numpy(float), np.where(n == 0, rows[response].to_numpy(float), np.nan))


def view_share(Xs: np.ndarray, y: np.ndarray, v: np.ndarray) -> float:
    """The share of one view's pile-to-pile variance that the side views' mean keeps: over the groups of
    repeated piles (rows of Xs alike), the pooled sum of squares about the group means of v over y's.
    1 (learn from y, one view) where some v is not finite, fewer than VIEW_GROUPS groups have repeats,
    or the views keep no less than one view does."""
    if not np.all(np.isfinite(v)):
        return 1.0
    _, inv = np.unique(np.round(Xs, 9), axis=0, return_inverse=True)
    inv = inv.ravel()
    n = np.bincount(inv)
    if int((n > 1).sum()) < VIEW_GROUPS:
        return 1.0

    def within(z):
        return float(np.sum((z - (np.bincount(inv, weights=z) / n)[inv]) ** 2))

    one = within(y)
    return float(min(within(v) / one, 1.0)) if one > 0 else 1.0


#: the most cross-kernel entries (groups x points x heaps) one :meth:`GPSurrogate.predict_joint` product holds
JOINT_CHUNK = 5e7


class GPSurrogate:
    """The angle's Gaussian process over ``parameters`` (scaled by ``bounds``: name -> (low, high);
    a parameter without bounds by its training range) and the ``conditions`` among the candidates
    that vary in the training rows: ``fit(X, y)`` with X the heaps' frame (the parameters' and
    any candidate conditions' columns) and y their response (the angle, or another such as the
    fullness), ``predict(X)``. Learned attributes end in ``_``: ``inputs_``, ``lows_``,
    ``highs_``, ``constants_`` (the candidate conditions every row shares), ``noise_sd_`` (the piles'
    rms scatter), ``scatter_`` (:func:`scatter_model`'s fit, or None: one scatter), ``white_sd_``,
    ``signal_sd_``, ``length_scales_`` (scaled units, per input), ``n_train_``, ``view_share_`` (1: learnt
    from one view a heap; below 1: from the side views' means, :func:`view_share`)."""

    def __init__(self, parameters: Sequence[str], conditions: Sequence[str] = (),
                 bounds: Mapping[str, tuple[float, float]] | None = None, nu: float = NU, restarts: int = 2,
                 seed: int = 0):
        self.parameters, self.conditions = list(parameters), list(conditions)
        self.bounds = dict(bounds or {})
        self.nu, self.restarts, self.seed = float(nu), int(restarts), int(seed)

    def _ranges(self, rows: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        for c in self.inputs_:
            a, b = self.bounds.get(c, (float(rows[c].min()), float(rows[c].max())))
            if not b > a:
                raise CalibError(f"{c} has no spread in the simulated heaps ({a:g}): the surrogate cannot learn it")
            lo.append(a)
            hi.append(b)
        return np.array(lo), np.array(hi)

    def fit(self, X: pd.DataFrame, y, views=None) -> "GPSurrogate":
        """Fit to the heaps X and their responses y (rows whose y is not finite are left out). ``views``:
        each heap's mean over its side views (:func:`views_of`), which the process then learns f
        from, with the noise of such a mean; y, one view as a photograph, then only sets the share of a
        pile's variance the views keep (``view_share_``), by which :meth:`pile_sd` is one view's."""
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel
        from threadpoolctl import threadpool_limits  # scikit-learn's own dependency

        if not isinstance(X, pd.DataFrame) or len(X) != len(np.atleast_1d(y)):
            raise CalibError("GPSurrogate.fit(X, y) takes the heaps as a frame and one response per row")
        missing = [c for c in self.parameters if c not in X.columns]
        if missing:
            raise CalibError(f"GPSurrogate.fit: the heaps lack the parameter column(s) {', '.join(missing)}")
        y = np.asarray(y, float)
        if views is not None and np.shape(views) != y.shape:
            raise CalibError("GPSurrogate.fit(X, y, views) takes one side views' mean per row, as y")
        keep = np.isfinite(y)
        rows, y = X[keep], y[keep]
        v = None if views is None else np.asarray(views, float)[keep]
        conds = informative_conditions(rows, self.conditions)
        self.inputs_ = self.parameters + conds
        self.constants_ = {c: float(rows[c].iloc[0]) for c in self.conditions
                           if c in rows.columns and rows[c].nunique() == 1}
        self.lows_, self.highs_ = self._ranges(rows)
        Xs = self._scale(rows)
        self.view_share_ = 1.0 if v is None else view_share(Xs, y, v)
        if self.view_share_ < 1.0:
            y = v
        self.y_mean_, self.y_sd_ = float(y.mean()), float(y.std()) or 1.0
        self.scatter_ = scatter_model(Xs, y)
        kernel = (ConstantKernel(1.0, (1e-3, 1e3))
                  * Matern(np.full(len(self.inputs_), 0.5), LENGTH_BOUNDS, nu=self.nu)
                  + WhiteKernel(0.1, (1e-6, 1.0)))
        # the scatter the repeated piles show, on each pile's diagonal; the white kernel adds what is left
        alpha = 1e-10 if self.scatter_ is None else self.scatter_.variance(Xs) / self.y_sd_ ** 2
        gp = GaussianProcessRegressor(kernel, alpha=alpha, n_restarts_optimizer=self.restarts, random_state=self.seed)
        # one BLAS thread: the matrices are a few hundred heaps a side, which threads speed up little, and on
        # a busy two-core machine the pool's waiting made hidden-effect's fit take 81 s instead of 4 s
        with warnings.catch_warnings(), threadpool_limits(1, user_api="blas"):
            # a length scale at its upper bound is an input that does not matter, not a failed fit
            warnings.simplefilter("ignore", ConvergenceWarning)
            self.gp_ = gp.fit(Xs, (y - self.y_mean_) / self.y_sd_)
        k = self.gp_.kernel_
        self.latent_ = k.k1  # s^2 Matern: the kernel of f, without the piles' scatter
        self.white_sd_ = float(np.sqrt(k.k2.noise_level)) * self.y_sd_
        self.noise_sd_ = float(np.sqrt(np.mean(self.pile_sd(Xs, scaled=True) ** 2)))
        self.signal_sd_ = float(np.sqrt(k.k1.k1.constant_value)) * self.y_sd_
        self.length_scales_ = pd.Series(np.atleast_1d(k.k1.k2.length_scale), index=self.inputs_)
        self.n_train_ = len(y)
        return self

    def condition_ranges(self) -> dict[str, tuple[float, float]]:
        """The condition variables the surrogate learnt, each with the range its heaps covered: beyond
        it the surrogate extrapolates."""
        k0 = len(self.parameters)
        return {c: (float(lo), float(hi)) for c, lo, hi in zip(self.inputs_[k0:], self.lows_[k0:], self.highs_[k0:])}

    def heap_sd(self, X, scaled: bool = False) -> np.ndarray:
        """The sd (deg) of what the process learns from one heap at X, its noise: one value everywhere,
        or sigma(x) where the repeated piles showed the scatter to change (``scatter_``), plus what the
        GP's white kernel learned. A pile's one view where the heaps had one, their side views' mean
        where they were fitted with ``views``."""
        Xs = np.atleast_2d(np.asarray(X, float)) if scaled else self._scale(X)
        var = np.full(len(Xs), self.white_sd_ ** 2)
        if self.scatter_ is not None:
            var = var + self.scatter_.variance(Xs)
        return np.sqrt(var)

    def pile_sd(self, X, scaled: bool = False) -> np.ndarray:
        """The pile-to-pile sd (deg) at X of one side view, as a photograph of a pile: :meth:`heap_sd`
        over the share of that variance the views keep, sqrt(``view_share_``)."""
        return self.heap_sd(X, scaled) / np.sqrt(self.view_share_)

    def log_pile_variance(self, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """log sigma^2 of a pile at b groups of m scaled inputs (G: (b, m, k)), with the white kernel's
        share w: mean log(w + v) (b, m) and its covariance within each group (b, m, m), the scatter
        process's carried by the delta method, d log(w + v) / d log v = v / (w + v). Needs a changing
        scatter (``scatter_``); of one view (:meth:`pile_sd`)."""
        lv, cov = self.scatter_.log_variance_joint(G)
        v = np.exp(lv)
        jac = v / (self.white_sd_ ** 2 + v)
        # fitted on the views' means: a photograph's one view scatters by 1 / view_share_ as much
        return np.log(self.white_sd_ ** 2 + v) - np.log(self.view_share_), jac[:, :, None] * cov * jac[:, None, :]

    def _scale(self, X) -> np.ndarray:
        if not hasattr(self, "lows_"):
            raise CalibError("this GPSurrogate is not fitted yet: call fit(X, y) first")
        if isinstance(X, pd.DataFrame):
            missing = [c for c in self.inputs_ if c not in X.columns]
            if missing:
                raise CalibError(f"the points lack the surrogate's input column(s) {', '.join(missing)} "
                                 f"(its inputs_: {', '.join(self.inputs_)})")
            X = X[self.inputs_].to_numpy(float)
        X = np.atleast_2d(np.asarray(X, float))
        if X.shape[-1] != len(self.inputs_):
            raise CalibError(f"the points have {X.shape[-1]} column(s), the surrogate {len(self.inputs_)} inputs "
                             f"({', '.join(self.inputs_)})")
        return (X - self.lows_) / (self.highs_ - self.lows_)

    def predict(self, X, return_std: bool = False):
        """The latent mean angle at X (a frame with the ``inputs_`` columns, or an array in their
        order) and, with ``return_std``, its sd (the surrogate's own uncertainty; no pile scatter)."""
        Xs = self._scale(X)
        Ks = self.latent_(Xs, self.gp_.X_train_)
        mean = self.y_mean_ + self.y_sd_ * (Ks @ self.gp_.alpha_)
        if not return_std:
            return mean
        v = solve_triangular(self.gp_.L_, Ks.T, lower=True, check_finite=False)
        var = self.latent_.diag(Xs) - np.einsum("ij,ij->j", v, v)
        return mean, self.y_sd_ * np.sqrt(np.clip(var, 0.0, None))


    def latent_cov(self, X) -> np.ndarray:
        """The latent f's posterior covariance (deg^2) between the points of X (n, k in ``inputs_`` order):
        what one more pile at one of them would teach about the others (``calibrate``'s acquisition)."""
        Xs = self._scale(X)
        v = solve_triangular(self.gp_.L_, self.latent_(Xs, self.gp_.X_train_).T, lower=True, check_finite=False)
        return self.y_sd_ ** 2 * (self.latent_(Xs) - v.T @ v)

    def sample_latent(self, X, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The latent mean at the points of X (N, k in ``inputs_`` order) and ``n`` joint draws of f there
        (n, N): functions the heaps so far cannot tell from the mean. A jitter of 1e-8 of the mean variance
        keeps the covariance's Cholesky factor finite where points nearly coincide."""
        X = np.asarray(X, float)
        mean, C = self.predict(X), self.latent_cov(X)
        C[np.diag_indices_from(C)] += 1e-8 * max(float(np.mean(np.diag(C))), 1e-12)
        try:
            L = np.linalg.cholesky(C)
        except np.linalg.LinAlgError:  # not positive definite in floating point: its clipped eigenbasis
            w, V = np.linalg.eigh(C)
            L = V * np.sqrt(np.clip(w, 0.0, None))
        return mean, mean + (L @ np.random.default_rng(seed).standard_normal((len(mean), n))).T

    def predict_joint(self, X) -> tuple[np.ndarray, np.ndarray]:
        """The latent mean (b, m) and covariance (b, m, m) of f at b groups of m points (X: (b, m, k) in
        ``inputs_`` order), cov_g = k(X_g, X_g) - k(X_g, X)(K + sigma^2 I)^-1 k(X, X_g): a point's
        conditions share the surrogate's error at one parameter set. The kernel is stationary, so
        k(x, x') is k(0, x - x') and every group's block costs m^2 differences."""
        if isinstance(X, pd.DataFrame) or np.ndim(X) != 3:
            raise CalibError("predict_joint(X) takes an array (groups, points, inputs) in inputs_ order; "
                             "predict(X) takes a frame")
        X = np.asarray(X, float)
        b, m, k = X.shape
        # in chunks of groups where the cross-kernel, (b m) x heaps, would pass 400 MB (9 GB for --walkers 10000's
        # start): a calibration's own calls (50 x 32 walkers' start) stay one product, so their bits do not move
        step = max(1, int(JOINT_CHUNK // max(m * len(self.gp_.X_train_), 1)))
        if b > step:
            parts = [self.predict_joint(X[i:i + step]) for i in range(0, b, step)]
            return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        Xs = self._scale(X.reshape(-1, k))
        Ks = self.latent_(Xs, self.gp_.X_train_)
        mean = (self.y_mean_ + self.y_sd_ * (Ks @ self.gp_.alpha_)).reshape(b, m)
        v = solve_triangular(self.gp_.L_, Ks.T, lower=True, check_finite=False).T.reshape(b, m, -1)
        G = Xs.reshape(b, m, k)
        prior = self.latent_(np.zeros((1, k)), (G[:, :, None, :] - G[:, None, :, :]).reshape(-1, k)).reshape(b, m, m)
        return mean, self.y_sd_ ** 2 * (prior - np.einsum("bin,bjn->bij", v, v))


def design_points(rows: pd.DataFrame, parameters: Sequence[str]) -> np.ndarray:
    """An integer label per row: rows with the same parameter values (a design point's piles under
    every condition and repeat) share one."""
    key = rows[list(parameters)].round(10).astype(str).agg("|".join, axis=1)
    return pd.factorize(key)[0]


def holdout_rmse(rows: pd.DataFrame, parameters: Sequence[str], conditions: Sequence[str],
                 bounds: Mapping[str, tuple[float, float]], response: str = "repose_angle",
                 folds: int = 5, seed: int = 0, which: Sequence[str] = ("gp", "rsm", "bp")) -> pd.DataFrame:
    """RMSE over held-out piles, sqrt(mean (y - yhat)^2), of the GP and of fit-surrogate's RSM and BP
    network, by ``folds``-fold cross-validation over the design points: each fold holds out a
    1/folds share of them with all their piles (a new parameter set is what a calibration asks for),
    and every surrogate is trained on the other piles. One 20 % split held out 7 of hidden-effect's
    35 points, and which surrogate won changed with the seed. A surrogate that cannot be fitted on a
    fold (an RSM whose design matrix the fold leaves singular) is scored on the piles it predicted
    (``piles``). A pile's own scatter (the GP's ``noise_sd``) is the floor no surrogate goes below. The GP
    learns from the heaps' side views' means where they have them (:func:`views_of`); every surrogate is
    scored on the held-out piles' one view, as a photograph."""
    from threadpoolctl import threadpool_limits

    from ..surrogate.models import _torch

    # one thread, torch's own pool too: the networks are tiny, and on a busy two-core machine a BP fit
    # took 3.9 s with two threads and 0.1 s with one (see GPSurrogate.fit)
    torch = _torch()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with threadpool_limits(1):
            return _cross_validate(rows, parameters, conditions, bounds, response, folds, seed, tuple(which))
    finally:
        torch.set_num_threads(threads)


def _cross_validate(rows, parameters, conditions, bounds, response, folds, seed, which) -> pd.DataFrame:
    from ..surrogate.models import BPNetwork, RSMSurrogate

    rows = rows[np.isfinite(rows[response].to_numpy(float))].reset_index(drop=True)
    pts = design_points(rows, parameters)
    fold = np.random.default_rng(seed).permutation(pts.max() + 1) % max(2, int(folds))
    y = rows[response].to_numpy(float)
    views = views_of(rows, response)
    preds = {k: np.full(len(y), np.nan) for k in which}
    noise = []
    for k in range(fold.max() + 1):
        test = fold[pts] == k
        gp = GPSurrogate(parameters, conditions, bounds, seed=seed).fit(
            rows[~test], y[~test], None if views is None else views[~test])
        noise.append(gp.noise_sd_)
        preds["gp"][test] = gp.predict(rows[test])
        X = rows[gp.inputs_].to_numpy(float)
        for name, model in (("rsm", RSMSurrogate(gp.inputs_)), ("bp", BPNetwork(gp.inputs_, seed=seed))):
            if name not in which:
                continue
            try:
                preds[name][test] = model.fit(X[~test], y[~test]).predict(X[test])
            except CalibError:  # a design matrix the fold leaves singular: scored on the other folds' piles
                pass
    return pd.DataFrame([{"surrogate": k, "rmse": float(np.sqrt(np.nanmean((p - y) ** 2))) if np.isfinite(p).any()
                          else np.nan, "noise_sd": float(np.mean(noise)), "piles": int(np.isfinite(p).sum()),
                          "design_points": int(pts.max() + 1), "folds": int(fold.max() + 1)}
                         for k, p in preds.items()])


class ColumnModel:
    """The chance that a fill stands as a column instead of forming a heap, over the same scaled inputs as
    the angle's surrogate ``gp``: a Gaussian-process classifier (scikit-learn's, Laplace's approximation,
    Matern 3/2 with one length scale per input) trained on every heap of the model that either stood
    or formed. Learned: ``clf_``, ``n_train_``, ``n_columns_``."""

    def __init__(self, gp: GPSurrogate, seed: int = 0):
        self.inputs_, self.lows_, self.highs_ = gp.inputs_, gp.lows_, gp.highs_
        self.parameters, self.seed = gp.parameters, seed

    def fit(self, rows: pd.DataFrame, stands) -> "ColumnModel":
        from sklearn.exceptions import ConvergenceWarning
        from sklearn.gaussian_process import GaussianProcessClassifier
        from sklearn.gaussian_process.kernels import ConstantKernel, Matern
        from threadpoolctl import threadpool_limits

        y = np.asarray(stands, bool)
        if y.all() or not y.any():
            raise CalibError("the heaps all stood as columns, or none did: nothing to learn the chance from")
        X = (rows[self.inputs_].to_numpy(float) - self.lows_) / (self.highs_ - self.lows_)
        kernel = ConstantKernel(1.0, (1e-2, 1e2)) * Matern(np.full(len(self.inputs_), 0.5), LENGTH_BOUNDS, nu=NU)
        with warnings.catch_warnings(), threadpool_limits(1, user_api="blas"):
            warnings.simplefilter("ignore", ConvergenceWarning)
            self.clf_ = GaussianProcessClassifier(kernel, n_restarts_optimizer=1, random_state=self.seed).fit(X, y)
        self.n_train_, self.n_columns_ = len(y), int(y.sum())
        return self

    def probability(self, X: np.ndarray) -> np.ndarray:
        """P(column) at X (n, inputs in ``inputs_`` order), clipped to [1e-4, 1 - 1e-4]."""
        Xs = (np.atleast_2d(np.asarray(X, float)) - self.lows_) / (self.highs_ - self.lows_)
        return np.clip(self.clf_.predict_proba(Xs)[:, 1], 1e-4, 1 - 1e-4)
