"""Write the shipped sample photographs: synthetic heaps of known angle (sample_data/photos/).

Five photographs of one condition, angles drawn around 32 deg with a pile-to-pile sd of 1 deg,
with noise, an illumination gradient, a slight camera roll and loose grains. The truth goes to
truth.toml beside them; no stage reads it. Rerun with `make sample-photos`.
"""

from pathlib import Path

import cv2
import numpy as np

from calib_cli.imaging.synth import SynthOptions, synth_heap

out = Path(__file__).resolve().parents[1] / "sample_data" / "photos"
out.mkdir(parents=True, exist_ok=True)
rng = np.random.default_rng(2026)
angles = np.round(rng.normal(32.0, 1.0, 5), 2)
lines = ["image,condition_id,particle_d_min_mm,particle_d_max_mm,cylinder_diameter_mm,fill_height_mm,lift_speed_mm_s"]
for i, a in enumerate(angles, start=1):
    opts = SynthOptions(noise_sd=3.0, gradient=0.2, roll_deg=float(rng.uniform(-1.5, 1.5)), scattered=3,
                        apex_round_px=12, toe_round_px=8)
    name = f"heap_{i:02d}.png"
    cv2.imwrite(str(out / name), synth_heap(float(a), opts, seed=i), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    lines.append(f"{name},A,6,8,50,50,100")
(out / "conditions.csv").write_text("\n".join(lines) + "\n")
(out / "truth.toml").write_text("# synthetic: the angle each photograph was drawn with (deg)\n"
                                + "".join(f'"heap_{i:02d}.png" = {a}\n' for i, a in enumerate(angles, 1)))
print("wrote", out, angles)
