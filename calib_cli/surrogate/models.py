"""RSM, BP network and PSO-BP network behind one estimator interface (paper 3.5.1-3.5.2; :mod:`.interface`).

``fit(X, y)`` / ``predict(X)`` with X in natural units, columns in ``inputs`` order; learned
attributes end in ``_``; ``to_state()`` / ``from_state()`` round-trip through JSON.

The BP network is one hidden tanh layer with a linear output; inputs and output are mapped
to [-1, 1] by their training min and max (MATLAB's mapminmax). It is trained full-batch by
L-BFGS (a quasi-Newton method, in the spirit of MATLAB's default Levenberg-Marquardt
``trainlm``) for at most ``epochs`` iterations or until the normalised training MSE reaches
``goal``. BP starts from one uniform draw in [-2, 2]; PSO-BP starts from the best of a
particle swarm over the same box (paper: swarm 10, 30 iterations, velocities [-0.5, 0.5],
inertia 0.6, c1 = c2 = 2), whose fitness is the training MSE of the untrained network.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd

from ..doe.bbd import QuadraticRSM
from ..errors import CalibError
from ..space import ParameterSpace
from .pso import pso_minimize

MODEL_NAMES = ("rsm", "bp", "pso-bp")


class RSMSurrogate:
    """The quadratic response surface (coded by the training data's min and max)."""

    name = "rsm"

    def __init__(self, inputs: Sequence[str]):
        self.inputs = list(inputs)

    def fit(self, X, y) -> "RSMSurrogate":
        X = pd.DataFrame(np.asarray(X, float), columns=self.inputs)
        space = ParameterSpace.from_data(X, self.inputs)
        self.rsm_ = QuadraticRSM(space, lack_of_fit=False, drop_degenerate=True).fit(X, y)
        self.coef_ = self.rsm_.coef_
        return self

    def predict(self, X) -> np.ndarray:
        return self.rsm_.predict(np.atleast_2d(np.asarray(X, float)))

    def to_state(self) -> dict:
        return {"kind": "rsm", "inputs": self.inputs, "space": self.rsm_.space.to_dicts(),
                "terms": self.rsm_.terms_, "coef": self.coef_.tolist()}

    @classmethod
    def from_state(cls, st: dict) -> "RSMSurrogate":
        m = cls(st["inputs"])
        r = QuadraticRSM(ParameterSpace.from_dicts(st["space"]), lack_of_fit=False)
        r.terms_ = st["terms"]
        r.coef_ = pd.Series(st["coef"], index=["Intercept", *st["terms"]])
        m.rsm_, m.coef_ = r, r.coef_
        return m


def _torch():
    import torch  # here, not at import: it costs every CLI command a second

    return torch


class BPNetwork:
    """One-hidden-layer back-propagation network (torch, float64, deterministic per seed)."""

    name = "bp"

    def __init__(self, inputs: Sequence[str], hidden: int = 8, epochs: int = 100, goal: float = 1e-5,
                 seed: int = 0):
        self.inputs = list(inputs)
        self.hidden, self.epochs, self.goal, self.seed = int(hidden), int(epochs), float(goal), int(seed)

    # parameters packed in one vector: W1 (h x k), b1 (h), W2 (h), b2 (1)
    def _dim(self, k: int) -> int:
        return self.hidden * k + 2 * self.hidden + 1

    def _forward(self, theta, Xn):
        torch = _torch()
        k, h = Xn.shape[1], self.hidden
        W1 = theta[: h * k].reshape(h, k)
        b1 = theta[h * k: h * k + h]
        W2 = theta[h * k + h: h * k + 2 * h]
        b2 = theta[-1]
        return torch.tanh(Xn @ W1.T + b1) @ W2 + b2

    def _norm_x(self, X):
        return 2 * (np.asarray(X, float) - self.x_lo_) / (self.x_hi_ - self.x_lo_) - 1

    def _loss_np(self, theta: np.ndarray, Xn, yn) -> float:
        torch = _torch()
        with torch.no_grad():
            return float(torch.mean((self._forward(torch.as_tensor(theta), Xn) - yn) ** 2))

    def _initial(self, Xn, yn) -> np.ndarray:
        return np.random.default_rng(self.seed).uniform(-2, 2, self._dim(Xn.shape[1]))

    def fit(self, X, y) -> "BPNetwork":
        torch = _torch()
        X = np.atleast_2d(np.asarray(X, float))
        y = np.asarray(y, float)
        if len(y) < 3:
            raise CalibError("a network needs at least 3 samples")
        self.x_lo_, self.x_hi_ = X.min(0), X.max(0)
        if np.any(self.x_hi_ <= self.x_lo_):
            raise CalibError("every surrogate input needs at least two distinct values")
        self.y_lo_, self.y_hi_ = float(y.min()), float(y.max())
        if self.y_hi_ <= self.y_lo_:
            raise CalibError("the responses are all equal: nothing to learn")
        Xn = torch.as_tensor(self._norm_x(X))
        yn = torch.as_tensor(2 * (y - self.y_lo_) / (self.y_hi_ - self.y_lo_) - 1)
        theta0 = self._initial(Xn, yn)
        self.init_loss_ = self._loss_np(theta0, Xn, yn)
        theta = torch.tensor(theta0, dtype=torch.float64, requires_grad=True)
        opt = torch.optim.LBFGS([theta], lr=1.0, max_iter=self.epochs, tolerance_grad=1e-12,
                                tolerance_change=1e-15, line_search_fn="strong_wolfe")

        def closure():
            opt.zero_grad()
            loss = torch.mean((self._forward(theta, Xn) - yn) ** 2)
            if loss.item() < self.goal:  # the training goal: stop descending
                return loss
            loss.backward()
            return loss

        opt.step(closure)
        self.theta_ = theta.detach().numpy().copy()
        self.loss_ = self._loss_np(self.theta_, Xn, yn)
        return self

    def predict(self, X) -> np.ndarray:
        torch = _torch()
        Xn = torch.as_tensor(self._norm_x(np.atleast_2d(np.asarray(X, float))))
        with torch.no_grad():
            yn = self._forward(torch.as_tensor(self.theta_), Xn).numpy()
        return self.y_lo_ + (yn + 1) * (self.y_hi_ - self.y_lo_) / 2

    def to_state(self) -> dict:
        return {"kind": self.name, "inputs": self.inputs, "hidden": self.hidden, "epochs": self.epochs,
                "goal": self.goal, "seed": self.seed, "theta": self.theta_.tolist(),
                "x_lo": self.x_lo_.tolist(), "x_hi": self.x_hi_.tolist(), "y_lo": self.y_lo_, "y_hi": self.y_hi_,
                "init_loss": self.init_loss_, "loss": self.loss_}

    @classmethod
    def from_state(cls, st: dict):
        m = cls(st["inputs"], st["hidden"], st["epochs"], st["goal"], st["seed"])
        m.theta_ = np.asarray(st["theta"])
        m.x_lo_, m.x_hi_ = np.asarray(st["x_lo"]), np.asarray(st["x_hi"])
        m.y_lo_, m.y_hi_ = st["y_lo"], st["y_hi"]
        m.init_loss_, m.loss_ = st["init_loss"], st["loss"]
        return m


class PSOBPNetwork(BPNetwork):
    """BP network whose initial weights and biases come from a particle swarm."""

    name = "pso-bp"

    def __init__(self, inputs, hidden: int = 8, epochs: int = 100, goal: float = 1e-5, seed: int = 0,
                 swarm: int = 10, iterations: int = 30, inertia: float = 0.6, c1: float = 2.0, c2: float = 2.0):
        super().__init__(inputs, hidden, epochs, goal, seed)
        self.swarm, self.iterations, self.inertia, self.c1, self.c2 = swarm, iterations, inertia, c1, c2

    def _initial(self, Xn, yn) -> np.ndarray:
        res = pso_minimize(lambda th: self._loss_np(th, Xn, yn), self._dim(Xn.shape[1]), self.swarm,
                           self.iterations, (-2.0, 2.0), 0.5, self.inertia, self.c1, self.c2, self.seed)
        self.pso_history_ = res.history
        return res.x


def make_model(name: str, inputs: Sequence[str], seed: int = 0, hidden: int = 8, epochs: int = 100):
    if name == "rsm":
        return RSMSurrogate(inputs)
    if name == "bp":
        return BPNetwork(inputs, hidden, epochs, seed=seed)
    if name == "pso-bp":
        return PSOBPNetwork(inputs, hidden, epochs, seed=seed)
    raise CalibError(f"unknown surrogate {name!r}; choose from {', '.join(MODEL_NAMES)}")


def model_from_state(st: dict):
    kind = st.get("kind")
    if kind == "rsm":
        return RSMSurrogate.from_state(st)
    if kind == "bp":
        return BPNetwork.from_state(st)
    if kind == "pso-bp":
        return PSOBPNetwork.from_state(st)
    raise CalibError(f"unknown saved surrogate kind {kind!r}")
