"""The one interface of the package's surrogates, scikit-learn's estimator shape: constructed with
its settings (and what names or codes its inputs), ``fit(X, y)`` learns from inputs X and responses
y and returns the surrogate, ``predict(X)`` gives the response at X; learned attributes end in ``_``.

Followed by :class:`~calib_cli.surrogate.models.RSMSurrogate`, :class:`~.models.BPNetwork`,
:class:`~.models.PSOBPNetwork`, :class:`~calib_cli.doe.bbd.QuadraticRSM` and
:class:`~calib_cli.posterior.gp.GPSurrogate` (structurally: none imports this module).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Surrogate(Protocol):
    def fit(self, X, y) -> "Surrogate": ...

    def predict(self, X) -> np.ndarray: ...
