"""Where ``calib calibrate`` simulates next, and when it stops (docs/method.md, "Calibrating in rounds").

A design is a list of *pairs*: a parameter point theta and one measured condition, each simulated
``repeats`` times (the groups of repeated piles are what the scatter's model learns from).

Round 0 is space-filling over the model's parameters (their prior box) and the measured conditions:
a Latin hypercube over d + 1 dimensions optimised for centred discrepancy (scipy's
``qmc.LatinHypercube(optimization="random-cd")``), its last dimension picking the condition, so the
conditions share the points evenly and every theta is new.

Later rounds choose pairs among the current posterior's draws crossed with the measured conditions,
by one of three rules (:data:`RULES`):

- ``variance`` (the default): greedily, the pair that most lowers the surrogates' variance summed over
  the posterior's draws and the conditions, each term over the measured mean's variance v_c (the
  integrated variance reduction of Sacks et al. 1989, weighted by the posterior). One more pair x with
  pile variance tau^2(x) / repeats lowers the latent variance at e by P(e, x)^2 / (P(x, x) + tau^2 / r),
  P the GP's posterior covariance, which is then updated as a rank-one downdate before the next pick
  (the variance does not depend on the angles yet to come, so a whole batch is chosen before it runs);
- ``max-sd``: greedily, the pair whose own variance over v_c is largest (uncertainty sampling);
- ``draws``: posterior draws at random, the conditions in turn.

The stop rule: every parameter's 90 % interval moved by less than :data:`STABLE` of its prior range
since the round a default batch of heaps before (:func:`reference_round`: the previous one at the
default batch), no effect's verdict changed, and the surrogates are sure enough for a verdict; else the
budget.
"""

from __future__ import annotations

from typing import Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from ..errors import CalibError
from .calibrate import _inputs

RULES = ("variance", "max-sd", "draws")
#: an interval is stable when neither end moved by more than this share of the prior range in a round
STABLE = 0.05
#: the posterior points (times the conditions) the acquisition evaluates and chooses among, at most
EVAL_POINTS, CANDIDATE_POINTS = 1024, 512


def first_design(bounds: Mapping[str, tuple[float, float]], conditions: Sequence[str], pairs: int,
                 seed: int = 0) -> pd.DataFrame:
    """Round 0: ``pairs`` (theta, condition) pairs, space-filling over the prior box and the conditions."""
    from scipy.stats import qmc

    if pairs < 2:
        raise CalibError(f"a first design needs at least 2 points, got {pairs}")
    names = list(bounds)
    lo, hi = np.array([bounds[p][0] for p in names]), np.array([bounds[p][1] for p in names])
    u = qmc.LatinHypercube(d=len(names) + 1, optimization="random-cd", seed=seed).random(pairs)
    which = np.minimum((u[:, -1] * len(conditions)).astype(int), len(conditions) - 1)
    x = lo + u[:, :-1] * (hi - lo)
    return pd.DataFrame({**{p: x[:, k] for k, p in enumerate(names)},
                         "condition_id": np.asarray(conditions, dtype=object)[which]})


def _points(gp, theta: np.ndarray, names: list[str], measured: pd.DataFrame) -> np.ndarray:
    """(len(theta) * C, inputs): each theta under every measured condition, the conditions fastest."""
    conds = {c: measured[c].to_numpy(float) for c in gp.inputs_ if c not in names}
    return _inputs(gp, theta, names, {}, conds, len(measured)).reshape(-1, len(gp.inputs_))


def _greedy(P: list[np.ndarray], w: list[np.ndarray], tau2: list[np.ndarray], n_eval: int, picks: int,
            integrated: bool) -> list[int]:
    """Candidate indices chosen one at a time, each response's covariance P (eval rows first, then the
    candidates) downdated after each pick. ``integrated``: score the weighted variance removed at the
    evaluation points; else the candidate's own weighted variance."""
    chosen: list[int] = []
    n_cand = P[0].shape[0] - n_eval
    for _ in range(min(picks, n_cand)):
        score = np.zeros(n_cand)
        for Pj, wj, tj in zip(P, w, tau2):
            diag = np.diag(Pj)[n_eval:]
            if integrated:
                score += (wj[:n_eval, None] * Pj[:n_eval, n_eval:] ** 2).sum(axis=0) / (diag + tj)
            else:
                score += wj[n_eval:] * diag
        score[chosen] = -np.inf
        x = int(np.argmax(score))
        chosen.append(x)
        for j, Pj in enumerate(P):
            col = Pj[:, n_eval + x].copy()
            P[j] = Pj - np.outer(col, col) / (col[n_eval + x] + tau2[j][x])
    return chosen


def acquire(surrogates: Sequence[tuple[object, np.ndarray]], samples: pd.DataFrame, measured: pd.DataFrame,
            pairs: int, repeats: int = 2, rule: str = "variance", seed: int = 0) -> pd.DataFrame:
    """The next round's ``pairs`` among the posterior's draws (``samples``, one column per parameter)
    crossed with the measured conditions, by ``rule`` (:data:`RULES`). ``surrogates``: each response's
    Gaussian process with its measured means' variances v (C,), the scale its variance is weighed on."""
    if rule not in RULES:
        raise CalibError(f"--rule must be one of {', '.join(RULES)}, got {rule!r}")
    names = [p for p in samples.columns if p in surrogates[0][0].parameters]
    C, rng = len(measured), np.random.default_rng(seed)
    draws = samples[names].to_numpy(float)
    n_eval = max(2, min(len(draws), EVAL_POINTS // C))
    n_cand = max(2, min(n_eval, CANDIDATE_POINTS // C))
    theta = draws[rng.choice(len(draws), n_eval, replace=len(draws) < n_eval)]
    # a chain's draws repeat (a rejected move): a pair picked twice would be one cached heap, paid for twice
    again = _repeated(theta[:n_cand])
    if rule == "draws":
        pick = rng.permutation(n_cand)
        pick = pick[~again[pick]][:pairs] if pairs <= (~again).sum() else rng.choice(n_cand, pairs)
        cond = (np.arange(len(pick)) + rng.integers(C)) % C
        return _frame(theta[pick], names, measured, cond)
    twin = np.repeat(again, C)
    pairs = min(pairs, int((~twin).sum()))  # never a twin, even where the distinct pairs run out
    P, w, tau2 = [], [], []
    for gp, v in surrogates:
        XE, XC = _points(gp, theta, names, measured), _points(gp, theta[:n_cand], names, measured)
        P.append(gp.latent_cov(np.vstack([XE, XC])))
        iv = 1.0 / np.maximum(v, 1e-12)
        w.append(np.r_[np.tile(iv, n_eval) / (n_eval * C), np.where(twin, 0.0, np.tile(iv, n_cand))])
        # what a heap teaches: its views' mean where fitted so; a twin's infinite noise teaches nothing
        tau2.append(np.where(twin, np.inf, gp.heap_sd(XC) ** 2 / repeats))
    chosen = _greedy(P, w, tau2, n_eval * C, pairs, integrated=rule == "variance")
    idx = np.array(chosen)
    return _frame(theta[:n_cand][idx // C], names, measured, idx % C)


def _repeated(theta: np.ndarray) -> np.ndarray:
    """Per row, whether an earlier row is the same point."""
    later = np.ones(len(theta), bool)
    later[np.unique(theta, axis=0, return_index=True)[1]] = False
    return later


def _frame(theta: np.ndarray, names: list[str], measured: pd.DataFrame, cond: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({**{p: theta[:, k] for k, p in enumerate(names)},
                         "condition_id": measured["condition_id"].astype(str).to_numpy()[cond]})


def interval_shift(prev: pd.DataFrame, cur: pd.DataFrame) -> float:
    """The largest move of any parameter's interval end (q05, q95) between two rounds' summaries, as a
    share of its prior range."""
    a, b = prev.set_index("parameter"), cur.set_index("parameter")
    span = (b["high"] - b["low"]).to_numpy(float)
    moves = [np.abs(b[q].to_numpy(float) - a.loc[b.index, q].to_numpy(float)) / span for q in ("q05", "q95")]
    return float(np.max(moves))


def reference_round(spent: Sequence[int], now: int, span: int) -> Optional[int]:
    """The index into the finished rounds (``spent``: the heaps simulated up to each) of the latest one at
    least ``span`` heaps before ``now``, which the stop rule compares with; None if none is. With ``span``
    the default batch that is the previous round; with rounds half as large, two back: a small round
    moves the intervals less, and "stable" should not mean less for it (half-size rounds stopped 17 %
    sooner on benchmarks/acquisition_rules.py's stand-in when compared round by round)."""
    for k in range(len(spent) - 1, -1, -1):
        if now - spent[k] >= span:
            return k
    return None


def stop_reason(prev: pd.DataFrame | None, cur: pd.DataFrame, verdicts_prev: Sequence[str],
                verdicts_cur: Sequence[str], decided: bool, since: str = "the previous round") -> str:
    """Why the rounds stop here by the rule ("" to go on): every interval and verdict stable since
    ``prev`` (the round ``since`` names), and the surrogates sure enough for a verdict."""
    if prev is None or not decided:
        return ""
    shift = interval_shift(prev, cur)
    if shift >= STABLE or list(verdicts_prev) != list(verdicts_cur):
        return ""
    return (f"stable: no interval end moved by {100 * STABLE:.0f} % of its range since {since} "
            f"(at most {100 * shift:.1f} %), no verdict changed, and the surrogates are sure enough for one")
