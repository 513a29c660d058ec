"""OpenBLAS's kernels pinned, so a run computes the same bits on every x86-64 CPU with AVX2.

numpy's and scipy's OpenBLAS pick their kernels by CPU when they load. The AVX-512 (SkylakeX)
kernels sum in another order than the AVX2 (Haswell) ones, so the Gaussian processes' fits part
in their last bits, then the posterior, then where a calibration's next round puts its heaps: from
the same 60 heaps, `sample_runs/hidden-effect`'s revision 0 read a surrogate ratio of 1.2446 with
the AVX2 kernels and 1.2384 with the AVX-512 ones, and its compare failed 1 and 3 of 6 conditions.
This module imports nothing that loads numpy; calib_cli/__init__.py calls it first.
"""
from __future__ import annotations

import os
import platform

CORE = "Haswell"   # OpenBLAS's AVX2 + FMA kernels: on every x86-64 CPU since 2013-2015
NEEDS = frozenset({"avx2", "fma"})
NATIVE = "CALIB_NATIVE_BLAS"   # "1": leave OpenBLAS on the kernels it picks for this CPU


def cpu_flags(cpuinfo: str = "/proc/cpuinfo") -> frozenset[str]:
    """The first processor's flags in `cpuinfo` (Linux); empty where it cannot be read."""
    try:
        with open(cpuinfo, encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


def pin_openblas(environ=os.environ, machine: str | None = None,
                 cpuinfo: str = "/proc/cpuinfo") -> str | None:
    """Set OPENBLAS_CORETYPE to the AVX2 kernels where the CPU has them; return what was set.

    A value the user set wins, and CALIB_NATIVE_BLAS=1 keeps the CPU's own kernels; a CPU without
    AVX2 and FMA (forcing them would be an illegal instruction), another architecture or an
    unreadable cpuinfo keep OpenBLAS's own choice. It acts only if it runs before numpy is first
    imported in the process.
    """
    if "OPENBLAS_CORETYPE" in environ or environ.get(NATIVE) == "1":
        return None
    if (machine or platform.machine()).lower() not in ("x86_64", "amd64"):
        return None
    if not NEEDS <= cpu_flags(cpuinfo):
        return None
    environ["OPENBLAS_CORETYPE"] = CORE
    return CORE
