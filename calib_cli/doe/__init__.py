"""Design of experiments: designs (sample) and their analysis (analyze).

Pure functions and result objects; no I/O. Follows the paper's section 3:
Plackett-Burman screening (:mod:`.pb`), steepest ascent (:mod:`.ascent`),
Box-Behnken response surface (:mod:`.bbd`), all on one least-squares core
(:mod:`.linear`).
"""
