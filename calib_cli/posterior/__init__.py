"""A Bayesian calibration: the posterior over the model's parameters given every measured condition.

- :mod:`.gp`        a Gaussian-process surrogate of the angle over the parameters and the condition
  variables, trained on every simulated heap (pile-to-pile scatter as its white noise)
- :mod:`.calibrate` the likelihood of the measured mean angles and its sampling (emcee)
"""
