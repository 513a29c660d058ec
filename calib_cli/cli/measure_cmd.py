"""`calib measure-angle`: thin wrapper over calib_cli.imaging."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import pandas as pd
import typer
from rich.progress import Progress

from .. import artifacts as art
from ..dem.heap import CONDITION_VARIABLES, FLOOR_VARIABLES
from ..errors import CalibError
from ..imaging.measure import measure_image, overlay, read_image
from ..imaging.stats import STAT_COLUMNS, describe
from .common import ForceOpt, RunOpt, check_run_dir, console, df_table, skipped

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"}
CONDITION_VARS = [*CONDITION_VARIABLES, "floor"]
DEFAULT_CONDITION = "all"


def _read_conditions(path: Path) -> pd.DataFrame:
    if not path.is_file():
        raise CalibError(f"conditions file not found: {path}")
    try:
        df = pd.read_csv(path, comment="#") if path.suffix.lower() != ".parquet" else art.read_table(path)
    except Exception as e:
        raise CalibError(f"conditions file {path} could not be read ({type(e).__name__})") from None
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in ("image", "condition_id") if c not in df.columns]
    if missing:
        raise CalibError(f"conditions file {path} lacks column(s) {', '.join(missing)}")
    if df["image"].duplicated().any():
        raise CalibError(f"conditions file {path} lists image {df['image'][df['image'].duplicated()].iloc[0]!r} twice")
    df["image"] = df["image"].astype(str)
    df["condition_id"] = df["condition_id"].astype(str)
    for c in CONDITION_VARS[:-1]:
        if c in df.columns and not np.all(np.isfinite(pd.to_numeric(df[c], errors="coerce"))):
            raise CalibError(f"conditions file {path}: column {c!r} has missing or non-numeric values")
    return df


def _aggregate(angles: pd.DataFrame, cond: pd.DataFrame | None) -> pd.DataFrame:
    rows = []
    for cid, g in angles.groupby("condition_id", sort=True):
        ok = g[g["status"] == "ok"]["repose_angle"]
        row = {"condition_id": cid, **describe(ok), "n_images": len(g)}
        if cond is not None:
            first = cond[cond["condition_id"] == cid]
            for c in CONDITION_VARS:
                if c in cond.columns and len(first):
                    row[c] = first[c].iloc[0]
        rows.append(row)
    return pd.DataFrame(rows)


def measure_angle(
    run: RunOpt,
    images: Annotated[Optional[Path], typer.Option(help="Folder of heap photographs (PNG/JPEG/TIFF/BMP).")] = None,
    conditions: Annotated[Optional[Path], typer.Option(help="CSV: image, condition_id [, condition variables, floor "
                          "and its floor_* values]. Without it all images are one condition.")] = None,
    angles: Annotated[Optional[Path], typer.Option(help="Instead of images: a CSV of angles already measured "
                      "(image, repose_angle [, condition_id]), e.g. the paper's Table 1.")] = None,
    band: Annotated[tuple[float, float], typer.Option(help="Height band of the flank fit (fractions).")] = (0.15, 0.85),
    force: ForceOpt = False,
):
    """Repose angle per photograph and per condition (paper 2.1, Table 1).

    Reads --images (and --conditions), or --angles. Writes RUN/measure/angles.parquet,
    conditions.parquet (n, mean, median, sd, range, cv_percent, se, ci95), profiles.parquet and
    an annotated overlay PNG per image in RUN/measure/overlays/. Unreadable, blank, heap-less
    or cut images get a status and a message; the exit code is non-zero only if none could be measured.
    """
    run = check_run_dir(run)
    if (images is None) == (angles is None):
        raise CalibError("give either --images FOLDER or --angles FILE")
    if not 0 <= band[0] < band[1] <= 1:
        raise CalibError(f"--band must satisfy 0 <= low < high <= 1, got {band}")
    cond = _read_conditions(conditions) if conditions is not None else None
    if angles is not None:
        if not angles.is_file():
            raise CalibError(f"angles file not found: {angles}")
        try:
            raw = pd.read_csv(angles, comment="#")
        except Exception as e:
            raise CalibError(f"angles file {angles} could not be read ({type(e).__name__})") from None
        if "repose_angle" not in raw.columns:
            raise CalibError(f"angles file {angles} lacks column repose_angle")
        vals = pd.to_numeric(raw["repose_angle"], errors="coerce")
        if not np.all(np.isfinite(vals)):
            raise CalibError(f"angles file {angles}: repose_angle has missing or non-numeric values")
        files = {}
        table = pd.DataFrame({"image": raw["image"].astype(str) if "image" in raw.columns
                              else [str(i + 1) for i in range(len(raw))],
                              "condition_id": raw["condition_id"].astype(str) if "condition_id" in raw.columns
                              else DEFAULT_CONDITION,
                              "angle_left": np.nan, "angle_right": np.nan, "repose_angle": vals.astype(float),
                              "fit_rmse_px": np.nan, "status": "ok", "message": "given"})
        inputs = {"angles": angles}
    else:
        if not images.is_dir():
            raise CalibError(f"--images {images} is not a folder")
        files = {p.name: p for p in sorted(images.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES}
        if not files:
            raise CalibError(f"no images (PNG/JPEG/TIFF/BMP) in {images}")
        inputs = {f"image:{n}": p for n, p in files.items()}
        table = None
    if conditions is not None:
        inputs["conditions"] = conditions
    st = art.Stage(run, "measure", "angles", inputs=inputs, settings={"band": list(band)})
    if st.up_to_date() and not force:
        return skipped(st)
    cmap = dict(zip(cond["image"], cond["condition_id"])) if cond is not None else {}
    profiles, overlays = [], {}
    if table is None:
        rows = []
        with Progress(console=console, transient=True) as prog:
            task = prog.add_task("measuring", total=len(files))
            for name, path in files.items():
                gray = read_image(path)
                res = measure_image(gray, band=band)
                cid = cmap.get(name, DEFAULT_CONDITION if cond is None else "unassigned")
                rows.append({"image": name, "condition_id": cid, "angle_left": res.angle_left,
                             "angle_right": res.angle_right, "repose_angle": res.repose_angle,
                             "fit_rmse_px": res.fit_rmse_px, "base_tilt_deg": res.base_tilt_deg,
                             "height_px": res.height_px, "status": res.status, "message": res.message})
                if res.status == "ok":
                    profiles.append(pd.DataFrame({"image": name, "condition_id": cid,
                                                  "s_px": res.profile_s, "h_px": res.profile_h}))
                if gray is not None:
                    overlays[name] = overlay(gray, res)
                prog.advance(task)
        table = pd.DataFrame(rows)
    if cond is not None:
        unknown = sorted(set(cond["image"]) - set(table["image"]))
        if unknown and files:
            console.print(f"[yellow]warning:[/] {len(unknown)} image(s) in the conditions table are not in the folder: "
                          f"{', '.join(unknown[:5])}")
        if (table["condition_id"] == "unassigned").any():
            console.print("[yellow]warning:[/] images not in the conditions table are grouped as 'unassigned'")
    n_ok = int((table["status"] == "ok").sum())
    if n_ok == 0:
        for _, r in table.iterrows():
            console.print(f"[red]{r['image']}[/]: {r['status']} - {r['message']}")
        raise CalibError(f"none of the {len(table)} image(s) could be measured")
    summary = _aggregate(table, cond)
    prof = pd.concat(profiles, ignore_index=True) if profiles else pd.DataFrame(
        {"image": [], "condition_id": [], "s_px": [], "h_px": []})
    with st.commit() as out:
        out.table("angles.parquet", table)
        out.table("conditions.parquet", summary)
        out.table("profiles.parquet", prof)
        for name, img in overlays.items():
            out.bytes(f"overlays/{Path(name).stem}.png", art.png_bytes(img))
    console.print(df_table(table[["image", "condition_id", "angle_left", "angle_right", "repose_angle", "status"]],
                           f"measure-angle -> {st.dir / 'angles.parquet'}"))
    for _, r in table[table["status"] != "ok"].iterrows():
        console.print(f"[yellow]{r['image']}[/]: {r['status']} - {r['message']}")
    for _, r in table[(table["status"] == "ok") & (table["message"] != "") & (table["message"] != "given")].iterrows():
        console.print(f"[yellow]{r['image']}[/]: {r['message']}")
    console.print(df_table(summary[["condition_id", *STAT_COLUMNS]], "Per condition (cf. paper Table 1)"))
    alike = floors_alike(summary)
    if alike:
        console.print(f"[yellow]warning:[/] floors {', '.join(alike)} have no values that tell them apart "
                      f"({', '.join(FLOOR_VARIABLES)}): they will be simulated as one floor")


def floors_alike(conditions: pd.DataFrame) -> list[str]:
    """Floor names of a conditions table that its floor_* columns do not tell apart (a floor's name
    alone is no physics: without values the floor takes the walls' friction in every simulation)."""
    if "floor" not in conditions.columns or conditions["floor"].nunique() < 2:
        return []
    vals = [c for c in FLOOR_VARIABLES if c in conditions.columns]
    keys = {f: tuple(None if pd.isna(v) else round(float(v), 12) for v in g[vals].iloc[0])
            for f, g in conditions.groupby("floor")}
    n = Counter(keys.values())
    return sorted(str(f) for f, k in keys.items() if n[k] > 1)

