"""Which rule of `calib calibrate` places its later rounds' heaps best, side by side in one run: the
variance rule (the surrogates' variance at the posterior's draws reduced most), max-sd (the largest
variance) and draws (posterior draws at random), on a stand-in lab whose truth is known.

The stand-in is hidden-effect-like: four parameters (static and rolling friction, restitution, surface
energy) and six conditions (two grain sizes x three fills); cohesion raises small grains' and small
heaps' angles, rolling friction every angle, so from the mean angles the two trade off; piles scatter
by 2 deg, plus up to 3 deg more with cohesion (so the scatter is evidence too). Each calibration runs the
real stage (calib_cli.stages.calibrate) with a stand-in campaign, which makes every heap instantly.
Prints, per rule, over the seeds: heaps simulated until the stop rule (or the budget), the mean 90 %
interval width over the prior range, the share of intervals holding the truth, how often
cohesion's verdict came out right (called for: Bayes factor of off < 0.1), and the answer's surrogate
ratio and Bayes factor of off. ``--repeats 2,1`` sets each rule beside itself with one pile a point;
``--batches 24,12`` beside itself with other batch sizes (heaps a later round; default the stage's, 4 per
input). ``decided_at``: the heaps simulated when a round's surrogate ratio first fell to 1 or below (the
bar under which a verdict is stated), a count the stop rule does not bend (a smaller batch moves the
intervals less per round, which is why the rule looks back a default batch of heaps, not one round).

    python benchmarks/acquisition_rules.py --seeds 4 --budget 250 --rules variance,max-sd,draws --repeats 2,1
    python benchmarks/acquisition_rules.py --seeds 4 --budget 250 --rules variance --batches 24,12
"""
from __future__ import annotations

import argparse
import importlib
import tempfile
import time
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

from calib_cli import artifacts as art
from calib_cli.dem.heap import condition_dict
from calib_cli.heaps.index import append_index
from calib_cli.model import Model, save_model
from calib_cli.stages import calibrate as cal

TRUTH = {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6}
SIZES, FILLS = (4.0, 5.0), (50.0, 75.0, 100.0)
PRIOR = "".join(f"[factors.{p}]\nlow = {lo}\nhigh = {hi}\n" for p, (lo, hi) in
                {"static_friction": (0.3, 0.7), "rolling_friction": (0.1, 0.3), "restitution": (0.1, 0.5),
                 "surface_energy": (0.0, 1.6)}.items())


def mean_angle(p: dict, d: float, fill: float) -> float:
    """The stand-in's mean angle (deg)."""
    return (18 + 14 * p["static_friction"] + 38 * p["rolling_friction"] - 3 * p["restitution"]
            + 9 * p["surface_energy"] * (4.5 / d) * (75 / fill) ** 0.5 - 2 * p["surface_energy"] ** 2)


def pile_sd(p: dict) -> float:
    return 2.0 + 3.0 * min(p["surface_energy"], 1.0)


def campaign(requests, run_dir, workers=1, on_done=None, dask=None, **kw):
    """Every requested heap, instantly: the stand-in's angle plus its pile scatter, seeded by the request."""
    rows = []
    for q in requests:
        rng = np.random.default_rng(q.seed)
        c = condition_dict(q.condition)
        rows.append({"run_hash": q.hash, "design": q.design, "run_id": q.run_id, "repeat": q.repeat, "seed": q.seed,
                     "preset": q.preset, "condition_id": q.condition_id, "model": q.model, "engine": q.engine,
                     **q.params, **c, "status": "ok", "source": q.source,
                     "repose_angle": mean_angle(q.params, c["particle_d_min_mm"], c["fill_height_mm"])
                     + rng.normal(0, pile_sd(q.params))})
    append_index(run_dir, rows)
    return pd.DataFrame(rows)


def lab(run: Path, seed: int) -> None:
    """Ten piles at the truth under each condition, and the model with cohesion."""
    rng = np.random.default_rng(seed)
    rows = []
    for d in SIZES:
        for h in FILLS:
            piles = mean_angle(TRUTH, d, h) + rng.normal(0, pile_sd(TRUTH), 10)
            rows.append({"condition_id": f"d{d:g}_H{h:g}", "particle_d_min_mm": d, "particle_d_max_mm": d + 1,
                         "cylinder_diameter_mm": 40.0, "fill_height_mm": h, "mean": piles.mean(),
                         "sd": piles.std(ddof=1), "n": 10})
    art.write_table(run / "measure" / "conditions.parquet", pd.DataFrame(rows))
    save_model(run, Model(("sliding_friction", "rolling_friction", "restitution", "cohesion")))
    (run / "settings.toml").write_text(PRIOR)  # the hidden-effect lab's factor table


def one(rule: str, seed: int, budget: int, root: Path, repeats: int = 2, batch: int | None = None) -> dict:
    run = root / f"{rule}-{repeats}-{batch}-{seed}"
    lab(run, 1000 + seed)
    t0 = time.perf_counter()
    r = cal.calibrate(run, budget=budget, rule=rule, repeats=repeats, batch=batch, walkers=24, steps=1000,
                      seed=seed, say=lambda *a, **k: None)
    t = r.table.set_index("parameter")
    se = t.loc["surface_energy"]
    per_round = r.rounds.drop_duplicates("round")
    sure = per_round[per_round["surrogate_ratio"] <= 1.0]
    name = rule + ("" if repeats == 2 else f" x{repeats}") + ("" if batch is None else f" batch {batch}")
    return {"rule": name, "seed": seed,
            "heaps": int(r.rounds["calibration_heaps"].max()),
            "decided_at": float(sure["calibration_heaps"].min()) if len(sure) else np.nan,
            "stopped": r.stop.split(":")[0], "width": float(t["rel_width"].mean()),
            "held": float(np.mean([t.loc[p, "q05"] <= v <= t.loc[p, "q95"] for p, v in TRUTH.items()])),
            "called_for": bool(se["decided"] and se["bf_off"] < 0.1), "ratio": float(se["surrogate_ratio"]),
            "bf_off": float(se["bf_off"]), "s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--budget", type=int, default=250)
    ap.add_argument("--rules", default="variance,max-sd,draws")
    ap.add_argument("--repeats", default="2", help="piles a design point, comma-separated to compare (e.g. 2,1)")
    ap.add_argument("--batches", default="", help="heaps a later round, comma-separated to compare (e.g. 24,12); "
                    "default the stage's")
    a = ap.parse_args()
    cal.run_campaign = campaign
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(a.seeds):
            for rule in a.rules.split(","):
                for reps in (int(r) for r in a.repeats.split(",")):
                    for batch in [int(b) for b in a.batches.split(",") if b] or [None]:
                        out.append(one(rule, seed, a.budget, Path(tmp), reps, batch))
                        print(out[-1], flush=True)
    df = pd.DataFrame(out)
    summary = df.groupby("rule", sort=False).agg(
        heaps=("heaps", "mean"), decided_at=("decided_at", "mean"),
        never_decided=("decided_at", lambda s: int(s.isna().sum())),
        stopped_by_rule=("stopped", lambda s: float(np.mean(s == "stable"))),
        width=("width", "mean"), held=("held", "mean"), called_for=("called_for", "mean"),
        ratio=("ratio", "median"), bf_off=("bf_off", "median"), s=("s", "mean"))
    print(f"\n{a.seeds} seeds, budget {a.budget}: mean over seeds (width: 90 % interval over the prior range; "
          "held: intervals holding the truth; called_for: cohesion's Bayes factor of off < 0.1, decided; "
          "ratio, bf_off: the answer's surrogate ratio and cohesion's Bayes factor of off, medians)")
    print(summary.to_string(float_format=lambda v: f"{v:.3g}"))
    first = summary.index[0]
    for col in ("heaps", "decided_at"):
        print(f"{col} relative to {first}: "
              + ", ".join(f"{k} {v / summary.loc[first, col]:.2f}" for k, v in summary[col].items()))


if __name__ == "__main__":
    main()
