"""The README's picture: a sample photograph with its fitted flanks beside a heap simulated at the
calibrated parameters (the first `compare` heap of the run), measured by the same code.

    .venv/bin/python docs/figures/readme_heaps.py sample_runs/calibration docs/figures/heaps.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from calib_cli.dem.heap import run_heap
from calib_cli.dem.render import render_side_view
from calib_cli.heaps.index import load_results
from calib_cli.heaps.inputs import request_from_row
from calib_cli.imaging.measure import measure_image, overlay


def _label(img: np.ndarray, text: str) -> np.ndarray:
    band = np.full((34, img.shape[1], 3), 255, np.uint8)
    cv2.putText(band, text, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 2, cv2.LINE_AA)
    return np.vstack([band, img])


def _fit_width(img: np.ndarray, width: int) -> np.ndarray:
    h = round(img.shape[0] * width / img.shape[1])
    return cv2.resize(img, (width, h), interpolation=cv2.INTER_AREA)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("out", type=Path)
    a = ap.parse_args()
    angles = pd.read_parquet(a.run / "measure" / "angles.parquet")
    first = angles[angles["status"] == "ok"].iloc[0]
    photo = cv2.imread(str(a.run / "measure" / "overlays" / Path(first["image"]).with_suffix(".png").name))
    res = load_results(a.run)
    row = res[res["design"] == "compare"].iloc[0]
    req = request_from_row(row)
    heap = run_heap(req.params, req.condition, req.numerics, req.seed)
    p = heap.system.particles
    gray = render_side_view(p.pos, p.rad).image
    sim = overlay(gray, measure_image(gray))
    w = 760
    left = _label(_fit_width(photo, w), f"photograph {Path(first['image']).stem}: {first['repose_angle']:.1f} deg")
    right = _label(_fit_width(sim, w), f"simulated at the calibrated parameters: {row['repose_angle']:.1f} deg")
    gap = np.full((12, w, 3), 255, np.uint8)
    cv2.imwrite(str(a.out), np.vstack([left, gap, right]))
    print(f"wrote {a.out}: photo {first['repose_angle']:.2f} deg, simulated heap {row['repose_angle']:.2f} deg "
          f"(committed row) / {heap.angle.angle:.2f} deg (coordinates)")


if __name__ == "__main__":
    main()
