"""calib: DEM contact-parameter calibration from heap tests."""
import sys

# settings, models and pipelines are read with tomllib (Python 3.11+): say so instead of a traceback
if sys.version_info < (3, 11):
    raise ImportError(f"calib needs Python 3.11 or newer (it reads TOML with tomllib); this is Python "
                      f"{'.'.join(map(str, sys.version_info[:3]))}")

from calib_cli.blas import pin_openblas

# before numpy loads: the same bits on AVX2 and AVX-512 CPUs (calib_cli/blas.py)
pin_openblas()

__version__ = "0.1.0"
