"""One photograph (with its fitted flanks) per condition, beside a simulated heap's side view where
the run directory still holds one (the per-heap folders under simulate/runs/ are caches)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

from .html import RunFiles, deg, esc, img, note

#: which simulated heaps stand for the calibrated model, best first
SIDE_DESIGNS = ("compare", "validate")


def photo(f: RunFiles, condition: str, mean: float) -> Optional[tuple[Path, float]]:
    """The overlay of the condition's photograph whose angle is closest to the condition's mean."""
    ang = f.table("measure/angles.parquet")
    if ang is None or "image" not in ang.columns:
        return None
    a = ang[(ang["condition_id"] == condition) & (ang["status"] == "ok")].copy()
    a["gap"] = (a["repose_angle"] - mean).abs()
    for r in a.sort_values("gap").itertuples(index=False):
        p = f.run / "measure" / "overlays" / (Path(str(r.image)).stem + ".png")
        if p.is_file():
            return p, float(r.repose_angle)
    return None


def side_view(f: RunFiles, condition: str) -> Optional[tuple[Path, str]]:
    """A kept side view of a compare (else validation) heap of the condition: the latest row of
    simulate/results.parquet whose folder is still there, else any kept folder saying so."""
    rows = f.table("simulate/results.parquet")
    runs = f.run / "simulate" / "runs"
    if rows is not None and {"design", "condition_id", "run_hash"} <= set(rows.columns):
        for design in SIDE_DESIGNS:
            sel = rows[(rows["design"] == design) & (rows["condition_id"] == condition)]
            for r in sel.iloc[::-1].itertuples(index=False):
                p = runs / str(r.run_hash) / "side.png"
                if p.is_file():
                    return p, f"{design} heap, {deg(r.repose_angle)}"
    for design in SIDE_DESIGNS:
        for res in sorted(runs.glob("*/result.json")) if runs.is_dir() else []:
            try:
                meta = json.loads(res.read_text())
            except (OSError, ValueError):
                continue
            if not isinstance(meta, dict):  # a file calib did not write: no heap to show
                continue
            side = res.parent / "side.png"
            if meta.get("design") == design and meta.get("condition_id") == condition and side.is_file():
                return side, f"{design} heap, {deg(meta.get('angle_image', meta.get('repose_angle')))}"
    return None


def photos_card(f: RunFiles) -> str:
    """One figure per measured condition: its photograph, and a simulated side view where one is kept."""
    cond = f.table("measure/conditions.parquet")
    title = "Photographs against simulated heaps"
    if cond is None or cond.empty:
        body = note("Not run yet: <code>calib measure-angle</code>.")
        return f"<div class='card wide'><h3>{title}</h3>{body}</div>"
    figs, n_side, n_photo = [], 0, 0
    for r in cond.itertuples(index=False):
        ph, sv = photo(f, r.condition_id, float(r.mean)), side_view(f, r.condition_id)
        if ph is None and sv is None:
            continue
        n_side += sv is not None
        n_photo += ph is not None
        inner = (img(f.run, ph[0], f"photograph, {r.condition_id}") if ph else "") + \
                (img(f.run, sv[0], f"simulated side view, {r.condition_id}", "side") if sv else "")
        cap = f"<b>{esc(r.condition_id)}</b>: " + (f"photo {deg(ph[1])} (mean {deg(r.mean)})" if ph else "no photo") \
            + (f"; simulated {sv[1]}" if sv else "")
        both = " both" if ph and sv else ""
        figs.append(f"<figure class='pair{both}'>{inner}<figcaption>{cap}</figcaption></figure>")
    angles = f.table("measure/angles.parquet")
    given = angles is not None and "message" in angles.columns and (angles["message"] == "given").all()
    missing = note("No photographs in this run directory: the angles were given as numbers "
                   "(<code>calib measure-angle --angles</code>)." if given else
                   "The photographs' overlays (<code>measure/overlays/</code>) are missing from this run "
                   "directory: <code>calib measure-angle --force</code> draws them again.")
    if not figs:
        body = missing
    else:
        body = f"<div class=gallery>{''.join(figs)}</div>" + (missing if n_photo < len(figs) else "")
        if n_side < len(figs):
            body += note("No simulated side view is kept in this run directory for "
                         + ("any condition" if n_side == 0 else f"{len(figs) - n_side} of {len(figs)} conditions")
                         + ": the per-heap folders under <code>simulate/runs/</code> are caches, not committed. "
                         "Those conditions show the measured overlay only; <code>calib compare</code> "
                         "re-simulates them.", "prov")
        title = title if n_side else "Photographs"  # the title promises no side view the card cannot show
        body += note("Each photograph is the condition's closest to its mean angle, with the contour, base "
                     "and fitted flanks drawn by <code>calib measure-angle</code>.", "prov")
    return f"<div class='card wide'><h3>{title}</h3>{body}</div>"
