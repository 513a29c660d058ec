"""Rendered side view of particles: an orthographic silhouette, as a camera sees a heap.

The image is what ``measure-angle`` reads, so simulation and photograph pass through the
same measurement operator (SPEC section 5). Dark particles on a light background with a
dark floor strip below z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class SideView:
    image: np.ndarray  # uint8 grayscale (H, W)
    px_per_m: float
    floor_row: int  # image row of z = 0
    center_col: float  # image column of x = 0


def render_side_view(pos: np.ndarray, rad: np.ndarray, px_per_m: float = 4000.0, margin: float = 0.15,
                     floor_px: int = 12, view_axis: int = 1, half_depth: float | None = None) -> SideView:
    """Project onto the plane normal to ``view_axis`` (1: look along y, see x-z).

    ``half_depth`` keeps only particles within that distance of the plane through the axis
    (a slice); None renders every particle (a silhouette, as a photograph).
    """
    h_axis = 0 if view_axis != 0 else 1
    keep = np.ones(len(rad), bool) if half_depth is None else np.abs(pos[:, view_axis]) <= half_depth
    x = pos[keep, h_axis]
    z = pos[keep, 2]
    r = rad[keep]
    half_w = max(float(np.max(np.abs(x) + r)) if x.size else 0.01, 0.01) * (1 + margin)
    top = max(float(np.max(z + r)) if z.size else 0.01, 0.01) * (1 + margin)
    W = int(np.ceil(2 * half_w * px_per_m))
    H = int(np.ceil(top * px_per_m)) + floor_px
    img = np.full((H, W), 235, np.uint8)
    floor_row = H - floor_px
    img[floor_row:, :] = 40
    cx = W / 2.0
    shift = 4  # sub-pixel circle centres
    for xi, zi, ri in zip(x, z, r):
        c = (int(round((cx + xi * px_per_m) * (1 << shift))), int(round((floor_row - zi * px_per_m) * (1 << shift))))
        cv2.circle(img, c, int(round(ri * px_per_m * (1 << shift))), 25, -1, lineType=cv2.LINE_AA, shift=shift)
    return SideView(img, px_per_m, floor_row, cx)


#: side views a simulated heap is measured from: view k looks along the direction at k * 180 / SIDE_VIEWS deg
#: about the cylinder's axis, so no two views share a flank. Four keep 0.52-0.69 of one view's pile-to-pile
#: variance of the angle and the fullness on three labs (docs/method.md, "Calibrating in rounds")
SIDE_VIEWS = 4


def turned(pos: np.ndarray, angle: float) -> np.ndarray:
    """The grains' positions turned by ``angle`` (rad) about the vertical axis through x = y = 0 (the
    cylinder's axis): rendering them is the camera moved round the heap by -angle."""
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([c * pos[:, 0] - s * pos[:, 1], s * pos[:, 0] + c * pos[:, 1], pos[:, 2]])


def side_views(pos: np.ndarray, rad: np.ndarray, n: int = SIDE_VIEWS) -> list[SideView]:
    """``n`` silhouettes over half a turn (:data:`SIDE_VIEWS`); view 0 is :func:`render_side_view`'s own."""
    return [render_side_view(pos, rad)] + [render_side_view(turned(pos, np.pi * k / n), rad) for k in range(1, n)]
