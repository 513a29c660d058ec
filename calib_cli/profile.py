"""Heap-profile geometry shared by the image path and the particle-coordinate path.

A flank is the part of the top profile h(r) between the toe and the apex; its angle is
``atan(|dh/dr|)`` of a robust straight-line fit (Huber IRLS, statsmodels' RLM algorithm) over a
height band that excludes the rounded apex and the toe (default 15-85 % of the
heap height), as the paper's Fig. 3 does with a tangent to the contour.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_BAND = (0.15, 0.85)


@dataclass(frozen=True)
class FlankFit:
    angle: float  # deg, positive
    slope: float  # dh/dr
    intercept: float
    rmse: float  # of the fitted points, in the profile's units
    n: int

    @property
    def ok(self) -> bool:
        return self.n >= 3 and math.isfinite(self.angle)


NO_FIT = FlankFit(float("nan"), float("nan"), float("nan"), float("nan"), 0)


HUBER_T = 1.345  # statsmodels.robust.norms.HuberT's default tuning constant
MAD_C = 0.6744897501960817  # statsmodels.robust.scale.Gaussian.ppf(3/4): MAD -> sd of a normal


def line_fit(x: np.ndarray, y: np.ndarray, w: np.ndarray | None = None) -> tuple[float, float]:
    """(intercept, slope) of the (weighted) least-squares line, from numpy's own pairwise sums
    about the means: no BLAS or LAPACK, whose kernels are picked by CPU and differ in the last
    place from machine to machine (docs/performance.md, "Reproducibility")."""
    w = np.ones(len(x)) if w is None else w
    sw = np.sum(w)
    xb, yb = np.sum(w * x) / sw, np.sum(w * y) / sw
    dx = x - xb
    slope = np.sum(w * dx * (y - yb)) / np.sum(w * dx * dx)
    return float(yb - slope * xb), float(slope)


def lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares by the normal equations, their entries summed by numpy and solved by
    Gaussian elimination with partial pivoting in Python floats: for a few well-conditioned
    columns (an illumination field), without BLAS or LAPACK (see :func:`line_fit`)."""
    k = A.shape[1]
    M = [[float(np.sum(A[:, i] * A[:, j])) for j in range(k)] + [float(np.sum(A[:, i] * b))] for i in range(k)]
    for c in range(k):
        piv = max(range(c, k), key=lambda i: abs(M[i][c]))
        M[c], M[piv] = M[piv], M[c]
        if M[c][c] == 0.0:
            raise np.linalg.LinAlgError("singular normal equations")
        for i in range(c + 1, k):
            f = M[i][c] / M[c][c]
            M[i] = [a - f * p for a, p in zip(M[i], M[c])]
    x = [0.0] * k
    for i in reversed(range(k)):
        x[i] = (M[i][k] - sum(M[i][j] * x[j] for j in range(i + 1, k))) / M[i][i]
    return np.array(x)


def combine(A: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """A @ coef column by column (no BLAS; see :func:`line_fit`)."""
    out = A[:, 0] * coef[0]
    for j in range(1, A.shape[1]):
        out = out + A[:, j] * coef[j]
    return out


def huber_line(r: np.ndarray, h: np.ndarray, maxiter: int = 50, tol: float = 1e-8) -> np.ndarray:
    """(intercept, slope) of ``sm.RLM(h, add_constant(r), M=HuberT()).fit()``, solved portably.

    statsmodels' IRLS step for step: OLS start, scale = MAD of the residuals about 0, Huber
    weights min(1, t/|z|), weighted refit, stop when the deviance sum rho((h - fit) / s_w)
    (s_w = the weighted residual variance, as statsmodels has it) changes by <= tol or after
    maxiter fits. Each weighted least-squares line is solved in closed form from numpy's own
    (pairwise) sums, not by an SVD in OpenBLAS as statsmodels does: OpenBLAS picks its kernels
    by CPU and they differ in the last place, so a heap's measured angle would depend on the
    machine (docs/performance.md, "Reproducibility"). Written out, too, because statsmodels'
    per-fit overhead made it 3x slower, ~5 % of a heap's run time (the rest phase fits the
    flanks every chunk to measure creep). Agrees with statsmodels to rounding (tests/test_profile.py).
    """
    n = r.shape[0]
    df = n - 2
    t, half_t2, k = HUBER_T, 0.5 * HUBER_T**2, n // 2

    def mad(resid):  # statsmodels.robust.scale.mad(resid, center=0): median(|resid| / c)
        e = np.abs(resid) / MAD_C
        if n % 2:
            return np.partition(e, k)[k]
        p = np.partition(e, (k - 1, k))
        return (p[k - 1] + p[k]) / 2.0

    def deviance(resid, wresid):
        z = resid / (np.sum(wresid * wresid) / df)
        a = np.abs(z)
        return np.sum(np.where(a <= t, 0.5 * z * z, a * t - half_t2))

    with np.errstate(divide="ignore", invalid="ignore"):  # an exact line: statsmodels divides by 0 too
        c0, c1 = line_fit(r, h)
        resid = h - (c0 + c1 * r)
        scale = mad(resid)
        prev = deviance(resid, resid)
        it = 1
        while scale != 0.0:  # statsmodels stops (with a warning) on a perfect fit
            a = np.abs(resid / scale)
            small = a <= t
            w = np.where(small, 1.0, t / np.where(small, 1.0, a))
            if not np.isfinite(w).all():
                raise ValueError("non-finite IRLS weights")
            c0, c1 = line_fit(r, h, w)
            resid = h - (c0 + c1 * r)
            scale = mad(resid)
            dev = deviance(resid, np.sqrt(w) * resid)
            it += 1
            if not (abs(dev - prev) > tol and it < maxiter):
                break
            prev = dev
    return np.array([c0, c1])


def _rlm(r, h):
    try:
        c0, c1 = huber_line(r, h)
        return float(c0), float(c1)
    except (ValueError, np.linalg.LinAlgError):
        c1, c0 = np.polyfit(r, h, 1)
        return float(c0), float(c1)


def fit_flank(r: np.ndarray, h: np.ndarray, height: float, band=DEFAULT_BAND, base: float = 0.0) -> FlankFit:
    """Robust line fit of a flank h(r) between the heights base + band[0]*height and base + band[1]*height.

    Two passes: the first selects points by their height; the second by their position r,
    between where the first line crosses the band's edges. Selecting on h alone is a
    truncation bias: a grain that raises h near the lower edge is let in, one near the upper
    edge is left out, and the line comes out flatter (-0.15 deg on synthetic heaps with
    6 px grains, -0.55 deg with 10 px grains).
    """
    r = np.asarray(r, dtype=float)
    h = np.asarray(h, dtype=float)
    lo, hi = base + band[0] * height, base + band[1] * height
    fin = np.isfinite(r) & np.isfinite(h)
    m = fin & (h >= lo) & (h <= hi)
    if m.sum() < 3 or np.ptp(r[m]) <= 0:
        return NO_FIT
    c0, c1 = _rlm(r[m], h[m])
    if c1 != 0:
        r_a, r_b = sorted(((lo - c0) / c1, (hi - c0) / c1))
        m2 = fin & (r >= r_a) & (r <= r_b)
        if m2.sum() >= 3 and np.ptp(r[m2]) > 0:
            m = m2
            c0, c1 = _rlm(r[m], h[m])
    resid = h[m] - (c0 + c1 * r[m])
    return FlankFit(math.degrees(math.atan(abs(c1))), c1, c0, float(np.sqrt(np.mean(resid**2))), int(m.sum()))


#: the fullness's base, in heap heights: below it the toe's loose grains and the floor's layer set the
#: width (one 6-8 mm grain is 15-25 % of a 40 mm cylinder's heap)
FULLNESS_LEVEL = 0.15


def _crossing(s: np.ndarray, h: np.ndarray, i: int, j: int, level: float) -> float:
    """Where h crosses ``level`` between neighbouring samples i (below) and j (above), linearly."""
    return float(s[i] + (level - h[i]) * (s[j] - s[i]) / (h[j] - h[i]))


def fullness(s: np.ndarray, h: np.ndarray, level: float = FULLNESS_LEVEL) -> float:
    """The profile's shape beside its angle: the area of the top profile h(s) above ``level`` heap
    heights H over that of the triangle of the same height and width w there,

        F = int (h - l H) ds / (0.5 (1 - l) H w)

    between the first crossings of l H from the apex outwards (a grain rolled beyond the toe is not
    the heap). F = 1 for a cone's straight flanks, above 1 for convex ones (rounded shoulders over a
    steep toe), below 1 for concave ones. Scale-free, so a photograph's pixels
    and a simulation's metres give the same number. NaN where either flank never falls to l H. A layer
    lying along the level itself (a skirt of single grains at 15 % of a small heap's height) would
    move the crossings, and F with them, by a step: on the sample labs' photographs and side views
    F's scatter about its trend shows no such split (residual kurtosis 0.5)."""
    s, h = np.asarray(s, float), np.asarray(h, float)
    fin = np.isfinite(s) & np.isfinite(h)
    s, h = s[fin], h[fin]
    if len(h) < 3 or not np.max(h) > 0:
        return float("nan")
    ia = int(np.argmax(h))
    H = float(h[ia])
    lv = level * H
    below_l, below_r = np.flatnonzero(h[:ia] < lv), ia + np.flatnonzero(h[ia:] < lv)
    if not (len(below_l) and len(below_r)):
        return float("nan")
    il, ir = int(below_l[-1]), int(below_r[0])
    sl, sr = _crossing(s, h, il, il + 1, lv), _crossing(s, h, ir, ir - 1, lv)
    if not sr > sl:
        return float("nan")
    xs = np.r_[sl, s[il + 1:ir], sr]
    ys = np.r_[0.0, h[il + 1:ir] - lv, 0.0]
    area = float(np.sum(0.5 * (ys[1:] + ys[:-1]) * np.diff(xs)))
    return area / (0.5 * (1.0 - level) * H * (sr - sl))


#: the band of heap heights whose flanks :func:`band_fullness` weighs: above the toe's loose grains and
#: floor layer, below a flat top (a fill that never reached an apex)
BAND_LEVELS = (0.15, 0.85)


def band_fullness(s: np.ndarray, h: np.ndarray, levels: tuple[float, float] = BAND_LEVELS) -> float:
    """The flanks' shape between two heights, l1 = levels[0] H and l2 = levels[1] H: the profile's area
    between them over that of the trapezoid with the same widths at both,

        F_b = int (min(h, l2) - l1)+ ds / (0.5 (w1 + w2) (l2 - l1))

    w1 the width between the first crossings of l1 from the apex outwards (a grain rolled beyond the
    toe is not the heap), w2 the span of the profile above l2. Straight flanks give 1 whatever the top:
    a cone and a truncated cone alike (a flat top, where the fill never reached an apex, moved
    :func:`fullness` as much as cohesion does); convex flanks (rounded shoulders over a steep toe) give
    more, concave ones less. Scale-free; NaN where a flank never falls to l1."""
    s, h = np.asarray(s, float), np.asarray(h, float)
    fin = np.isfinite(s) & np.isfinite(h)
    s, h = s[fin], h[fin]
    if len(h) < 3 or not np.max(h) > 0:
        return float("nan")
    o = np.argsort(s)
    s, h = s[o], h[o]
    ia = int(np.argmax(h))
    H = float(h[ia])
    l1, l2 = levels[0] * H, levels[1] * H
    below_l, below_r = np.flatnonzero(h[:ia] < l1), ia + np.flatnonzero(h[ia:] < l1)
    if not (len(below_l) and len(below_r)):
        return float("nan")
    il, ir = int(below_l[-1]), int(below_r[0])
    sl, sr = _crossing(s, h, il, il + 1, l1), _crossing(s, h, ir, ir - 1, l1)
    above = np.flatnonzero(h[il:ir + 1] >= l2) + il
    a, b = int(above[0]), int(above[-1])
    s2l = _crossing(s, h, a - 1, a, l2) if a > il else s[a]
    s2r = _crossing(s, h, b + 1, b, l2) if b < ir else s[b]
    if not (sr > sl and s2r >= s2l):
        return float("nan")
    xs = np.r_[sl, s[il + 1:ir], sr]
    ys = np.r_[0.0, np.clip(h[il + 1:ir], l1, l2) - l1, 0.0]
    area = float(np.sum(0.5 * (ys[1:] + ys[:-1]) * np.diff(xs)))
    return area / (0.5 * ((sr - sl) + (s2r - s2l)) * (l2 - l1))
