"""Synthetic heap photographs of known angle (tests; the hidden-effect lab).

An analytic cone with a granular surface (grain-sized bumps along its flanks) standing on a
floor, drawn 4x supersampled and downsampled so that edges are anti-aliased like a camera's,
with optional disturbances: polarity, illumination gradient, a shadow, Gaussian noise, blur,
camera roll, loose grains scattered at the toe, a rounded apex and toe. A DEM final state is
rendered with :func:`calib_cli.dem.render.render_side_view` instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SynthOptions:
    width: int = 640
    height: int = 480
    heap_height_px: float = 160.0
    base_row: float = 400.0
    grain_px: float = 6.0  # grain diameter in pixels (surface roughness; 0: a smooth surface)
    dark_heap: bool = True
    floor_strip: bool = True  # a floor in the heap's class below the base
    gradient: float = 0.0  # relative illumination change across the image (0.4 = +-20 %)
    shadow: bool = False
    noise_sd: float = 0.0  # grey levels
    blur_px: float = 0.0
    roll_deg: float = 0.0
    scattered: int = 0  # loose grains on the floor beyond the toe
    apex_round_px: float = 0.0
    toe_round_px: float = 0.0
    center_frac: float = 0.5


def _profile(x: np.ndarray, angle: float, o: SynthOptions, xc: float) -> np.ndarray:
    """Height above the base of an ideal cone, with optional rounding at apex and toe."""
    t = math.tan(math.radians(angle))
    H = o.heap_height_px
    h = np.maximum(H - np.abs(x - xc) * t, 0.0)
    if o.apex_round_px > 0:  # smooth cap: quadratic within apex_round_px of the apex
        d = np.abs(x - xc)
        r = o.apex_round_px
        cap = H - r * t / 2 - d * d * t / (2 * r)
        h = np.where(d < r, cap, h)
    if o.toe_round_px > 0:
        # a parabolic fillet tangent to the flank at toe - r and to the floor at toe + r
        toe, r = H / t, o.toe_round_px
        s = np.abs(x - xc)
        h = np.where(np.abs(s - toe) < r, t * (toe + r - s) ** 2 / (4 * r), h)
    return h


def synth_heap(angle: float, options: SynthOptions | None = None, seed: int = 0) -> np.ndarray:
    """A grayscale heap image whose flanks make ``angle`` degrees with its base."""
    o = options or SynthOptions()
    rng = np.random.default_rng(seed)
    k = 4  # supersampling
    W, H = o.width * k, o.height * k
    xc = o.center_frac * W
    fg, bg = (40.0, 215.0) if o.dark_heap else (215.0, 40.0)
    img = np.full((H, W), bg, np.float32)
    base = o.base_row * k
    x = np.arange(W) + 0.5
    kk = SynthOptions(**{**o.__dict__, "heap_height_px": o.heap_height_px * k, "apex_round_px": o.apex_round_px * k,
                         "toe_round_px": o.toe_round_px * k})
    h = _profile(x, angle, kk, xc)
    # the body of the heap
    Y = np.arange(H)[:, None] + 0.5
    img[(Y >= base - h[None, :]) & (Y <= base)] = fg
    if o.floor_strip:
        img[int(base):, :] = fg
    # granular surface: grains half embedded along the flanks
    g = o.grain_px * k
    t = math.tan(math.radians(angle))
    n_grains = int(2 * o.heap_height_px * k / t / g * 1.5) if g > 0 else 0
    for _ in range(n_grains):
        xs = xc + rng.uniform(-1, 1) * kk.heap_height_px / t
        hs = np.interp(xs, x, h)
        if hs <= 0:
            continue
        depth = rng.uniform(0.3, 0.6) * g / 2
        r = g / 2 * rng.uniform(0.8, 1.1)
        # centre (r - depth) out along the flank's outward normal (sign t, -1)/sqrt(1 + t^2), image y down
        off = (r - depth) / math.hypot(t, 1.0)
        cx = xs + np.sign(xs - xc) * t * off
        cy = base - hs - off
        cv2.circle(img, (int(cx), int(cy)), int(r), float(fg), -1)
    for _ in range(o.scattered):
        toe = kk.heap_height_px / t
        side = rng.choice([-1, 1])
        xs = xc + side * (toe + rng.uniform(3, 12) * g)
        cv2.circle(img, (int(xs), int(base - g / 2)), int(g / 2), float(fg), -1)
    img = cv2.resize(img, (o.width, o.height), interpolation=cv2.INTER_AREA)
    if o.shadow:
        sh = np.zeros_like(img)
        cv2.ellipse(sh, (int(o.width * 0.75), int(o.base_row - 20)), (90, 50), 0, 0, 360, 1.0, -1)
        sh = cv2.GaussianBlur(sh, (0, 0), 15)
        bgmask = np.abs(img - bg) < 1
        img = np.where(bgmask, img * (1 - 0.25 * sh), img)
    if o.gradient:
        ramp = 1 + o.gradient * (np.arange(o.width)[None, :] / o.width - 0.5)
        vr = 1 + 0.5 * o.gradient * (np.arange(o.height)[:, None] / o.height - 0.5)
        img = img * ramp * vr
    if o.roll_deg:
        M = cv2.getRotationMatrix2D((o.width / 2, o.height / 2), o.roll_deg, 1.0)
        img = cv2.warpAffine(img, M, (o.width, o.height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if o.blur_px:
        img = cv2.GaussianBlur(img, (0, 0), o.blur_px)
    if o.noise_sd:
        img = img + rng.normal(0, o.noise_sd, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)
