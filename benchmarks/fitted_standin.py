"""How many heaps would revision 1 of a sample lab's loop need under other round sizes, weighings or aims, on a
stand-in fitted to that lab's own heaps? Side by side in one run, nothing simulated (but with ``--real``).

The stand-in: the lab's surface as the committed run learnt it from all its heaps (the angle's and the
fullness's Gaussian processes, fitted as the answer's are), each new pile that surface's mean plus its
pile scatter there (the angle's sd from the scatter model, the fullness's from its process, the two
correlated as the lab's photographs are). Revision 1 starts where the committed run's did: a copy of the
run with the rows at hand then (revision 0's, compare's and diagnose's real heaps; as
benchmarks/gpu_device_prep.py makes it), and the real stage (calib_cli.stages.calibrate) runs with a
stand-in campaign. ``--firsts`` sets round 0's heaps (0: the stage's default), ``--batches`` a later round's,
``--weighs`` how a later round weighs the two responses' variances, ``--targets`` which draws it aims at;
``--real`` simulates the new heaps instead (about 45 minutes a calibration on 2 cores).
Prints per setting and seed: the heaps learnt from when a round's surrogate ratio first fell to 1 or below
(``decided_at``), those at the stop, why it stopped, how many of the 90 % intervals held the truth, and each
round's heaps and ratio. A surface drawn from the surrogate's own kind of function flatters it: on
hidden-effect the default decided at 276 here and at 348 for real.

    python benchmarks/fitted_standin.py --src sample_runs/hidden-effect --firsts 0,48,24 --seeds 0,1
    python benchmarks/fitted_standin.py --src sample_runs/control-lab --firsts 0,24 --seeds 0
    python benchmarks/fitted_standin.py --src sample_runs/hidden-effect --targets tempered,mix --seeds 0,1
    python benchmarks/fitted_standin.py --src sample_runs/hidden-effect --firsts 24,0 --targets plugin --seeds 0
    python benchmarks/fitted_standin.py --src sample_runs/hidden-effect --real --firsts 24 --targets tempered --seeds 0
    python benchmarks/fitted_standin.py --src sample_runs/hidden-effect --views 0,1 --seeds 0,1

``--views 0,1``: every pile, those at hand redrawn too, gets 4 side views (:func:`pile`), and the rounds learn from
one view (0) or the views' mean (1, ``calibrate --side-views``).
"""
from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

# first: calib_cli pins OpenBLAS's kernels before numpy loads, as the command line does (calib_cli/blas.py)
importlib.import_module("calib_cli")
import numpy as np
import pandas as pd

from calib_cli.heaps.index import append_index
from calib_cli.dem.heap import condition_dict
from calib_cli.posterior import adaptive
from calib_cli.posterior.profiles import FULLNESS
from calib_cli.stages import calibrate as cal
from heap_floor import _answer, _profile  # this script's folder is on the path when it runs

TRUTHS = {"hidden-effect": {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.6},
          "control-lab": {"static_friction": 0.45, "rolling_friction": 0.15, "restitution": 0.3, "surface_energy": 0.0}}


def surfaces(src: Path):
    """The lab's angle and fullness processes fitted on every heap of its final model (as heap_floor.py reads its
    answer), the lab's rho, a row to copy the heaps' other columns from, and the prior's box."""
    a = _answer(src)
    full = _profile(a)
    return a.gp, full.gp, full.rho, a.rows.iloc[0].to_dict(), a.bounds


#: the share of one view's pile variance the mean of 4 side views keeps, angle and fullness (benchmarks/heap_views.py:
#: 0.59-0.69 and 0.52-0.62 on three labs)
SHARES = (0.65, 0.57)


def pile(angle, full, rho, x: pd.DataFrame, seed: int) -> dict:
    """One stand-in pile at x: its one view's angle and fullness (the surfaces' means plus their pile scatter, the
    two correlated by rho) and their means over 4 side views. A view's value is the heap's own (variance
    (4 f - 1) / 3 of one view's) plus which flanks it caught (4 (1 - f) / 3, apart in each view), so that one view
    scatters as the surfaces' piles do and the 4 views' mean by f of it (:data:`SHARES`)."""
    g = np.random.default_rng(seed)
    z = g.normal(size=(2, 5))  # per response: the heap's own, then one per view
    z[1] = rho * z[0] + np.sqrt(1 - rho ** 2) * z[1]
    out = {}
    for k, (gp, name, views, f) in enumerate(((angle, "repose_angle", "angle_views", SHARES[0]),
                                              (full, FULLNESS, "fullness_views", SHARES[1]))):
        m, sd = float(gp.predict(x[gp.inputs_])[0]), float(gp.pile_sd(x[gp.inputs_])[0])
        seen = m + sd * (np.sqrt((4 * f - 1) / 3) * z[k, 0] + np.sqrt(4 * (1 - f) / 3) * z[k, 1:])
        out.update({name: float(seen[0]), views: float(seen.mean())})
    return {**out, "side_views": 4}


def stand_in(angle, full, rho, template):
    def campaign(requests, run_dir, workers=1, on_done=None, dask=None, **kw):
        out = []
        for q in requests:
            c = condition_dict(q.condition)
            out.append({**template, "run_hash": q.hash, "design": q.design, "run_id": q.run_id, "repeat": q.repeat,
                        "seed": q.seed, "preset": q.preset, "condition_id": q.condition_id, "model": q.model,
                        "engine": q.engine, **q.params, **c, "status": "ok", "source": q.source,
                        **pile(angle, full, rho, pd.DataFrame([{**q.params, **c}]), q.seed)})
        append_index(run_dir, out)
        return pd.DataFrame(out)
    return campaign


def redraw_at_hand(run: Path, angle, full, rho) -> None:
    """The heaps at hand drawn from the stand-in too (``--views``): each formed heap of the model's parameters given
    its one view and 4 views' means as :func:`pile` draws them, seeded by its seed, so that a run learning from one
    view and one learning from the views start from the same heaps."""
    from calib_cli import artifacts as art
    from calib_cli.heaps.index import RESULTS

    rows = pd.read_parquet(run / RESULTS)
    x = rows.assign(**{p: rows[p].fillna(0.0) if p in rows.columns else 0.0 for p in angle.parameters})
    new = [pile(angle, full, rho, x.iloc[[i]], int(rows["seed"].iloc[i])) if rows["status"].iloc[i] == "ok"
           else {"side_views": 0} for i in range(len(rows))]
    rows = pd.concat([rows.drop(columns=[c for c in ("repose_angle", FULLNESS) if c in rows.columns]),
                      pd.DataFrame(new, index=rows.index)], axis=1)
    art.write_table(run / RESULTS, rows)


_plain_greedy = adaptive._greedy


def _combined_greedy(P, w, tau2, n_eval, picks, integrated):
    """The variance rule with each response's terms weighed by 1 / (1 + r_j)^2, r_j its ratio now: the slope of
    the combined ratio the bar reads, 1 / (1 + r) = mean_j 1 / (1 + r_j), in each response's ratio (the stage
    weighs the responses alike, as if the bar were their sum)."""
    r = [float(np.sum(np.diag(Pj)[:n_eval] * wj[:n_eval])) for Pj, wj in zip(P, w)]
    return _plain_greedy(P, [wj / (1 + rj) ** 2 for wj, rj in zip(w, r)], tau2, n_eval, picks, integrated)


_plain_acquire = cal.acquire


_plain_surrogates = cal._surrogates


def plugin(fit, samples: pd.DataFrame, measured: pd.DataFrame, seed: int) -> pd.DataFrame:
    """The posterior's draws resampled to the posterior whose likelihood leaves the surrogates' own variance out
    (the measured means' alone, V0, against V0 + S): weights N(r; 0, V0) / N(r; 0, V0 + S) at each draw, r the
    residuals of both responses. Where the rounds end the surrogates' variance is small beside the measured
    means', so this is where the posterior is heading if the surrogates' means are right; resampling keeps it
    inside the last posterior's support."""
    from calib_cli.posterior.calibrate import _inputs, _joint_terms, mvn_logpdf, response_variances
    gp, second = fit.gp, fit.second
    names = [p for p in samples.columns if p in gp.parameters]
    t, C = samples[names].to_numpy(float), len(measured)
    cv = {c: measured[c].to_numpy(float) for g in (gp, second.gp if second else gp) for c in g.inputs_
          if c not in g.parameters}
    X = _inputs(gp, t, names, {}, cv, C)
    X2 = _inputs(second.gp, t, names, {}, cv, C) if second else None
    (_, v), *rest = response_variances(gp, measured, second)
    r, V = _joint_terms(gp, second, X, X2, measured["mean"].to_numpy(float), v, rest[0][1] if rest else None)
    V0 = V.copy()
    V0[:, :C, :C] -= gp.predict_joint(X)[1]
    if second:
        V0[:, C:, C:] -= second.gp.predict_joint(X2)[1]
    lw = mvn_logpdf(r, V0) - mvn_logpdf(r, V)
    w = np.exp(lw - lw.max())
    w /= w.sum()
    print(f"  plugin: effective draws {1 / np.sum(w ** 2):.0f} of {len(w)}", flush=True)
    pick = np.random.default_rng(seed).choice(len(w), len(w), p=w)
    return samples.iloc[pick].reset_index(drop=True)


def aiming(targets: str, box: dict):
    """The stage's ``acquire`` aimed at other draws than the last posterior's: ``posterior`` (the stage's),
    ``tempered`` (each draw pushed away from the medians by sqrt(2), the spread of the posterior with its
    likelihood's exponent halved were it Gaussian, kept in the prior's box), ``mix`` (the last two
    posteriors' draws together): where the posterior may go next, not only where it is; or ``plugin`` (the
    posterior were the surrogates exact, :func:`plugin`): where it narrows to."""
    last: list[pd.DataFrame] = []
    fits: list = []

    def surrogates(run, model, prev, conds, plan):
        fits.append(prev.fit)
        return _plain_surrogates(run, model, prev, conds, plan)
    cal._surrogates = surrogates

    def acquire(surrogates, samples, measured, pairs, repeats=2, rule="variance", seed=0):
        aim = samples
        if targets == "plugin" and fits and fits[-1] is not None:
            aim = plugin(fits[-1], samples, measured, seed)
        elif targets == "tempered":
            names = [p for p in samples.columns if p in box]
            med = samples[names].median()
            aim = samples.copy()
            for p in names:
                aim[p] = np.clip(med[p] + np.sqrt(2.0) * (samples[p] - med[p]), *box[p])
        elif targets == "mix" and last:
            aim = pd.concat([last[-1].sample(len(samples), replace=True, random_state=seed), samples],
                            ignore_index=True).sample(frac=1.0, random_state=seed).reset_index(drop=True)
        last.append(samples)
        return _plain_acquire(surrogates, aim, measured, pairs, repeats, rule, seed)
    return acquire


def one(src: Path, root: Path, first, batch, seed: int, budget: int, truth: dict, weigh: str = "sum",
        targets: str = "posterior", box: dict | None = None, workers: int = 0, views: int = -1,
        fitted: tuple = ()) -> dict:
    """One calibration; ``workers``: simulate its heaps on that many (else the stand-in draws them), saying each
    round as the stage does. ``views`` 0 or 1 (``--views``): the heaps at hand redrawn from the stand-in
    (:func:`redraw_at_hand`, ``fitted`` its surfaces) and the surrogates learning from one view or the views' mean."""
    adaptive._greedy = _combined_greedy if weigh == "combined" else _plain_greedy
    cal.acquire = aiming(targets, box or {})
    run = root / f"{first}-{batch}-{seed}-{weigh}-{targets}-{views}"
    subprocess.run([sys.executable, str(Path(__file__).with_name("gpu_device_prep.py")), "--src", str(src),
                    "--out", str(run)], check=True, capture_output=True)
    if views >= 0:
        redraw_at_hand(run, *fitted[:3])
    t0 = time.perf_counter()
    r = cal.calibrate(run, budget=budget, first=first, batch=batch, seed=seed, at_revision=1, workers=workers or 1,
                      say=None if workers else lambda *a, **k: None, views=views == 1)
    per = r.rounds[r.rounds["revision"] == 1]
    rounds = per.drop_duplicates("round")
    sure = rounds[rounds["surrogate_ratio"] <= 1.0]
    t = r.table.set_index("parameter")
    return {"first": first or "default", "batch": batch or "default", "weigh": weigh, "targets": targets,
            **({"views": "4 views' mean" if views else "one view"} if views >= 0 else {}), "seed": seed,
            "start": int(rounds["heaps"].iloc[0] - rounds["calibration_heaps"].iloc[0]),
            "decided_at": int(sure["heaps"].min()) if len(sure) else np.nan,
            "trajectory": " ".join(f"{h}:{q:.2f}" for h, q in zip(rounds["heaps"], rounds["surrogate_ratio"])),
            "stop_heaps": int(rounds["heaps"].max()), "stopped": r.stop.split(":")[0],
            "held": int(sum(t.loc[p, "q05"] <= v <= t.loc[p, "q95"] for p, v in truth.items())),
            "bf_off": float(t.loc["surface_energy", "bf_off"]), "s": round(time.perf_counter() - t0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", default="sample_runs/hidden-effect")
    ap.add_argument("--firsts", default="0", help="round 0's heaps, comma-separated (0: the stage's default)")
    ap.add_argument("--batches", default="0", help="a later round's heaps, comma-separated (0: the default)")
    ap.add_argument("--weighs", default="sum", help="how a later round weighs the responses' variances: sum (the "
                    "stage's) or combined (each by the combined ratio's slope in it), comma-separated to compare")
    ap.add_argument("--targets", default="posterior", help="where a later round aims: posterior (the stage's), "
                    "tempered, mix or plugin (see aiming()), comma-separated to compare")
    ap.add_argument("--seeds", default="0,1", help="the calibrations' seeds, comma-separated (the design's, the "
                    "piles' and the sampler's)")
    ap.add_argument("--views", default="", help="0,1: the heaps at hand redrawn from the stand-in, each pile with 4 "
                    "side views, and the surrogates learning from one view (0) or the views' mean (1; calibrate "
                    "--side-views), comma-separated to compare")
    ap.add_argument("--budget", type=int, default=250)
    ap.add_argument("--real", action="store_true", help="simulate the new heaps (the run's own preset and engine) "
                    "instead of drawing them from the stand-in: one real calibration a setting")
    ap.add_argument("--workers", type=int, default=2, help="heaps simulated at once with --real")
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    src = Path(a.src)
    *fitted, box = surfaces(src)
    if not a.real:
        cal.run_campaign = stand_in(*fitted)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in (int(x) for x in a.seeds.split(",")):
            for first in (int(f) or None for f in a.firsts.split(",")):
                for batch in (int(b) or None for b in a.batches.split(",")):
                    for weigh in a.weighs.split(","):
                        for targets in a.targets.split(","):
                            for views in ([int(v) for v in a.views.split(",")] if a.views else [-1]):
                                out.append(one(src, Path(tmp), first, batch, seed, a.budget, TRUTHS[src.name], weigh,
                                               targets, box, a.workers if a.real else 0, views, tuple(fitted)))
                                print(out[-1], flush=True)
    df = pd.DataFrame(out)
    print(df.drop(columns="trajectory").to_string())
    keys = ["first", "batch", "weigh", "targets", *(["views"] if "views" in df.columns else [])]
    print(df.groupby(keys, sort=False)[["decided_at", "stop_heaps", "held"]].mean().to_string())
    print("\n".join(f"{r.first} {r.batch} {r.weigh} {r.targets} seed {r.seed}: {r.trajectory}" for r in df.itertuples()))


if __name__ == "__main__":
    main()
