"""Repose angle of a heap photograph (paper section 2.1, Fig. 3).

1. grayscale, denoise (Gaussian), flatten the illumination (a robust low-order polynomial
   fitted to the background), Otsu threshold; the class that dominates the top rows is the
   background, so either polarity (dark heap on light, light on dark) works;
2. the heap is the largest foreground component standing on the base; loose grains (other
   components) are ignored;
3. the base line is fitted: from the floor surface at both lateral ends when the floor is in
   the heap's class (a strip across the image), else from the heap's bottom edge; its tilt is
   the camera roll, removed by working in the base-line frame;
4. the top profile per column with sub-pixel precision (linear interpolation of the threshold
   crossing in the smoothed image);
5. each flank is fitted by :func:`calib_cli.profile.fit_flank` (robust line, 15-85 % of the
   height by default), the same code the particle-coordinate angle uses; angle per flank, their
   mean, fit RMSE; a left/right difference above ``roll_warn_deg`` gets a message;
6. the silhouette is checked to be a heap's cone (:class:`ShapeLimits`): the frame cuts no flank,
   no standing wall, straight flanks, flanks alike; else a status of :data:`FLAGS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..profile import DEFAULT_BAND, combine, fit_flank, line_fit, lstsq


@dataclass
class ImageAngle:
    status: str  # ok | unreadable | blank | no_heap | cut | column | not_cone | asymmetric
    message: str = ""
    angle_left: float = float("nan")
    angle_right: float = float("nan")
    repose_angle: float = float("nan")
    fit_rmse_px: float = float("nan")
    base_tilt_deg: float = float("nan")
    height_px: float = float("nan")
    profile_s: np.ndarray = field(default_factory=lambda: np.empty(0))  # along the base, px (apex at 0)
    profile_h: np.ndarray = field(default_factory=lambda: np.empty(0))  # above the base, px
    fits: tuple = ()
    base: tuple = ()  # (a, b, tilt_rad): the base line y = a + b x in image pixels
    apex_along: float = float("nan")  # apex position along the base line, px
    mask: np.ndarray | None = None


def read_image(path: Path) -> np.ndarray | None:
    """The photograph in grey, or None where it cannot be decoded (empty, corrupt, or larger than
    OpenCV decodes: its pixel limit raises rather than returning nothing)."""
    data = np.fromfile(str(path), dtype=np.uint8)
    if data.size == 0:
        return None
    try:
        return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    except cv2.error:
        return None


def _flatten(gray: np.ndarray, fg: np.ndarray) -> np.ndarray:
    """Divide out a quadratic illumination field fitted to the background pixels."""
    h, w = gray.shape
    ys, xs = np.nonzero(~fg)
    if len(xs) < 50 or len(np.unique(xs)) < 3 or len(np.unique(ys)) < 3:  # a quadratic needs 3 rows and columns
        return gray
    step = max(1, len(xs) // 20000)
    xs, ys = xs[::step], ys[::step]
    x, y = xs / w - 0.5, ys / h - 0.5
    A = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    b = gray[ys, xs].astype(float)
    # BLAS-free solves (profile.lstsq): a photograph's angle is the same on every machine
    try:
        coef = lstsq(A, b)
        for _ in range(3):  # reweight: drop pixels far from the fit (shadows, stray grains)
            r = b - combine(A, coef)
            keep = np.abs(r) < 2.5 * (np.median(np.abs(r)) * 1.4826 + 1e-9)
            if keep.sum() < 20 or len(np.unique(xs[keep])) < 3 or len(np.unique(ys[keep])) < 3:
                break
            coef = lstsq(A[keep], b[keep])
    except np.linalg.LinAlgError:  # a background in one row or column fixes no field: left as it is
        return gray
    X, Y = np.meshgrid(np.arange(w) / w - 0.5, np.arange(h) / h - 0.5)
    field_ = coef[0] + coef[1] * X + coef[2] * Y + coef[3] * X * X + coef[4] * X * Y + coef[5] * Y * Y
    field_ = np.maximum(field_, 1.0)
    return gray / field_ * float(np.median(b))


def _otsu(img: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """Foreground mask, threshold, and whether the foreground is the darker class."""
    u8 = np.clip(img, 0, 255).astype(np.uint8)
    t, m = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    bright = m > 0
    top = bright[: max(2, img.shape[0] // 10)]
    dark_fg = top.mean() > 0.5  # the top rows are background
    fg = ~bright if dark_fg else bright
    return fg, float(t), dark_fg


def _robust_line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """y = a + b x by least squares with two rounds of outlier trimming."""
    keep = np.ones(len(x), bool)
    a = b = 0.0
    for _ in range(3):
        if keep.sum() < 2:
            break
        a, b = line_fit(x[keep], y[keep])
        r = np.abs(y - (a + b * x))
        keep = r <= max(2.5 * np.median(r[keep]) * 1.4826, 1.0)
    return a, b


@dataclass(frozen=True)
class ShapeLimits:
    """When a measured silhouette is not a heap's cone, whose mean flank angle would be no repose angle.

    The defaults pass every shipped photograph and rendered lab heap with a margin (docs/artefacts.md
    gives the distributions): rendered DEM heaps of a few grains per flank are rough and domed (flank
    fit residuals up to 0.14 of the height, flanks up to 19 deg apart), so the limits are loose; photos
    of fine grains may tighten ``max_flank_diff_deg`` and ``max_residual``.
    """

    max_flank_diff_deg: float = 25.0  # asymmetric: left and right flank angles further apart
    max_residual: float = 0.20  # not_cone: a flank's line-fit RMSE over the band, in heap heights
    max_wall: float = 0.5  # column: the profile rises this many heap heights within a tenth of one ...
    min_stance: float = 0.2  # ... on a silhouette at least this tall for its width at 15 % of its height
    min_floor: float = 0.5  # cut: the least share of either image edge (a 40th of the width) on the base line


#: statuses of a silhouette measured but not a heap's cone: left out of the condition statistics
#: unless the user keeps them; they carry the angles where the flanks could be fitted
FLAGS = ("cut", "column", "not_cone", "asymmetric")


def _segment(g: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The largest foreground component (the heap, with the floor strip if any), the flattened
    image and its threshold; None without foreground."""
    fg0, _, _ = _otsu(g)
    flat = _flatten(g, cv2.dilate(fg0.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0)
    fg, thr, _ = _otsu(flat)
    fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, st, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if n <= 1:
        return None
    big = 1 + int(np.argmax(st[1:, cv2.CC_STAT_AREA]))
    return lab == big, flat, thr


def _top_edge(comp: np.ndarray, flat: np.ndarray, thr: float, cols: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Sub-pixel top edge per column: where the smoothed intensity crosses the threshold between
    rows; NaN where the component touches the top of the frame or has no column."""
    ytop = np.full(comp.shape[1], np.nan)
    for x in cols:
        y = int(top[x])
        if y <= 0:
            continue  # touches the frame
        v0, v1 = flat[y - 1, x], flat[y, x]
        if (v1 - v0) != 0:
            f = (thr - v0) / (v1 - v0)
            ytop[x] = (y - 1) + min(max(f, 0.0), 1.0) + 0.5
        else:
            ytop[x] = y
    return ytop


def _wall(s: np.ndarray, h: np.ndarray, height: float) -> tuple[float, float]:
    """The largest rise of the profile within a tenth of the heap height horizontally, in heap
    heights (a cone's flank at 60 deg gives 0.17, a standing column's wall 1), and the stance: the
    height over the width at 15 % of it (a column stands; a layer spread a few grains high does not,
    though one grain on it rises as steeply)."""
    o = np.argsort(s)
    s, h = s[o], h[o]
    grid = np.arange(s[0], s[-1], 1.0)
    w = max(1, int(round(0.1 * height)))
    if len(grid) <= w:
        return 0.0, 0.0
    hg = np.interp(grid, s, h)
    up = grid[hg >= 0.15 * height]
    return float(np.max(np.abs(hg[w:] - hg[:-w])) / height), float(height / max(up[-1] - up[0], 1.0))


def _floor_share(hgt: np.ndarray, height: float) -> tuple[float, str]:
    """The smaller share of the image's two edges (a 40th of the width each) lying on the base line, and
    which edge. The base line is fitted to the image's ends (a twelfth of the width each): where a flank
    reaches into them (the frame cuts the heap, or its toe is that close to the frame) the line runs
    above the floor, or through the flank, and the edges are off it; the angle of such a heap is not
    to be trusted (it came out right only for straight, symmetric synthetic cones)."""
    edge, tol = max(2, len(hgt) // 40), max(3.0, 0.03 * height)
    with np.errstate(invalid="ignore"):
        left, right = (float(np.mean(np.abs(v) <= tol)) for v in (hgt[:edge], hgt[-edge:]))
    return (left, "left") if left <= right else (right, "right")


def _flag(res: "ImageAngle", limits: ShapeLimits, wall: tuple[float, float],
          floor: tuple[float, str] | None) -> None:
    """Set the status of a silhouette that is no heap's cone (the first check that fails, FLAGS' order)."""
    fl, fr = res.fits if res.fits else (None, None)
    if floor is not None and floor[0] < limits.min_floor:
        res.status, res.message = "cut", (f"the heap is cut by the {floor[1]} side of the frame, or its toe is too "
                                          f"close to it: {floor[0]:.0%} of that edge lies on the base line")
    elif wall[0] > limits.max_wall and wall[1] >= limits.min_stance:
        res.status, res.message = "column", (f"a standing column, not a heap: a wall rises {wall[0]:.2f} of the "
                                             f"height within a tenth of it (limit {limits.max_wall:g})")
    elif fl is not None and max(fl.rmse, fr.rmse) > limits.max_residual * res.height_px:
        side, f = max((("left", fl), ("right", fr)), key=lambda t: t[1].rmse)
        res.status, res.message = "not_cone", (f"the {side} flank is not straight: line-fit residual "
                                               f"{f.rmse / res.height_px:.2f} of the height (limit "
                                               f"{limits.max_residual:g}); not a cone")
    elif fl is not None and abs(fl.angle - fr.angle) > limits.max_flank_diff_deg:
        res.status, res.message = "asymmetric", (f"left and right flanks differ by {abs(fl.angle - fr.angle):.1f} "
                                                 f"deg (limit {limits.max_flank_diff_deg:g}): an asymmetric heap, "
                                                 "or camera yaw")


#: the smallest photograph measured (rows, columns): the floor's ends and the toes are read from its
#: outer 1/12 and 1/40 of the width, and a heap needs 15 px of height
MIN_IMAGE_PX = (20, 40)


def measure_image(gray: np.ndarray | None, band=DEFAULT_BAND, roll_warn_deg: float = 2.0,
                  min_height_px: float = 15.0, limits: ShapeLimits | None = ShapeLimits()) -> ImageAngle:
    """The repose angle of one photograph (module docstring). ``limits``: the checks that a measured
    silhouette is a heap's cone (status ``cut``, ``column``, ``not_cone``, ``asymmetric`` otherwise);
    None measures without them, as simulated heaps are (campaign: their rows must not depend on them)."""
    if gray is None:
        return ImageAngle("unreadable", "not a readable image")
    if gray.ndim == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
    g = cv2.GaussianBlur(gray.astype(np.float64), (5, 5), 0)
    if g.std() < 2.0:
        return ImageAngle("blank", "the image is blank (no contrast)")
    if gray.shape[0] < MIN_IMAGE_PX[0] or gray.shape[1] < MIN_IMAGE_PX[1]:  # a thumbnail left among the photographs
        return ImageAngle("no_heap", f"the image is too small to measure ({gray.shape[1]} x {gray.shape[0]} px; at "
                                     f"least {MIN_IMAGE_PX[1]} x {MIN_IMAGE_PX[0]})")
    seg = _segment(g)
    if seg is None:
        return ImageAngle("no_heap", "no foreground region")
    comp, flat, thr = seg
    H, W = comp.shape
    cols = np.flatnonzero(comp.any(axis=0))
    top = np.argmax(comp, axis=0).astype(float)  # first foreground row per column
    bottom = H - 1 - np.argmax(comp[::-1], axis=0)
    spans_width = len(cols) >= 0.97 * W
    if spans_width:
        # floor strip in the heap's class: the base is the floor surface at both lateral ends
        edge = max(5, W // 12)
        xs = np.r_[np.arange(edge), np.arange(W - edge, W)]
        a, b = _robust_line(xs.astype(float), top[xs])
    else:
        a, b = _robust_line(cols.astype(float), bottom[cols].astype(float) + 1.0)
    tilt = math.atan(b)
    if abs(math.degrees(tilt)) > 10.0:
        # a camera is not rolled this much: one end of the "floor" is heap, cut by the frame
        return ImageAngle("cut", "the heap is cut by the side of the frame (no floor visible on one side)")
    ytop = _top_edge(comp, flat, thr, cols, top)
    # into the base-line frame: s along the base, h above it (image y points down)
    c, s_ = math.cos(tilt), math.sin(tilt)
    xs = np.arange(W, dtype=float) + 0.5
    ok = np.isfinite(ytop)
    base_y = a + b * xs
    hgt = (base_y - ytop) * c
    along = xs * c + (ytop - a) * s_
    if not ok.any():
        return ImageAngle("cut", "the heap touches the top of the frame")
    hmax = float(np.nanmax(np.where(ok, hgt, np.nan)))
    if hmax < min_height_px:
        return ImageAngle("no_heap", f"no heap found (tallest region {hmax:.0f} px above the base)")
    ia = int(np.nanargmax(np.where(ok, hgt, -np.inf)))
    if comp[0].any():
        return ImageAngle("cut", "the heap is cut by the top of the frame", height_px=hmax)
    ends = [x for x in (0, W - 1) if comp[:, x].any()]
    if not spans_width and ends:
        return ImageAngle("cut", "the heap is cut by the side of the frame", height_px=hmax)
    if spans_width and (hgt[: W // 40].max() > 0.1 * hmax or hgt[-(W // 40):].max() > 0.1 * hmax):
        return ImageAngle("cut", "the heap is cut by the side of the frame (no toe visible)", height_px=hmax)
    s0 = along[ia]
    left = ok & (np.arange(W) < ia)
    right = ok & (np.arange(W) > ia)
    fl = fit_flank(s0 - along[left], hgt[left], hmax, band)
    fr = fit_flank(along[right] - s0, hgt[right], hmax, band)
    wall = _wall(along[ok], hgt[ok], hmax) if limits is not None else (0.0, 0.0)
    floor = _floor_share(hgt, hmax) if limits is not None and spans_width else None
    if not (fl.ok and fr.ok):
        res = ImageAngle("no_heap", "no flank could be fitted (is this a heap?)", height_px=hmax)
        if limits is not None:
            _flag(res, limits, wall, floor)  # a column's walls leave no flank to fit
        return res
    res = ImageAngle("ok", "", fl.angle, fr.angle, 0.5 * (fl.angle + fr.angle),
                     float(np.sqrt(0.5 * (fl.rmse**2 + fr.rmse**2))), math.degrees(tilt), hmax,
                     along[ok] - s0, hgt[ok], (fl, fr), (a, b, tilt), s0, comp)
    if abs(fl.angle - fr.angle) > roll_warn_deg:
        res.message = (f"left and right flanks differ by {abs(fl.angle - fr.angle):.1f} deg "
                       "(an asymmetric heap, or camera yaw)")
    if limits is not None:
        _flag(res, limits, wall, floor)
    return res


def overlay(gray: np.ndarray, res: ImageAngle) -> np.ndarray:
    """Annotated image: contour, base line, fitted flanks in the band, angles written on it."""
    img = cv2.cvtColor(gray if gray.ndim == 2 else cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
    H, W = img.shape[:2]
    if res.mask is not None:
        cnts, _ = cv2.findContours(res.mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, cnts, -1, (0, 200, 255), 1)
    if res.base:
        a, b, tilt = res.base
        cv2.line(img, (0, int(round(a))), (W - 1, int(round(a + b * (W - 1)))), (255, 120, 0), 1, cv2.LINE_AA)
        c, s_ = math.cos(tilt), math.sin(tilt)
        for fit, sign in zip(res.fits, (-1, 1)):
            if not fit.ok:
                continue
            pts = []
            for hh in (DEFAULT_BAND[0] * res.height_px, DEFAULT_BAND[1] * res.height_px):
                along = res.apex_along + sign * (hh - fit.intercept) / fit.slope
                # inverse of the base-frame rotation: x = c s + sin h, y = a + sin s - c h
                pts.append((int(round(c * along + s_ * hh)), int(round(a + s_ * along - c * hh))))
            cv2.line(img, pts[0], pts[1], (0, 0, 255), 2, cv2.LINE_AA)
    txt = (f"L {res.angle_left:.2f}  R {res.angle_right:.2f}  mean {res.repose_angle:.2f} deg"
           + ("" if res.status == "ok" else f"  ({res.status})")  # a flagged heap: its angles, and why not counted
           if math.isfinite(res.repose_angle) else f"{res.status}: {res.message}")
    cv2.putText(img, txt, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 255), 2, cv2.LINE_AA)
    return img
