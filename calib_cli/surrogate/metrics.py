"""Accuracy metrics of the paper (Eqs. 8-10) and held-out evaluation."""

from __future__ import annotations

from typing import Callable

import numpy as np

from .interface import Surrogate


def r2(y, yhat) -> float:
    """Eq. 8: 1 - sum (y - yhat)^2 / sum (y - ybar)^2."""
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    return float(1 - np.sum((y - yhat) ** 2) / np.sum((y - y.mean()) ** 2))


def mse(y, yhat) -> float:
    """Eq. 9."""
    return float(np.mean((np.asarray(y, float) - np.asarray(yhat, float)) ** 2))


def aad(y, yhat) -> float:
    """Eq. 10: mean absolute deviation."""
    return float(np.mean(np.abs(np.asarray(y, float) - np.asarray(yhat, float))))


def scores(y, yhat) -> dict:
    return {"r2": r2(y, yhat), "mse": mse(y, yhat), "aad": aad(y, yhat)}


def split_80_20(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A seeded random 80/20 split (the paper's), test set at least one sample."""
    idx = np.random.default_rng(seed).permutation(n)
    n_test = max(1, int(round(0.2 * n)))
    return np.sort(idx[n_test:]), np.sort(idx[:n_test])


def leave_one_out(make: Callable[[], Surrogate], X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Predictions of each sample by a model fitted without it."""
    out = np.empty(len(y))
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        out[i] = make().fit(X[keep], y[keep]).predict(X[i:i + 1])[0]
    return out
