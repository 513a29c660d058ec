"""The measurement, the discrepancy loop, the heaps, and every raw table collapsed at the end."""

from __future__ import annotations

import html

import pandas as pd

from .html import RunFiles, esc, figure, img, note, num, table
from .stages import _cols, figures, not_run, section

#: stage folders in run order: their Parquet tables are listed raw at the end
RAW_STAGES = ["measure", "pb", "ascent", "bbd", "surrogate", "invert", "calibrate", "compare", "diagnose", "posterior",
              "suggest", "simulate"]


def measurement(f: RunFiles) -> str:
    cond = f.table("measure/conditions.parquet")
    if cond is None:
        return section("measurement", "Measured repose angle", "2.1, Table 1", not_run("calib measure-angle"))
    body = table(_cols(cond, ["condition_id", "n", "mean", "median", "sd", "ci95_low", "ci95_high",
                              "particle_d_min_mm", "particle_d_max_mm", "cylinder_diameter_mm", "fill_height_mm",
                              "lift_speed_mm_s", "floor"]), digits=4)
    ang = f.table("measure/angles.parquet")
    if ang is not None and "status" in ang.columns and (ang["status"] != "ok").any():
        bad = ang[ang["status"] != "ok"]
        body += note(f"{len(bad)} image(s) gave no angle: " + esc(", ".join(
            f"{i} ({s})" for i, s in zip(bad.get("image", bad.index), bad["status"]))))
    shots = f.pngs("measure/overlays")
    if shots:
        body += (f"<details><summary>All {len(shots)} photographs with their fitted flanks</summary>"
                 f"<div class=gallery>{''.join(img(f.run, p) for p in shots)}</div></details>")
    return section("measurement", "Measured repose angle", "2.1, Table 1", body)


def posterior(f: RunFiles) -> str:
    """calibrate's rounds (the intervals narrowing, the surrogates' ratio, the Bayes factors), the answer's
    corner plot and the surrogates' held-out errors: what the first screen's posterior card summarises."""
    title = "The posterior: calibration in rounds"
    if not f.has_dir("posterior"):
        return section("posterior", title, None, not_run("calib calibrate"))
    rev = f.prov("posterior/summary.parquet").get("model_revision", "?")
    shots = [figure(f.run, f.run / rel, cap) for rel, cap in (
        ("calibrate/rounds.png", "Each parameter's 90 % interval and median against the heaps its round's posterior "
                                 "learnt from; the surrogates' variance over the measured means' (a verdict below 1) "
                                 "and each effect's Bayes factor of off. In black, the answer: the last round's "
                                 "posterior sampled longer" + _averaged_words(f) + ". A Bayes factor drawn hollow is an "
                                 "upper bound: no draw fell near the effect's off value, and a round's shorter chains "
                                 "bound it less tightly than the answer's."),
        ("posterior/corner.png", f"Model revision {esc(rev)}'s posterior draws over the prior's ranges, every pair "
                                 "(dashed: 90 % intervals)")) if (f.run / rel).is_file()]
    body = f"<div class='figs post'>{''.join(shots)}</div>" if shots else ""
    sur = f.table("posterior/surrogates.parquet")
    if sur is not None and not sur.empty:
        body += note("The surrogates' held-out error per pile against the piles' own scatter (deg for the angle), "
                     "by cross-validation over the design points:") + table(sur, digits=3)
    return section("posterior", title, None, body)


def _averaged_words(f: RunFiles) -> str:
    """", then averaged over EFFECT on and off (probability off P)" where the answer averages an effect (the
    summary's provenance records it: :meth:`~calib_cli.posterior.evidence.PosteriorFit.provenance`)."""
    avg = f.prov("posterior/summary.parquet").get("averaged")
    if not avg:
        return ""
    return (f", then averaged over {esc(avg['effect'].replace('_', ' '))} on and off (probability off "
            f"{num(float(avg['p_off']), 2)}), so its intervals are not the rounds' (which keep the effect free)")


def discrepancy(f: RunFiles) -> str:
    """compare's residual and history plots, diagnose's ranking with its evidence, and its trends."""
    if not f.has_dir("compare") and not f.has_dir("diagnose"):
        return section("discrepancy", "Discrepancy loop", None,
                       not_run("calib compare; calib diagnose; calib model add EFFECT"))
    body = figures(f, "compare") if f.has_dir("compare") else not_run("calib compare")
    rank = f.table("diagnose/ranking.parquet")
    if rank is None:
        body += not_run("calib diagnose")
    else:
        rev = f.prov("diagnose/ranking.parquet").get("model_revision", "?")
        body += note(f"Candidate missing effects, judged on model revision {esc(rev)}'s residuals:")
        body += table(_cols(rank, ["effect", "verdict", "p_value", "explained_fraction", "evidence"]), digits=3)
        tr = f.table("diagnose/trends.parquet")
        if tr is not None:
            body += note(f"Model revision {esc(rev)}'s residual against each condition variable (a line fitted "
                         "over the conditions):") + table(tr, digits=3)
    return section("discrepancy", "Discrepancy loop: model against the measurements", None, body)


def heap_setups(f: RunFiles) -> list[str]:
    """One line per group of the run's heaps (design, validation, compare, ...): how many, and
    at which preset, shear modulus and contact laws - what its calibrated parameters hold at."""
    rows = f.table("simulate/results.parquet")
    if rows is None or rows.empty:
        return []
    from ..heaps.index import heap_setups as setups

    label = rows["design"].fillna("").replace("", "single runs") if "design" in rows.columns \
        else pd.Series("all", index=rows.index)
    items = []
    for name, grp in rows.groupby(label, sort=False):
        engines = sorted(set(grp["engine"].dropna()) - {"builtin"}) if "engine" in grp.columns else []
        mixed = int((grp["precision"] == "mixed").sum()) if "precision" in grp.columns else 0
        also = [f"engine {', '.join(engines)}"] * bool(engines) + [f"{mixed} in mixed precision"] * bool(mixed)
        items.append(f"<li>{html.escape(str(name))}: {len(grp)} heap(s), {html.escape('; '.join(setups(grp)))}"
                     + (f" ({html.escape('; '.join(also))})" if also else "") + "</li>")
    return ["<p>Heaps in this run directory (every model revision's), by what they were simulated for: a "
            "calibration holds at the "
            "preset and shear modulus its heaps had (docs/physics.md, 'Which modulus').</p><ul>", *items, "</ul>"]


def simulations(f: RunFiles) -> str:
    lines = heap_setups(f)
    body = "\n".join(lines) if lines else note("No heap simulated in this run directory: the responses were "
                                               "given as tables (<code>--responses</code>).")
    return section("simulations", "Simulations", "2.2", body)


def raw_tables(f: RunFiles) -> str:
    """Every Parquet table of the run, each collapsed, wide ones scrolling inside their box."""
    parts = []
    for stage in RAW_STAGES:
        for p in sorted((f.run / stage).glob("*.parquet")) if f.has_dir(stage) else []:
            rel = p.relative_to(f.run).as_posix()
            df, prov = f.table(rel), f.prov(rel)
            # diagnose judges the revision compare held then; compare may since hold a later one
            rev = f" (model revision {prov['model_revision']})" if "model_revision" in prov else ""
            parts.append(f"<details class=raw><summary>{esc(stage)}/{esc(p.name)}{esc(rev)} "
                         f"<span class=prov>{len(df)} &times; {len(df.columns)}</span></summary>"
                         f"<p class=prov>{esc(prov.get('command', ''))}</p>{table(df)}</details>")
    body = "".join(parts) or note("No table in this run directory.")
    return section("raw", "Raw tables", False, note(
        "Every table is a Parquet artefact in the run directory; its provenance (command, inputs, settings "
        "hash) is in its schema metadata. The first 40 rows of each are shown.", "prov") + body)
