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
   mean, fit RMSE; a left/right difference above ``roll_warn_deg`` is flagged.
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
    status: str  # ok | unreadable | blank | no_heap | cut
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
    data = np.fromfile(str(path), dtype=np.uint8)
    if data.size == 0:
        return None
    return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)


def _flatten(gray: np.ndarray, fg: np.ndarray) -> np.ndarray:
    """Divide out a quadratic illumination field fitted to the background pixels."""
    h, w = gray.shape
    ys, xs = np.nonzero(~fg)
    if len(xs) < 50:
        return gray
    step = max(1, len(xs) // 20000)
    xs, ys = xs[::step], ys[::step]
    x, y = xs / w - 0.5, ys / h - 0.5
    A = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    b = gray[ys, xs].astype(float)
    # BLAS-free solves (profile.lstsq): a photograph's angle is the same on every machine
    coef = lstsq(A, b)
    for _ in range(3):  # reweight: drop pixels far from the fit (shadows, stray grains)
        r = b - combine(A, coef)
        keep = np.abs(r) < 2.5 * (np.median(np.abs(r)) * 1.4826 + 1e-9)
        if keep.sum() < 20:
            break
        coef = lstsq(A[keep], b[keep])
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


def measure_image(gray: np.ndarray | None, band=DEFAULT_BAND, roll_warn_deg: float = 2.0,
                  min_height_px: float = 15.0) -> ImageAngle:
    if gray is None:
        return ImageAngle("unreadable", "not a readable image")
    if gray.ndim == 3:
        gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
    g = cv2.GaussianBlur(gray.astype(np.float64), (5, 5), 0)
    if g.std() < 2.0:
        return ImageAngle("blank", "the image is blank (no contrast)")
    fg0, _, _ = _otsu(g)
    flat = _flatten(g, cv2.dilate(fg0.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0)
    fg, thr, dark_fg = _otsu(flat)
    fg = cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, st, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if n <= 1:
        return ImageAngle("no_heap", "no foreground region")
    big = 1 + int(np.argmax(st[1:, cv2.CC_STAT_AREA]))
    comp = lab == big
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
    # sub-pixel top edge: where the smoothed intensity crosses the threshold between rows
    ytop = np.full(W, np.nan)
    for x in cols:
        y = int(top[x])
        if y <= 0:
            ytop[x] = np.nan  # touches the frame
            continue
        v0, v1 = flat[y - 1, x], flat[y, x]
        if (v1 - v0) != 0:
            f = (thr - v0) / (v1 - v0)
            ytop[x] = (y - 1) + min(max(f, 0.0), 1.0) + 0.5
        else:
            ytop[x] = y
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
    if not (fl.ok and fr.ok):
        return ImageAngle("no_heap", "no flank could be fitted (is this a heap?)", height_px=hmax)
    res = ImageAngle("ok", "", fl.angle, fr.angle, 0.5 * (fl.angle + fr.angle),
                     float(np.sqrt(0.5 * (fl.rmse**2 + fr.rmse**2))), math.degrees(tilt), hmax,
                     along[ok] - s0, hgt[ok], (fl, fr), (a, b, tilt), s0, comp)
    if abs(fl.angle - fr.angle) > roll_warn_deg:
        res.message = (f"left and right flanks differ by {abs(fl.angle - fr.angle):.1f} deg "
                       "(an asymmetric heap, or camera yaw)")
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
           if res.status == "ok" else f"{res.status}: {res.message}")
    cv2.putText(img, txt, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 255), 2, cv2.LINE_AA)
    return img
