"""How much of a simulated heap's scatter would more side views take away? (issue 47: a surrogate that learns more
per heap.) A heap's angle is measured today from one rendered side view, the mean of its two flanks; a pile's
scatter is then partly the heap's own (how high and steep it stood) and partly which two flanks the camera saw.

For every finished heap folder under the given run directories (``RUN/simulate/runs/<hash>/state.parquet``, as
``calib synth-lab`` leaves under ``OUT/.runs`` and a run keeps until its caches are cleared), the final grains
are rendered from V azimuths spread over half a turn (view k looks along the direction at k * 180 / V deg, so
its two flanks are at distinct azimuths) and measured by the same code as the photographs. Heaps that share
everything but their seed (a lab condition's repeats, a design point's two piles) form groups; the table gives
the pooled within-group sd of the angle and the fullness from the first view alone (the one the results rows
hold as ``angle_image``) and from the mean over 2 and 4 views, and f, the ratio of the variances: the share of a
heap's noise variance that V views keep. A surrogate's variance where it is noise-bound scales with f at equal heaps
(``heap_floor.py``'s emulation), while the lab's measured means keep their one-view photographs' variance. Since
2026-12-06 every heap's row records its 4 views' means (``angle_views``, ``fullness_views``) and the surrogates
learn from them, f estimated on each fit's own repeated piles (``GPSurrogate.view_share_``).

    .venv/bin/python benchmarks/heap_views.py /tmp/views/he-lab/.runs /tmp/views/ctl-lab/.runs

the labs of ``stages/hidden-effect.toml`` and ``control-lab.toml`` made again (60 heaps each, ~5 min on 2 cores):

    calib synth-lab --out /tmp/views/he-lab --hidden cohesion --set static_friction=0.45 \
        --set rolling_friction=0.15 --set restitution=0.3 --set surface_energy=0.6 --sizes 4-5,5-6 \
        --cylinders 40 --fills 50,75,100 --repeats 10 --preset default --workers 2
    (the control: --out /tmp/views/ctl-lab --hidden none --set surface_energy=0, the rest alike)

(docs/method.md's third lab is hidden-capillary's, from its ``lab/.runs`` before the caches were cleared.)
"""
from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

VIEWS = (1, 2, 4)


def _views(state: pd.DataFrame, n: int) -> list:
    """The n views' measurements (ImageAngle), view 0 the results row's own: the views a campaign renders
    (:func:`calib_cli.dem.render.side_views`), measured as it measures them."""
    from calib_cli.dem.render import side_views
    from calib_cli.imaging.measure import measure_image

    xyz, rad = state[["x", "y", "z"]].to_numpy(float), state["radius"].to_numpy(float)
    return [measure_image(v.image, limits=None) for v in side_views(xyz, rad, n)]


def heap_table(runs: list[Path], n: int = max(VIEWS)) -> pd.DataFrame:
    """One row per heap: its group (every key but the seed), and each view's angle and fullness."""
    from calib_cli.profile import fullness

    rows = []
    for run in runs:
        for folder in sorted((run / "simulate/runs").glob("*/")):
            if not (folder / "state.parquet").is_file() or not (folder / "key.json").is_file():
                continue
            key = json.loads((folder / "key.json").read_text())
            key.pop("seed", None)
            row = {"run": str(run), "group": json.dumps(key, sort_keys=True), "heap": folder.name,
                   "row_angle": json.loads((folder / "result.json").read_text()).get("angle_image")}
            for k, m in enumerate(_views(pd.read_parquet(folder / "state.parquet"), n)):
                ok = m.status == "ok"
                row[f"angle_{k}"] = m.repose_angle if ok else np.nan
                row[f"fullness_{k}"] = fullness(m.profile_s, m.profile_h) if ok else np.nan
            rows.append(row)
    return pd.DataFrame(rows)


def scatter(heaps: pd.DataFrame, what: str) -> dict:
    """Pooled within-group sd of ``what`` (angle or fullness) from 1, 2 and 4 views, and f = var(V) / var(1)."""
    n = max(VIEWS)
    step = {1: [0], 2: [0, n // 2], 4: list(range(n))}
    out = {}
    for v in VIEWS:
        x = heaps[[f"{what}_{k}" for k in step[v]]].mean(axis=1, skipna=False)
        g = x.groupby(heaps["group"])
        dev = (x - g.transform("mean")).dropna()
        dof = int((g.count() - 1).clip(lower=0).sum())
        out[v] = float(np.sum(dev ** 2) / dof)
    return {"groups": heaps["group"].nunique(), "heaps": len(heaps), "dof": dof,
            **{f"sd {v} view{'s' * (v > 1)}": np.sqrt(out[v]) for v in VIEWS},
            **{f"f {v}": out[v] / out[1] for v in VIEWS[1:]}}


def main() -> None:
    runs = [Path(a) for a in sys.argv[1:]]
    heaps = heap_table(runs)
    same = np.isclose(heaps["row_angle"].astype(float), heaps["angle_0"], atol=1e-9, equal_nan=True).mean()
    print(f"{len(heaps)} heaps; view 0 equals the results row's angle in {same:.0%} of them")
    table = [{"runs": str(run), "response": what, **scatter(heaps[heaps["run"] == str(run)], what)}
             for run in runs for what in ("angle", "fullness")]
    print(pd.DataFrame(table).round(3).to_string(index=False))


if __name__ == "__main__":
    main()
