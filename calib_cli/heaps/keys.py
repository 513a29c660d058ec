"""Heap cache keys: the physics versions a heap's key names, the key itself (:class:`Request`), the seed
scheme, and the host a heap ran on (what besides its key its last bits depend on).

Each run is identified by the hash of everything that determines its result (model, parameters,
condition, numerics, seed, the versions of its laws and kernel); its artefacts live in
``RUN/simulate/runs/<hash>/`` (:data:`RUNS`).
"""

from __future__ import annotations

import functools
import platform
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from .. import artifacts as art
from ..dem import GPU_VERSION, KERNEL_VERSION
from ..dem.heap import HeapCondition, Numerics, heap_model, run_key
from ..dem.laws import REGISTRY, ContactModel
from ..engines.clumps import SPHERES

#: a run directory's cached heaps, one folder per run hash
RUNS = Path("simulate") / "runs"


def physics(model: ContactModel | None = None) -> dict[str, object]:
    """The physics a heap's cache key names: the kernel's version (integration, neighbour search, the
    force loop's assembly) and the name and version of each contact law the heap composes (``model``;
    every registered law without one), not the bytes of the source, so that a comment or a refactoring
    that keeps the arithmetic re-simulates nothing, and raising one law's version re-simulates exactly
    the heaps that used it."""
    laws = model.laws if model is not None else [law for family in REGISTRY.values() for law in family.values()]
    return {"kernel": KERNEL_VERSION, **{f"{law.family}={law.name}": law.version for law in laws}}


#: every law's version and the kernel's (docs; a heap's key takes only its own laws': :func:`heap_source`)
PHYSICS = physics()


def cache_source(physics: Mapping[str, object]) -> str:
    """The name of a physics version in cache keys and the results' `source` column: 77675d5eca62
    while the kernel and the laws named are at their first version (the last kernel source keyed by
    its bytes, whose heaps they compute bit for bit: the golden heaps of tests/test_heap.py), a hash
    of the versions after."""
    if str(physics.get("kernel")) == "1" and all(v == 1 for k, v in physics.items() if k != "kernel"):
        return "77675d5eca62"
    return art.hash_obj(dict(physics))[:12]


def heap_source(params: Mapping[str, float], condition: HeapCondition | None = None) -> str:
    """The physics version a heap of these parameters and condition runs (its laws' and the kernel's)."""
    return cache_source(physics(heap_model(params, condition)))


#: the version of the whole table (the kernel, every law): compare and diagnose name it in their settings, so
#: that any raised version re-runs them (the heaps it leaves unchanged come from the cache)
CACHE_SOURCE = cache_source(PHYSICS)
#: the second engines' own source (calib_cli/engines/: the LAMMPS parameter mapping, clumps), in their
#: heaps' keys beside CACHE_SOURCE: a changed mapping re-simulates instead of serving the old one's heaps
ENGINE_SOURCE = art.hash_obj({f.name: art.file_hash(f)
                              for f in sorted((Path(__file__).parents[1] / "engines").glob("*.py"))})[:12]


@dataclass(frozen=True)
class Request:
    """One heap to simulate. Its ``key`` (and ``hash``) holds what determines the result; preset, design,
    run id, repeat and condition id only label its results row."""

    params: Mapping[str, float]
    condition: HeapCondition
    numerics: Numerics
    seed: int
    preset: str = ""
    design: str = ""  # the design stage this run belongs to ("pb", "bbd", ...), if any
    run_id: int = 0
    repeat: int = 0
    model: str = ""
    condition_id: str = ""
    engine: str = "builtin"  # builtin | lammps | gpu
    mpi: int = 1  # MPI ranks of a LAMMPS run (the summation order, hence the trajectory, depends on it)
    shapes: tuple[str, ...] = SPHERES  # grain shapes of a LAMMPS run (engines/clumps.py)

    @property
    def key(self) -> dict:
        k = run_key(self.params, self.condition, self.numerics, self.seed, self.model)
        k["source"] = self.source
        if self.engine != "builtin":  # keeps the built-in engine's existing cache keys
            k["engine"] = self.engine
            k["engine_source"] = f"gpu-{GPU_VERSION}" if self.engine == "gpu" else ENGINE_SOURCE
        if self.mpi > 1:
            k["mpi"] = self.mpi
        if tuple(self.shapes) != SPHERES:
            k["shapes"] = list(self.shapes)
        return k

    @property
    def source(self) -> str:
        """The physics version this heap runs (:func:`heap_source`)."""
        return heap_source(self.params, self.condition)

    @property
    def hash(self) -> str:
        return art.hash_obj(self.key)


def derive_seed(base: int, run_id: int, repeat: int) -> int:
    """Independent, reproducible seeds per (design run, repeat): two design runs at the same
    point (a PB design can repeat one) are separate replicates, not one cached run."""
    return int(np.random.SeedSequence([int(base), int(run_id), int(repeat)]).generate_state(1)[0] & 0x7FFFFFFF)


@functools.cache
def host() -> str:
    """What, besides the inputs in the run hash, the heap's last bits depend on: the instruction
    set numpy dispatches its ufunc loops on, numpy's and numba's versions.

    numpy sends float64 transcendental ufuncs (cbrt, power, ...) to AVX-512 loops (Intel's
    SVML) where the CPU has AVX-512 and to others elsewhere, which differ in the last place,
    and a heap amplifies any such difference until it settles differently (docs/performance.md,
    "Reproducibility": verified by switching numpy's AVX-512 loops off on one machine).
    """
    import numba

    return f"{platform.machine()} {simd_level()} numpy {np.__version__} numba {numba.__version__}"


def _numpy_cpu() -> tuple[list[str], dict]:
    """numpy's dispatch targets (lowest first) and the CPU features it found."""
    try:
        from numpy._core import _multiarray_umath as m
    except ImportError:  # numpy < 2
        from numpy.core import _multiarray_umath as m
    return list(m.__cpu_dispatch__), dict(m.__cpu_features__)


def numpy_dispatch_targets() -> list[str]:
    """The SIMD targets numpy can dispatch its ufunc loops on, lowest first (NPY_DISABLE_CPU_FEATURES
    takes names from this list)."""
    return _numpy_cpu()[0]


def simd_level() -> str:
    """The highest of numpy's dispatch targets this CPU (and NPY_DISABLE_CPU_FEATURES) enables,
    e.g. X86_V3 (AVX2) or AVX512_ICL; the baseline if none."""
    targets, cpu = _numpy_cpu()
    on = [t for t in targets if cpu.get(t)]
    return on[-1] if on else "baseline"
