"""Surrogates of the simulated angle and their inversion (paper sections 3.5-3.6).

- :mod:`.interface` the surrogates' one interface, ``fit(X, y)`` / ``predict(X)`` (:class:`~.interface.Surrogate`)
- :mod:`.models` RSM, BP network, PSO-initialised BP network behind one fit/predict interface
- :mod:`.pso`    a small seeded particle-swarm optimiser (PSO-BP's initial weights)
- :mod:`.ga`     a small seeded real-coded genetic algorithm (the inversion, Eq. 11)
- :mod:`.metrics` R2, MSE, AAD (Eqs. 8-10); 80/20 split and leave-one-out evaluation
"""
