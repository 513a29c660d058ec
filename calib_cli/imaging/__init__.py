"""Image analysis: repose angle from heap photographs (paper section 2.1, Fig. 3).

- :mod:`.measure` the pipeline (threshold, heap region, base line, sub-pixel profile, flanks)
- :mod:`.synth`   synthetic heap photographs of known angle (tests, the hidden-effect lab)
- :mod:`.stats`   per-condition statistics (paper Table 1)
"""
