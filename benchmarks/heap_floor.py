"""How many heaps would the "surrogate sure enough" bar need if every heap sat where the posterior lies? (issue 47:
the strict budget of 250 heaps.) For a committed sample run's answer, per measured condition c:

    n_c = mean over the posterior's draws theta of  sigma^2(theta, c) / v_c

sigma^2 the simulated piles' variance there (the angle's Gaussian process, its scatter model included), v_c the
measured mean's variance as the likelihood takes it. n_c piles at one point bring the surrogate's variance of
that mean to about sigma^2 / n_c = v_c, the bar (ratio 1) for the angle alone, with nothing shared between
conditions or parameter points. The sum over the conditions is the heaps a perfectly placed design would need;
beside it, the model's heaps in the prior's box now (the answer's and any simulated since, e.g. compare's) and
the surrogate's variance at the draws when it learns from all of them.

``placed``: the same bar with what one condition's heaps teach the others and the neighbouring parameter points
counted, by the answer's own angle surrogate (its length scales and scatter, as fitted on every heap) and its
draws, both known before the first heap: pairs of piles are placed one at a time by the variance rule of `calib
calibrate` for the angle alone (the pair that most lowers the angle surrogate's variance over the draws and
conditions, each over v_c; the stage also weighs the profile's), a pair free to go where one went before, from
the heaps at hand when the calibration of the model's revision began (``at hand``), from those and its round 0's
space-filling heaps (``round 0``), or from none. It prints the heaps at which the angle's ratio first reaches 1:
what an oracle of the posterior and the length scales would spend. Then the same for the bar as the stage reads
it: the angle's and the profile's processes (the fullness's fitted on every heap too), pairs weighed as the stage
weighs them, until the combined ratio reaches 1; and from the heaps at hand plus a space-filling round 0 of 24,
48 or 72 piles designed as the stage designs one. ``refits``: per round, whether its length scales made it less
sure than its heaps allow.

    .venv/bin/python benchmarks/heap_floor.py sample_runs/hidden-effect sample_runs/control-lab

``--warps sqrt,cbrt``: instead, per round, the angle's, the profile's and the combined ratio at the answer's draws,
each process fitted on the round's heaps with surface energy as it is and through each warp (the input, its
prior range and the draws mapped by it before scaling to [0, 1]): whether a surrogate that stretches the low
surface energies, where the angle climbs fastest, is sure sooner (docs/method.md, "Calibrating in rounds").

    .venv/bin/python benchmarks/heap_floor.py --warps sqrt,cbrt sample_runs/hidden-effect sample_runs/control-lab

``--trend``: the same table as ``--warps`` with a linear trend in both processes' latent kernel (s^2 Matern +
c^2 (sigma_0^2 + x.x'), the trend's coefficients' uncertainty carried): whether a process that knows the responses
rise near linearly over the factor table learns more per heap.

    .venv/bin/python benchmarks/heap_floor.py --trend sample_runs/hidden-effect sample_runs/control-lab

``--views``: the same table as ``--warps`` with both processes learning from one side view a heap (view 0, as
every heap did before 2026-12-06) and from each heap's mean over its 4 side views (the results rows' ``angle_views``
and ``fullness_views``): on one run's own heaps, what the views change, apart from where its rounds placed them.

    .venv/bin/python benchmarks/heap_floor.py --views sample_runs/hidden-effect sample_runs/control-lab

``--noise 0.6,0.7/0.5``: what heaps that each scatter less would do (e.g. measured from several side views,
``benchmarks/heap_views.py``): every simulated pile's variance scaled by each factor f (``a/p``: the angle's by a,
the fullness's by p), the lab's measured means as they are. Per round, the angle's, the profile's and the
combined ratio at the answer's draws from the answer's processes conditioned on the round's heaps (their length
scales and signal kept); then the oracle's heaps to a combined ratio of 1 from the heaps at hand plus the default
round 0 of 72.

    .venv/bin/python benchmarks/heap_floor.py --noise 0.7/0.5,0.6 sample_runs/hidden-effect sample_runs/control-lab
"""
from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import NamedTuple

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd


STARTS = ("at hand", "round 0", "none")
ROUND0 = (24, 48, 72)  # space-filling first rounds of the stage's design, the oracle placing after them


class Answer(NamedTuple):
    """A committed run's answer as the three tables read it."""
    run: Path
    model: object
    conds: pd.DataFrame  # the measured conditions
    rows: pd.DataFrame  # the model's heaps in the prior's box with an angle
    bounds: dict  # the prior's box
    gp: object  # the answer's angle process, fitted on every one of ``rows``
    hand: pd.Series  # which rows were at hand when the calibration began
    own: pd.Series  # which rows the calibration simulated itself
    samples: pd.DataFrame  # the answer's draws


def _answer(run: Path, views: bool = False) -> Answer:
    from calib_cli.measurements import measured_conditions
    from calib_cli.model import load_model
    from calib_cli.posterior.evidence import in_box, model_rows, model_surrogate, prior_bounds, settings_ranges
    from calib_cli.stages.common import resolve_settings

    model, conds = load_model(run), measured_conditions(run)
    rows = model_rows(run, model, views=views)
    bounds = prior_bounds(model, "settings", rows, settings_ranges(resolve_settings(run, None, None)))
    rows = in_box(rows, bounds)
    rows = rows[np.isfinite(rows["repose_angle"].to_numpy(float))].reset_index(drop=True)
    hand = set(pd.read_parquet(run / f"calibrate/rev{model.revision}/round-00/reused.parquet")["run_hash"])
    own = (rows["design"] == "calibrate") & (rows["model"] == model.hash)
    return Answer(run, model, conds, rows, bounds, model_surrogate(rows, model, 0, scale=bounds),
                  rows["run_hash"].isin(hand), own, pd.read_parquet(run / "posterior/samples.parquet"))


def _draws(answer: Answer, draws: int) -> np.ndarray:
    """``draws`` of the answer's posterior draws (its parameters' columns), the same ones for every table that
    reads them at the answer."""
    s = answer.samples
    return s[answer.gp.parameters].to_numpy(float)[np.random.default_rng(1).choice(len(s), draws, replace=False)]


def _round_heaps(rows: pd.DataFrame, hand: pd.Series, own: pd.Series, k: int) -> pd.DataFrame:
    """The heaps round ``k`` of the calibration learnt from: those at hand when it began, and its rounds' up to k."""
    return rows[hand | (own & (rows["run_id"] < 1000 * (k + 2)))]


def _combined(ratios) -> float:
    """The combined ratio the bar reads, from each response's: 1 / (1 + r) = the mean of 1 / (1 + r_j)."""
    return 1.0 / float(np.mean([1.0 / (1.0 + x) for x in ratios])) - 1.0


def _given(gp, S: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """The latent covariance (standardised units) at the scaled points Z given piles at the scaled points S, with
    ``gp``'s length scales, signal and scatter."""
    if not len(S):
        return gp.latent_(Z)
    L = np.linalg.cholesky(gp.latent_(S) + np.diag(gp.heap_sd(S, scaled=True) ** 2 / gp.y_sd_ ** 2))
    A = np.linalg.solve(L, gp.latent_(S, Z))
    return gp.latent_(Z) - A.T @ A


def floor(answer: Answer, draws: int = 256) -> tuple[pd.DataFrame, int]:
    """The per-condition table of the module's docstring and the model's heaps in the prior's box."""
    from calib_cli.posterior.adaptive import _points

    conds, gp, s = answer.conds, answer.gp, answer.samples
    t = s[gp.parameters].to_numpy(float)[np.random.default_rng(0).choice(len(s), min(draws, len(s)), replace=False)]
    C = len(conds)
    X = _points(gp, t, gp.parameters, conds)
    pile = gp.pile_sd(X).reshape(len(t), C) ** 2
    latent = gp.predict(X, return_std=True)[1].reshape(len(t), C) ** 2
    v = mean_variance_of(answer)
    return pd.DataFrame({"condition": conds["condition_id"], "lab sd": conds["sd"].round(2), "piles": conds["n"],
                         "v_c": v.round(2), "pile variance": pile.mean(0).round(1),
                         "surrogate variance now": latent.mean(0).round(2),
                         "n_c": (pile / v[None, :]).mean(0).round(1)}), len(answer.rows)


class Profile(NamedTuple):
    """The answer's fullness as the oracle and the stand-in read it."""
    gp: object  # its process, fitted on every heap of the answer's rows with a fullness
    v: np.ndarray  # the measured fullness means' variances
    has: pd.Series  # which of the answer's rows have a fullness
    rho: float  # the lab's correlation of a photograph's fullness with its angle


def _profile(answer: Answer) -> Profile:
    """The answer's fullness (:class:`Profile`), its process fitted as the answer's angle process is."""
    from calib_cli.posterior.calibrate import mean_variance
    from calib_cli.posterior.evidence import model_surrogate
    from calib_cli.posterior.profiles import FULLNESS, measured_fullness

    has = pd.Series(np.isfinite(answer.rows[FULLNESS].to_numpy(float)), index=answer.rows.index)
    gp = model_surrogate(answer.rows[has], answer.model, 0, FULLNESS, answer.bounds)
    table, rho = measured_fullness(answer.run, answer.conds)
    return Profile(gp, mean_variance(table["sd"], table["n"], gp.noise_sd_), has, rho)


def first_round(answer: Answer, heaps: int, repeats: int = 2, seed: int = 0) -> pd.DataFrame:
    """A space-filling round 0 of ``heaps`` piles as the stage designs one (``adaptive.first_design``: pairs
    of ``repeats`` piles over the prior's box and the measured conditions), as rows of the surrogates' inputs."""
    from calib_cli.posterior.adaptive import first_design

    design = first_design(answer.bounds, answer.conds["condition_id"].astype(str).tolist(), heaps // repeats, seed)
    rows = design.merge(answer.conds.assign(condition_id=answer.conds["condition_id"].astype(str)), on="condition_id")
    return rows.loc[rows.index.repeat(repeats)].reset_index(drop=True)


def placed(answer: Answer, start_from: str, profile: Profile | None = None, first: int = 0, repeats: int = 2,
           draws: int = 170, candidates: int = 85, most: int = 400) -> tuple[int, list[tuple[int, float]]]:
    """The angle's ratio as oracle-placed pairs of ``repeats`` piles are added (see the module's docstring), from
    the heaps at hand when the calibration began, those and its round 0's, or none (:data:`STARTS`): the heaps it
    starts from and (heaps, ratio) after each pair, until the ratio is at most 1 or ``most`` heaps. ``profile``
    (:func:`_profile`): the fullness's process beside the angle's, both weighed by the variance rule as the stage weighs them, and
    the ratio the combined one the bar reads (1 / (1 + r) = the mean of 1 / (1 + r_j)). ``first``: a
    space-filling round 0 of this many piles (:func:`first_round`) added to the start."""
    from calib_cli.posterior.adaptive import _greedy, _points

    conds, rows, gp, hand, own = answer.conds, answer.rows, answer.gp, answer.hand, answer.own
    pick = {"at hand": hand, "round 0": hand | (own & (rows["run_id"] < 2000)),
            "none": pd.Series(False, index=rows.index)}[start_from]
    t = _draws(answer, draws)
    C, X = len(conds), _points(gp, t, gp.parameters, conds)
    n = len(X)
    pairs = [(gp, mean_variance_of(answer), pick)]
    if profile is not None:
        pairs.append((profile.gp, profile.v, pick & profile.has))
    extra = first_round(answer, first, repeats) if first else rows.iloc[:0]
    P, w, tau2, vs = [], [], [], []
    for g, v, start in pairs:
        Z = g._scale(np.vstack([X, X[:candidates * C]]))  # the evaluation points, then the candidates among them
        S = pd.concat([rows.loc[start, g.inputs_], extra[g.inputs_]], ignore_index=True)
        P.append(g.y_sd_ ** 2 * _given(g, g._scale(S), Z))
        w.append(np.r_[np.tile(1 / v, draws) / n, np.tile(1 / v, candidates)])
        tau2.append(g.heap_sd(Z[n:], scaled=True) ** 2 / repeats)
        vs.append(v)

    def ratio() -> float:
        r = [float(np.mean(np.diag(Pj)[:n].reshape(draws, C) / v)) for Pj, v in zip(P, vs)]
        return _combined(r)
    heaps = int(pick.sum()) + len(extra)
    path = [(heaps, ratio())]
    while path[-1][1] > 1.0 and heaps < most:
        _greedy(P, w, tau2, n, 1, integrated=True)  # one pick, P downdated in place
        heaps += repeats
        path.append((heaps, ratio()))
    return int(pick.sum()) + len(extra), path


def refits(answer: Answer, draws: int = 400) -> pd.DataFrame:
    """Per round of the model's calibration, its heaps (those at hand and its rounds' up to it) and the angle's
    ratio at the answer's draws from a process fitted on them alone (``own fit``) and from the answer's process
    (its length scales, signal and scatter, learnt from every heap) conditioned on the same heaps (``answer's
    fit``): where the two agree, a round's heaps, not its length scales, set how sure it is."""
    from calib_cli.posterior.adaptive import _points
    from calib_cli.posterior.evidence import model_surrogate

    _, model, conds, rows, bounds, final, hand, own, _ = answer
    t = _draws(answer, draws)
    X = _points(final, t, final.parameters, conds)
    v = mean_variance_of(answer)
    out = []
    for k in range(int(rows.loc[own, "run_id"].max()) // 1000):
        sub = _round_heaps(rows, hand, own, k)
        mine = model_surrogate(sub, model, 0, scale=bounds)
        var = final.y_sd_ ** 2 * np.diag(_given(final, final._scale(sub), final._scale(X)))
        out.append({"round": k, "heaps": len(sub),
                    "own fit": float(np.mean(mine.predict(pd.DataFrame(X, columns=final.inputs_), return_std=True)[1]
                                             .reshape(len(t), -1) ** 2 / v)),
                    "answer's fit": float(np.mean(var.reshape(len(t), -1) / v))})
    return pd.DataFrame(out).round(2)


WARPS = {"none": lambda x: x, "sqrt": np.sqrt, "cbrt": np.cbrt}


def warped_refits(answer: Answer, warp: str, draws: int = 400) -> pd.DataFrame:
    """Per round (as :func:`refits`), the angle's, the profile's and the combined ratio (1 / (1 + r) = the mean of
    1 / (1 + r_j)) at the answer's draws, both processes fitted on the round's heaps with surface energy mapped by
    ``warp`` (:data:`WARPS`), its prior range and the draws with it."""
    from calib_cli.posterior.adaptive import _points
    from calib_cli.posterior.calibrate import mean_variance
    from calib_cli.posterior.evidence import model_surrogate
    from calib_cli.posterior.profiles import FULLNESS, measured_fullness

    _, model, conds, rows, bounds, final, hand, own, _ = answer
    f, p = WARPS[warp], "surface_energy"
    rows = rows.assign(**{p: f(rows[p].clip(lower=0.0).to_numpy(float))})
    bounds = {**bounds, p: tuple(float(f(np.float64(max(b, 0.0)))) for b in bounds[p])}
    t = _draws(answer, draws)
    j = final.parameters.index(p)
    t[:, j] = f(np.clip(t[:, j], 0.0, None))
    table, _ = measured_fullness(answer.run, conds)
    out = []
    for k in range(int(rows.loc[own, "run_id"].max()) // 1000):
        sub = _round_heaps(rows, hand, own, k)
        ratio = {}
        for name, response, measured in (("angle", "repose_angle", conds), ("profile", FULLNESS, table)):
            have = sub[np.isfinite(sub[response].to_numpy(float))]
            gp = model_surrogate(have, model, 0, response=response, scale=bounds)
            X = pd.DataFrame(_points(gp, t, gp.parameters, conds), columns=gp.inputs_)
            v = mean_variance(measured["sd"], measured["n"], gp.noise_sd_)
            ratio[name] = float(np.mean(gp.predict(X, return_std=True)[1].reshape(len(t), -1) ** 2 / v))
        out.append({"warp": warp, "round": k, "heaps": len(sub), **ratio, "combined": _combined(ratio.values())})
    return pd.DataFrame(out).round(2)


def _trend_surrogate():
    """The library's Gaussian process with a linear trend added to its latent kernel (``--trend``)."""
    import warnings

    from sklearn.base import clone
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process.kernels import ConstantKernel, DotProduct
    from threadpoolctl import threadpool_limits

    from calib_cli.posterior.gp import GPSurrogate

    class TrendGP(GPSurrogate):
        def fit(self, X, y, views=None):
            super().fit(X, y, views)  # inputs, scaling, scatter and the plain fit, then refitted with the trend
            k0 = self.gp_.kernel
            kernel = (k0.k1 + ConstantKernel(0.1, (1e-4, 1e2)) * DotProduct(1.0, (1e-2, 1e2))) + k0.k2
            with warnings.catch_warnings(), threadpool_limits(1, user_api="blas"):
                warnings.simplefilter("ignore", ConvergenceWarning)
                self.gp_ = clone(self.gp_).set_params(kernel=kernel).fit(self.gp_.X_train_, self.gp_.y_train_)
            k = self.gp_.kernel_
            self.latent_, self.trend_ = k.k1, k.k1.k2
            self.white_sd_ = float(np.sqrt(k.k2.noise_level)) * self.y_sd_
            self.noise_sd_ = float(np.sqrt(np.mean(self.pile_sd(self.gp_.X_train_, scaled=True) ** 2)))
            return self

    return TrendGP


class _Quieter:
    """A fitted process whose piles scatter with ``f`` times its variance (the lab's means untouched)."""

    def __init__(self, gp, f: float):
        self._gp, self._f = gp, float(f)

    def __getattr__(self, name):
        return getattr(self._gp, name)

    def heap_sd(self, X, scaled: bool = False) -> np.ndarray:
        return np.sqrt(self._f) * self._gp.heap_sd(X, scaled)


def quieter(answer: Answer, full: Profile, f: str, draws: int = 400) -> tuple[pd.DataFrame, int]:
    """Per round (as :func:`refits`), the angle's, the profile's and the combined ratio at the answer's draws from
    the answer's processes with every pile's variance scaled by ``f`` ("a" for both, "a/p" for the angle's and the
    fullness's) conditioned on the round's heaps; and the oracle's heaps to a combined ratio of 1 from the heaps
    at hand and the default round 0 (:func:`placed`). ``full``: the answer's fullness (:func:`_profile`)."""
    from calib_cli.posterior.adaptive import _points

    fa, fp = (float(x) for x in (f.split("/") * 2)[:2])
    quiet = answer._replace(gp=_Quieter(answer.gp, fa))
    prof = full._replace(gp=_Quieter(full.gp, fp))
    rows, hand, own = answer.rows, answer.hand, answer.own
    t = _draws(answer, draws)
    out = []
    for k in range(int(rows.loc[own, "run_id"].max()) // 1000):
        sub = _round_heaps(rows, hand, own, k)
        ratio = {}
        for name, g, v, have in (("angle", quiet.gp, mean_variance_of(answer), sub.index),
                                 ("profile", prof.gp, prof.v, sub.index[full.has[sub.index]])):
            X = _points(g, t, g.parameters, answer.conds)
            var = g.y_sd_ ** 2 * np.diag(_given(g, g._scale(rows.loc[have, g.inputs_]), g._scale(X)))
            ratio[name] = float(np.mean(var.reshape(len(t), -1) / v))
        out.append({"f": f, "round": k, "heaps": len(sub), **ratio, "combined": _combined(ratio.values())})
    _, path = placed(quiet, "at hand", prof, ROUND0[-1])
    return pd.DataFrame(out).round(2), path[-1][0]


def mean_variance_of(answer: Answer) -> np.ndarray:
    """The measured mean angles' variances v_c, as the likelihood takes them."""
    from calib_cli.posterior.calibrate import mean_variance

    return mean_variance(answer.conds["sd"], answer.conds["n"], answer.gp.noise_sd_)


def main() -> None:
    args = sys.argv[1:]
    if args[:1] == ["--trend"]:
        from calib_cli.posterior import evidence

        for run in map(Path, args[1:] or ["sample_runs/hidden-effect", "sample_runs/control-lab"]):
            answer = _answer(run)
            plain = warped_refits(answer, "none").assign(warp="matern")
            evidence.GPSurrogate, library = _trend_surrogate(), evidence.GPSurrogate
            try:
                trend = warped_refits(answer, "none").assign(warp="matern + linear")
                sub = _round_heaps(answer.rows, answer.hand, answer.own, 3)
                amp = evidence.model_surrogate(sub, answer.model, 0, scale=answer.bounds).trend_
            finally:
                evidence.GPSurrogate = library
            print(f"\n{run}: each round's ratios at the answer's draws, without and with a linear trend "
                  f"(the angle's trend after round 3: {amp})")
            print(pd.concat([plain, trend]).rename(columns={"warp": "kernel"}).to_string(index=False))
        return
    if args[:1] == ["--noise"]:
        factors, args = ["1", *args[1].split(",")], args[2:]
        for run in map(Path, args or ["sample_runs/hidden-effect", "sample_runs/control-lab"]):
            answer = _answer(run)
            full = _profile(answer)  # fitted once for every scaling
            tables, oracle = zip(*(quieter(answer, full, f) for f in factors))
            print(f"\n{run}: each round's ratios at the answer's draws, every pile's variance scaled by f")
            print(pd.concat(tables).to_string(index=False))
            print("the oracle's heaps to a combined ratio of 1 from those at hand and a round 0 of 72: "
                  + ", ".join(f"f = {f}: {h}" for f, h in zip(factors, oracle)))
        return
    if args[:1] == ["--views"]:
        from calib_cli.posterior.evidence import VIEW_COLUMNS

        for run in map(Path, args[1:] or ["sample_runs/hidden-effect", "sample_runs/control-lab"]):
            answer = _answer(run, views=True)
            one = answer._replace(rows=answer.rows.drop(columns=list(VIEW_COLUMNS), errors="ignore"))
            print(f"\n{run}: each round's ratios at the answer's draws, the processes learning from one view a heap "
                  "and from its side views' mean")
            print(pd.concat([warped_refits(one, "none").assign(warp="one view"),
                             warped_refits(answer, "none").assign(warp="views' mean")])
                  .rename(columns={"warp": "learnt from"}).to_string(index=False))
        return
    if args[:1] == ["--warps"]:
        warps, args = ["none", *args[1].split(",")], args[2:]
        for run in map(Path, args or ["sample_runs/hidden-effect", "sample_runs/control-lab"]):
            answer = _answer(run)
            print(f"\n{run}: each round's ratios at the answer's draws, surface energy warped")
            print(pd.concat([warped_refits(answer, w) for w in warps]).to_string(index=False))
        return
    for run in map(Path, args or ["sample_runs/hidden-effect", "sample_runs/control-lab"]):
        answer = _answer(run)  # one fit of the answer's process for the three tables
        table, learnt = floor(answer)
        print(f"\n{run}: {learnt} heaps of the model in the prior's box; n_c summed: {table['n_c'].sum():.0f}")
        print(table.to_string(index=False))
        full = _profile(answer)  # the fullness's process fitted once for the six oracles that read it
        for profile in (None, full):
            for start_from in STARTS:
                start, path = placed(answer, start_from, profile)
                both = profile is not None
                print(f"placed by an oracle, {'angle and profile (combined ratio)' if both else 'angle'}, from "
                      f"{start} heaps ({start_from}): ratio {path[0][1]:.3g} -> {path[-1][1]:.3g} at {path[-1][0]} "
                      f"heaps ({path[-1][0] - start} placed; " + ", ".join(f"{h}: {r:.2f}" for h, r in path[1::6]) + ")")
        for first in ROUND0:
            start, path = placed(answer, "at hand", full, first)
            print(f"placed by an oracle, angle and profile, after a space-filling round 0 of {first} beside the heaps "
                  f"at hand: ratio {path[0][1]:.3g} -> {path[-1][1]:.3g} at {path[-1][0]} heaps ({path[-1][0] - start} placed)")
        print("the angle's ratio at the answer's draws after each round, its own fit and the answer's:")
        print(refits(answer).to_string(index=False))


if __name__ == "__main__":
    main()
