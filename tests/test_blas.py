"""OpenBLAS's kernels pinned before numpy loads (calib_cli/blas.py)."""
import os
import subprocess
import sys

import pytest

from calib_cli.blas import CORE, cpu_flags, pin_openblas


def _cpuinfo(tmp_path, flags):
    p = tmp_path / "cpuinfo"
    p.write_text(f"processor\t: 0\nmodel name\t: test\nflags\t\t: {flags}\n\nprocessor\t: 1\nflags\t: sse2\n")
    return str(p)


def test_an_avx2_cpu_gets_the_avx2_kernels(tmp_path):
    env = {}
    assert pin_openblas(env, "x86_64", _cpuinfo(tmp_path, "fpu sse2 avx avx2 fma avx512f")) == CORE
    assert env == {"OPENBLAS_CORETYPE": "Haswell"}


def test_what_the_user_set_wins(tmp_path):
    env = {"OPENBLAS_CORETYPE": "SkylakeX"}
    assert pin_openblas(env, "x86_64", _cpuinfo(tmp_path, "avx2 fma")) is None
    assert env == {"OPENBLAS_CORETYPE": "SkylakeX"}
    env = {"CALIB_NATIVE_BLAS": "1"}
    assert pin_openblas(env, "x86_64", _cpuinfo(tmp_path, "avx2 fma")) is None
    assert env == {"CALIB_NATIVE_BLAS": "1"}


@pytest.mark.parametrize("machine, flags", [("x86_64", "sse2 avx"),      # no AVX2: Haswell's would trap
                                            ("x86_64", "avx2"),          # no FMA
                                            ("aarch64", "avx2 fma")])    # another architecture
def test_a_cpu_without_them_keeps_openblas_own_choice(tmp_path, machine, flags):
    env = {}
    assert pin_openblas(env, machine, _cpuinfo(tmp_path, flags)) is None
    assert env == {}


def test_an_unreadable_cpuinfo_pins_nothing(tmp_path):
    assert cpu_flags(str(tmp_path / "absent")) == frozenset()
    env = {}
    assert pin_openblas(env, "x86_64", str(tmp_path / "absent")) is None and env == {}


@pytest.mark.skipif(not {"avx2", "fma"} <= cpu_flags(), reason="needs an x86-64 CPU with AVX2 and FMA")
def test_importing_calib_first_loads_numpy_and_scipy_with_the_avx2_kernels():
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    code = ("import calib_cli, numpy, scipy.linalg\n"
            "from threadpoolctl import threadpool_info\n"
            "print(sorted({i.get('architecture') for i in threadpool_info() if i['internal_api'] == 'openblas'}))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['Haswell']"


#: a top-level import that loads numpy (numba and the others import it themselves)
NUMPY_USERS = r"(import|from) (numpy|pandas|scipy|numba|cv2|torch|matplotlib|statsmodels|pyarrow|sklearn|emcee)\b"


def test_every_benchmark_that_uses_calib_pins_before_numpy_loads():
    """A benchmark that refits a posterior must compute on the kernels `calib` computes on, so calib_cli
    (its pin) is imported before numpy, or any library that loads it, at the top of each script that uses both."""
    import re
    from pathlib import Path

    late = []
    for p in sorted((Path(__file__).parent.parent / "benchmarks").glob("*.py")):
        lines = p.read_text().splitlines()
        first = lambda pat: next((i for i, s in enumerate(lines) if re.match(pat, s)), None)  # noqa: E731
        np_at = first(NUMPY_USERS)
        calib_at = first(r"\s*(import calib_cli|from calib_cli|importlib\.import_module\(\"calib_cli\"\))")
        if np_at is not None and calib_at is not None and calib_at > np_at:
            late.append(p.name)
    assert late == []
