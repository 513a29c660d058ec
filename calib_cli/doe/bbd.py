"""Box-Behnken design and the quadratic response surface (paper 3.3-3.4, Eq. 7, Table 8).

The full second-order model in coded units,

    y = b0 + sum_i b_i x_i + sum_{i<j} b_ij x_i x_j + sum_i b_ii x_i^2,

fitted by least squares, with the ANOVA of Table 8: partial sums of squares per
term, residual split into lack of fit and pure error (the centre replicates),
R2, adjusted R2, predicted R2 (PRESS) and adequate precision.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pandas as pd
from ..errors import CalibError
from ..space import ParameterSpace
from .linear import fit_linear


def design(space: ParameterSpace, center_points: int = 5, fixed: dict[str, float] | None = None) -> pd.DataFrame:
    """Box-Behnken design in natural units (3 factors, 5 centre points -> 17 runs)."""
    if len(space) < 3:
        raise CalibError(f"a Box-Behnken design needs at least 3 factors, got {len(space)}")
    import pyDOE3  # here, not at import: it costs every CLI command 0.6 s

    coded = pyDOE3.bbdesign(len(space), center=center_points)
    df = pd.DataFrame(space.to_natural(coded), columns=space.names)
    for name, v in (fixed or {}).items():
        df[name] = float(v)
    df.insert(0, "run_id", np.arange(1, len(df) + 1))
    return df


def quadratic_terms(names: list[str]) -> list[str]:
    return [*names, *(f"{a}:{b}" for a, b in combinations(names, 2)), *(f"{a}^2" for a in names)]


def quadratic_matrix(coded: np.ndarray) -> np.ndarray:
    """Columns x_i, x_i x_j (i<j), x_i^2 in the order of :func:`quadratic_terms`."""
    x = np.atleast_2d(np.asarray(coded, dtype=float))
    k = x.shape[1]
    cols = [x[:, i] for i in range(k)]
    cols += [x[:, i] * x[:, j] for i, j in combinations(range(k), 2)]
    cols += [x[:, i] ** 2 for i in range(k)]
    return np.column_stack(cols)


class QuadraticRSM:
    """The quadratic response surface over ``space`` (the factors and their coding) as an estimator:
    ``fit(X, y)`` and ``predict(X)`` with X the factors in natural units (a frame with the space's
    columns, or an (n, k) array in its order) and y the response.

    Learned attributes: ``terms_``, ``coef_`` (coded units, a Series indexed by term, ``Intercept``
    first), ``fit_`` (the :class:`LinearFit` with ``anova`` and ``stats``).
    """

    def __init__(self, space: ParameterSpace, lack_of_fit: bool = True, drop_degenerate: bool = False):
        self.space = space
        self.lack_of_fit = lack_of_fit
        self.drop_degenerate = drop_degenerate

    def fit(self, X, y) -> "QuadraticRSM":
        coded = self._coded(X)
        y = np.asarray(y, dtype=float)
        terms = quadratic_terms(self.space.names)
        if self.drop_degenerate:
            # an input seen at only two levels has x^2 = a + b x: its square term cannot be estimated
            two = {n for j, n in enumerate(self.space.names) if len(np.unique(np.round(coded[:, j], 9))) < 3}
            terms = [t for t in terms if not (t.endswith("^2") and t[:-2] in two)]
        self.terms_ = terms
        self.fit_ = fit_linear(y, self._matrix(coded), terms, points=coded, lack_of_fit=self.lack_of_fit)
        self.coef_ = self.fit_.coef
        return self

    def _coded(self, X) -> np.ndarray:
        if isinstance(X, pd.DataFrame):
            X = X[self.space.names].to_numpy(dtype=float)
        return self.space.to_coded(X)

    def _matrix(self, coded) -> np.ndarray:
        full = quadratic_terms(self.space.names)
        idx = [full.index(t) for t in self.terms_]
        return quadratic_matrix(coded)[:, idx]

    def predict(self, X) -> np.ndarray:
        """Predicted response at natural-unit points X."""
        return self.predict_coded(self._coded(X))

    def predict_coded(self, coded) -> np.ndarray:
        M = self._matrix(coded)
        c = self.coef_.to_numpy()
        return c[0] + M @ c[1:]

    @property
    def anova_(self) -> pd.DataFrame:
        return self.fit_.anova

    @property
    def stats_(self) -> dict:
        return self.fit_.stats

    def equation(self, digits: int = 4) -> str:
        """The fitted model written like the paper's Eq. 7 (coded units)."""
        short = all(f.symbol for f in self.space.factors)
        sym = {f.name: (f.symbol if short else f.name) for f in self.space.factors}
        join = "" if short else "*"

        def term_sym(t: str) -> str:
            if t.endswith("^2"):
                return f"{sym[t[:-2]]}^2"
            return join.join(sym[p] for p in t.split(":"))

        c = self.coef_
        s = f"Y = {c['Intercept']:.{digits}g}"
        for t in self.terms_:
            v = float(c[t])
            s += f" {'-' if v < 0 else '+'} {abs(v):.{digits}g}{'' if short else '*'}{term_sym(t)}"
        return s
