"""The built-in DEM engine: polydisperse spheres with contact laws composed by name
(:mod:`.laws`): Hertz-Mindlin (no slip) with JKR cohesion and constant-directional-torque rolling
friction, as in EDEM, by default; a spring-dashpot-slider rolling law (LAMMPS's `rolling sds`),
other friction caps and capillary liquid bridges on request.

Imports nothing from the CLI. Layers, each usable alone:

- :mod:`.laws`       contact laws, one module per family, composed by name (numba-compiled,
                     tested against analytic results)
- :mod:`.materials`  materials and interactions -> the contact model and its parameter rows
- :mod:`.neighbours` Verlet neighbour list from a cell list, contact history carried over
- :mod:`.forces`     one composed contact, and every contact of a step
- :mod:`.integrate`  velocity-Verlet steps in compiled chunks
- :mod:`.compile`    each law composition's kernel compiled once per machine (a lock beside the cache)
- :mod:`.timestep`   critical time steps
- :mod:`.system`     a particle system with walls; a factory returns its step function
- :mod:`.heap`      the heap test scenario (fill, settle, lift, rest) and presets
- :mod:`.angle`     repose angle from particle coordinates
- :mod:`.render`    rendered side view (silhouette) of a heap
"""

import hashlib
import os
from pathlib import Path

KERNEL_VERSION = "1"
#: the GPU engine's own bookkeeping (dem/gpu.py: neighbour slots, grids, the step's kernels), in its heaps' keys
GPU_VERSION = "1"


def _source_hash() -> str:
    h = hashlib.sha256()
    here = Path(__file__).parent
    for f in sorted(here.rglob("*.py")):
        h.update(str(f.relative_to(here)).encode() + f.read_bytes())
    return h.hexdigest()[:12]


#: hash of the kernel's source (dem/ and dem/laws/): names numba's cache folder only, because numba's own
#: cache tracks each function's own file and would keep stale machine code of a law inlined from another
#: module. Heaps' cache keys name the laws' versions instead (calib_cli.heaps.keys.PHYSICS)
SOURCE_HASH = _source_hash()

if "NUMBA_CACHE_DIR" not in os.environ:
    import numba

    numba.config.CACHE_DIR = str(Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
                                 / "calib" / "numba" / SOURCE_HASH)
