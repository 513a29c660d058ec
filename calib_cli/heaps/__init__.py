"""Simulated heaps: their cache keys, the campaigns that run them, the index of their results.

- :mod:`.keys`   physics versions, cache keys (:class:`~.keys.Request`), seeds, the host a heap ran on
- :mod:`.inputs` a command's parameters, conditions and heap setup, checked and turned into requests
- :mod:`.runner` running requests (cached, resumable; local pool, Dask or GPU batches)
- :mod:`.index`  the results index ``RUN/simulate/results.parquet``: its readers and writer

Most code only reads results (:mod:`.index`), which imports neither :mod:`.runner` (the executors) nor the
imaging (a contract in pyproject.toml holds it); it does import the heap's definitions (calib_cli.dem.heap).
"""
