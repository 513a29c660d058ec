"""What a law calls that differs between the CPU and the GPU: one name, each target's own code.

The laws are compiled for the CPU (numba) and for NVIDIA GPUs (numba's CUDA target, :mod:`..gpu`). Most
of what they call (``math.sqrt``, arithmetic) exists on both; what does not is here, as a generic
function numba resolves per target when it compiles the caller.
"""

from __future__ import annotations

import numpy as np
from numba.core.target_extension import current_target
from numba.extending import overload


def cbrt(x):
    """The real cube root: libm's on the CPU (as np.cbrt compiles there, so every CPU gives the same
    bits: docs/performance.md, "Reproducibility"), libdevice's on a GPU."""
    return np.cbrt(x)


@overload(cbrt, inline="always")
def _cbrt(x):
    if "cuda" in str(current_target()).lower():
        from numba.cuda import libdevice

        return lambda x: libdevice.cbrt(x)
    return lambda x: np.cbrt(x)
