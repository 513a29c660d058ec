"""Makes gpu_run/he_rev1 for benchmarks/gpu_device.sh: the hidden-effect sample run as it stood when its
revision-1 calibration began (settings, model revision 1, measurements, revision 0's rounds, and the 204
heaps' rows at hand then: every row but revision 1's own calibration and compare heaps), so that
`calib calibrate --at-revision 1 --engine gpu` there repeats that calibration on the GPU engine.

    python benchmarks/gpu_device_prep.py [--src sample_runs/hidden-effect] [--out gpu_run/he_rev1]
"""
import argparse
import importlib
import json
import shutil
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import pandas as pd

from calib_cli.artifacts import file_hash


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", default="sample_runs/hidden-effect")
    ap.add_argument("--out", default="gpu_run/he_rev1")
    a = ap.parse_args()
    src, out = Path(a.src), Path(a.out)
    shutil.rmtree(out, ignore_errors=True)
    (out / "simulate").mkdir(parents=True)
    for name in ("settings.toml", "model.toml"):
        shutil.copy(src / name, out / name)
    shutil.copytree(src / "model", out / "model")
    shutil.copytree(src / "measure", out / "measure", ignore=shutil.ignore_patterns("overlays"))
    shutil.copytree(src / "calibrate" / "rev0", out / "calibrate" / "rev0")
    for lock in (src / "calibrate").glob("rev0*.lock.json"):
        shutil.copy(lock, out / "calibrate" / lock.name)
    rounds = pd.read_parquet(src / "calibrate" / "rounds.parquet")
    rounds[rounds["revision"] == 0].to_parquet(out / "calibrate" / "rounds.parquet", index=False)
    # revision 0's lock vouches for rounds.parquet as it wrote it: this one, without revision 1's rows, else the
    # calibration's last write refuses it as changed by hand (seen on the GPU, 2026-11-28)
    lock = out / "calibrate" / "rev0.lock.json"
    held = json.loads(lock.read_text())
    held["outputs"]["rounds.parquet"] = file_hash(out / "calibrate" / "rounds.parquet")
    lock.write_text(json.dumps(held, indent=2))
    rows = pd.read_parquet(src / "simulate" / "results.parquet")
    rev1 = pd.read_parquet(src / "calibrate" / "rev1" / "round-00" / "reused.parquet")
    # revision 1's model: that of the calibration heaps that were not at hand when it began
    later = rows[(rows["design"] == "calibrate") & ~rows["run_hash"].isin(rev1["run_hash"])]
    own = rows["model"].isin(set(later["model"])) & rows["design"].isin(["calibrate", "compare"])
    rows[~own].to_parquet(out / "simulate" / "results.parquet", index=False)
    print(f"{out}: {int((~own).sum())} heaps' rows at hand ({int(own.sum())} of revision 1's own left out)")


if __name__ == "__main__":
    main()
