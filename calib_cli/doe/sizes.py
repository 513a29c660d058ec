"""The run counts a Plackett-Burman design can have (paper section 3.1): plain Python, so that reading the
settings can check ``pb.runs`` without importing the analysis (scipy, pandas: a second at every command)."""

from __future__ import annotations

from ..errors import CalibError


def sizes(upto: int = 100) -> list[int]:
    """The run counts pyDOE3 builds a Plackett-Burman design of: 2^k, 12 x 2^k and 20 x 2^k (its Hadamard
    matrices: Sylvester's doubling of 1, 12 and 20), from 4."""
    out = {b * 2 ** k for b in (1, 12, 20) for k in range(max(int(upto), 1).bit_length()) if 4 <= b * 2 ** k <= upto}
    return sorted(out)


def check_runs(runs: int, k: int, where: str = "pb design") -> None:
    """``runs`` a size :func:`sizes` holds and more than the ``k`` factors, or a one-line error naming both."""
    ok = [n for n in sizes(max(int(runs), 4 * (k + 1), 100)) if n > k]
    if runs not in ok:
        raise CalibError(f"{where}: no Plackett-Burman design has {runs} runs for {k} factor(s); choose one of "
                         f"{', '.join(map(str, ok[:8]))}, ...")
