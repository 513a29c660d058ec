"""The built-in DEM engine: polydisperse spheres, Hertz-Mindlin (no slip) with JKR
cohesion and constant-directional-torque rolling friction, as in EDEM (SPEC section 5), or
with ``rolling_spring = 1`` a spring-dashpot-slider rolling law (LAMMPS's `rolling sds`), and
with ``caps_pulloff = 1`` sliding and rolling capped on |F_el + 2 F_c| (Thornton 1991,
Marshall 2009, LAMMPS's jkr).

Imports nothing from the CLI. Layers, each usable alone:

- :mod:`.contact`   scalar contact laws (numba-compiled, tested against analytic results)
- :mod:`.materials` materials and interaction parameters -> packed kernel arrays
- :mod:`.kernel`    neighbour list, forces, velocity-Verlet integration (numba)
- :mod:`.system`    a particle system with walls; a factory returns its step function
- :mod:`.heap`      the heap test scenario (fill, settle, lift, rest) and presets
- :mod:`.angle`     repose angle from particle coordinates
- :mod:`.render`    rendered side view (silhouette) of a heap
"""

import hashlib
import os
from pathlib import Path

KERNEL_VERSION = "1"


def _source_hash() -> str:
    h = hashlib.sha256()
    for f in sorted(Path(__file__).parent.glob("*.py")):
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


#: hash of the kernel's source: part of every simulation's cache key (unless calib_cli.campaign's
#: SAME_BITS declares that it computes an earlier source's heaps bit for bit), and the numba
#: cache folder, because numba's own cache only tracks each function's own file and would keep
#: stale machine code of a contact law inlined from another module
SOURCE_HASH = _source_hash()

if "NUMBA_CACHE_DIR" not in os.environ:
    import numba

    numba.config.CACHE_DIR = str(Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
                                 / "calib" / "numba" / SOURCE_HASH)
