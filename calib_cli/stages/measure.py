"""Measure heap photographs (or take angles measured elsewhere): the repose angle per image and
per condition, the calibration's targets (paper 2.1, Table 1)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pandas as pd
from scipy.stats import t as student_t

from .. import artifacts as art
from ..conditions import condition_ids, read_conditions_csv
from ..dem.heap import CONDITION_VARIABLES, FLOOR_VARIABLES
from ..errors import CalibError, reason
from ..imaging.measure import FLAGS, ShapeLimits, measure_image, overlay, read_image
from ..imaging.stats import STAT_COLUMNS, describe
from ..parameters import ALLOW_EXTREME, check, extremes_allowed
from .common import Result, Say, check_run_dir, plain, shown, stage, writes_run

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp"}
CONDITION_VARS = [*CONDITION_VARIABLES, "floor"]
DEFAULT_CONDITION = "all"
#: the rig's sizes and speed, which only a positive number describes
RIG_SIZES = ("particle_d_min_mm", "particle_d_max_mm", "cylinder_diameter_mm", "fill_height_mm", "lift_speed_mm_s")


def _read_conditions(path: Path) -> pd.DataFrame:
    """The conditions file: a CSV as a user writes it, checked where it enters (:mod:`calib_cli.conditions`),
    or a Parquet table of them (its rig values checked here)."""
    if path.suffix.lower() == ".parquet":
        df = _read_conditions_parquet(path)
    else:
        df = read_conditions_csv(path, need=("image", "condition_id"))
    if df["image"].duplicated().any():
        raise CalibError(f"conditions file {path} lists image {str(df['image'][df['image'].duplicated()].iloc[0])!r} twice")
    df["image"] = df["image"].astype(str)
    df["condition_id"] = df["condition_id"].astype(str)
    pathlike = df["image"][df["image"].map(lambda n: Path(n).name != n or n in ("", ".", ".."))]
    if len(pathlike):  # a name, not a path: the photographs are the files of --images
        raise CalibError(f"conditions file {path}: image {pathlike.iloc[0]!r} is a path; give file names of the "
                         "--images folder")
    return df


def _read_conditions_parquet(path: Path) -> pd.DataFrame:
    if not path.is_file():
        raise CalibError(f"conditions file not found: {path}")
    df = art.read_table(path, what="conditions file")
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in ("image", "condition_id") if c not in df.columns]
    if missing:
        raise CalibError(f"conditions file {path} lacks column(s) {', '.join(missing)}")
    for c in CONDITION_VARS[:-1]:
        v = pd.to_numeric(df[c], errors="coerce") if c in df.columns else None
        if v is not None and not np.all(np.isfinite(v)):
            raise CalibError(f"conditions file {path}: column {c!r} has missing or non-numeric values")
        if v is not None and c in RIG_SIZES and not np.all(v > 0):
            raise CalibError(f"conditions file {path}: column {c!r} must be positive, got {v[v <= 0].iloc[0]:g}")
    return df


def _photos(images: Path) -> dict[str, Path]:
    """The photographs of a folder by file name. Two with one name but their suffix (a.png, a.jpg) are
    an error: their overlays would collide, and they are one heap photographed twice or two heaps misnamed."""
    if not images.is_dir():
        raise CalibError(f"--images {images} is not a folder")
    named = [p for p in sorted(images.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES]
    odd = [p.name for p in named if not p.is_file()]  # a folder named x.png, a broken or looping link
    if odd:
        raise CalibError(f"{odd[0]} in {images} is named as a photograph but is not a readable file (a folder or a "
                         f"broken link): move it out{f' ({len(odd)} such names)' if len(odd) > 1 else ''}")
    files = {p.name: p for p in named}
    if not files:
        others = sorted({p.suffix.lower() for p in images.iterdir() if p.is_file() and p.suffix})
        also = f" (its files end in {', '.join(others[:6])})" if others else ""
        raise CalibError(f"no images (PNG/JPEG/TIFF/BMP/WebP) in {images}{also}")
    stems: dict[str, list[str]] = {}
    for name in files:
        stems.setdefault(Path(name).stem.casefold(), []).append(name)
    twins = [names for names in stems.values() if len(names) > 1]
    if twins:
        raise CalibError(f"photos {' and '.join(twins[0])} in {images} share the name {Path(twins[0][0]).stem!r}: "
                         f"rename or remove one{f' ({len(twins)} such names)' if len(twins) > 1 else ''}")
    return files


def _read_angles(path: Path) -> pd.DataFrame:
    """An angles CSV: repose_angle (a number in (0, 90) degrees on every row) [, image, condition_id]."""
    if not path.is_file():
        raise CalibError(f"angles file not found: {path}")
    try:
        raw = pd.read_csv(path, comment="#", skipinitialspace=True)
    except Exception as e:
        raise CalibError(f"angles file {path} could not be read ({reason(e)})") from None
    raw.columns = [str(c).strip() for c in raw.columns]  # "image, repose_angle" as a responses file takes it
    if "repose_angle" not in raw.columns:
        raise CalibError(f"angles file {path} lacks column repose_angle")
    vals = pd.to_numeric(raw["repose_angle"], errors="coerce")
    with np.errstate(invalid="ignore"):
        bad = np.flatnonzero(~(np.isfinite(vals) & (vals > 0) & (vals < 90)))
    if len(bad):
        label = (lambda i: f"image {raw['image'].iloc[i]}") if "image" in raw.columns else (lambda i: f"row {i + 1}")
        shown = (lambda v: v if isinstance(v, str) else f"{v:g}")  # as written: 90, not 90.0
        where = [f"{label(i)}: {shown(raw['repose_angle'].iloc[i])}" for i in bad[:5]]
        raise CalibError(f"angles file {path}: repose_angle must be a number in (0, 90) degrees; {len(bad)} "
                         f"row(s) are not ({'; '.join(where)}{'; ...' if len(bad) > 5 else ''})")
    if len(vals) >= 2 and vals.max() < 1.6 and not extremes_allowed():  # every angle under pi/2
        raise CalibError(f"angles file {path}: every repose_angle is below 1.6 ({vals.min():g}-{vals.max():g}): are "
                         f"these radians? Give degrees (set {ALLOW_EXTREME}=1 to use them as they are)")
    for v in vals:
        check("repose_angle", v, f"angles file {path}")
    if "image" in raw.columns and raw["image"].duplicated().any():
        raise CalibError(f"angles file {path} lists image {str(raw['image'][raw['image'].duplicated()].iloc[0])!r} twice")
    if "condition_id" in raw.columns:  # a blank one would be a condition "nan" of its own, or no condition at all
        raw = raw.assign(condition_id=condition_ids(raw, path, "angles file"))
    return raw.assign(repose_angle=vals.astype(float))


def _condition_ids(names: list[str], cmap: dict, no_table: bool) -> list[str]:
    """Each image's condition: from the conditions table (``unassigned`` if it is not there), or one for all."""
    return [cmap.get(n, DEFAULT_CONDITION if no_table else "unassigned") for n in names]


def _angles_table(path: Path, cmap: dict, cond: pd.DataFrame | None, say: Say) -> pd.DataFrame:
    """The angles file as an angles table; a conditions table joins on its image column, as for photos."""
    raw = _read_angles(path)
    rig = [c for c in raw.columns if c in CONDITION_VARIABLES]
    if rig:  # a rig comes from the conditions table: these would go unseen by every later stage
        say(f"note: {path} has rig column(s) {', '.join(rig)}, which are not read: give each condition's "
            "rig in a --conditions table (image, condition_id and the rig's columns)")
    names = raw["image"].astype(str).tolist() if "image" in raw.columns else [str(i + 1) for i in range(len(raw))]
    if cond is None:
        cid = raw["condition_id"].astype(str).tolist() if "condition_id" in raw.columns else DEFAULT_CONDITION
    elif "image" not in raw.columns:
        raise CalibError(f"angles file {path} has no image column for the conditions table to join on")
    else:
        cid = _condition_ids(names, cmap, False)
        if "condition_id" in raw.columns:
            own = raw["condition_id"].astype(str).tolist()
            clash = [(n, o, c) for n, o, c in zip(names, own, cid) if o != c]
            if clash:
                n, o, c = clash[0]
                raise CalibError(f"image {n} is in condition {o!r} in angles file {path} but in {c!r} by the "
                                 f"conditions table: give condition_id in one of them")
    return pd.DataFrame({"image": names, "condition_id": cid, "angle_left": np.nan, "angle_right": np.nan,
                         "repose_angle": raw["repose_angle"], "fit_rmse_px": np.nan, "status": "ok",
                         "message": "given"})


def used(angles: pd.DataFrame, keep_flagged: bool = False) -> pd.Series:
    """The rows of an angles table that enter the condition statistics: ``ok``, and with ``keep_flagged``
    the silhouettes measured but flagged as no heap's cone (imaging.measure.FLAGS)."""
    ok = angles["status"] == "ok"
    if keep_flagged:
        ok |= angles["status"].isin(FLAGS) & np.isfinite(angles["repose_angle"].astype(float))
    return ok


def _aggregate(angles: pd.DataFrame, cond: pd.DataFrame | None, keep_flagged: bool = False) -> pd.DataFrame:
    rows = []
    for cid, g in angles.groupby("condition_id", sort=True):
        use = used(g, keep_flagged)
        ok = g[use]["repose_angle"]
        stats = describe(ok) if "pile" not in g.columns else by_pile(ok, g.loc[use, "pile"])
        row = {"condition_id": cid, **stats, "n_images": len(g)}
        if cond is not None:
            first = cond[cond["condition_id"] == cid]
            for c in CONDITION_VARS:
                if c in cond.columns and len(first):
                    row[c] = first[c].iloc[0]
        rows.append(row)
    return pd.DataFrame(rows)


def by_pile(values: pd.Series, piles: pd.Series) -> dict:
    """A condition's statistics (:func:`describe`) where several photographs may show one pile: ``n`` counts
    piles and the mean is their views' means' mean, since a pile is one draw of the pile-to-pile scatter
    however many views it has (its views counted as piles made the mean look up to that many times surer);
    ``sd`` is one photograph's, the scatter a photograph and one simulated view show, but no less than the
    piles' means' (the photographs' own undercounts the piles where their views agree), so that ``se`` = sd /
    sqrt(piles) is never narrower than the piles' means give."""
    v = pd.to_numeric(values, errors="coerce")
    keep = np.isfinite(v.to_numpy(float))
    means = v[keep].groupby(piles[keep].to_numpy()).mean()
    out, n = describe(v[keep]), len(means)
    if n == out["n"]:  # one photograph a pile
        return out
    mean = float(means.mean()) if n else np.nan
    sd = max(out["sd"], float(means.std(ddof=1))) if n > 1 else out["sd"]
    se = sd / np.sqrt(n) if n > 1 else np.nan
    half = float(student_t.ppf(0.975, n - 1) * se) if n > 1 else np.nan
    return {**out, "n": n, "mean": mean, "sd": sd, "se": se, "ci95_low": mean - half, "ci95_high": mean + half,
            "cv_percent": 100 * sd / mean if n > 1 else np.nan}


def _measure_images(files: dict[str, Path], cmap: dict, no_table: bool, band, limits: ShapeLimits,
                    keep_flagged: bool, progress) -> tuple:
    """One row per image (its angles, status and message), the flank profiles of those that enter the
    statistics, the overlays."""
    rows, profiles, overlays = [], [], {}
    for i, ((name, path), cid) in enumerate(zip(files.items(), _condition_ids(list(files), cmap, no_table))):
        gray = read_image(path)
        res = measure_image(gray, band=band, limits=limits)
        rows.append({"image": name, "condition_id": cid, "angle_left": res.angle_left,
                     "angle_right": res.angle_right, "repose_angle": res.repose_angle,
                     "fit_rmse_px": res.fit_rmse_px, "base_tilt_deg": res.base_tilt_deg,
                     "height_px": res.height_px, "status": res.status, "message": res.message})
        if res.status == "ok" or (keep_flagged and res.status in FLAGS and np.isfinite(res.repose_angle)):
            profiles.append(pd.DataFrame({"image": name, "condition_id": cid,
                                          "s_px": res.profile_s, "h_px": res.profile_h}))
        if gray is not None:
            overlays[name] = overlay(gray, res)
        if progress:
            progress(i + 1, len(files))
    return pd.DataFrame(rows), profiles, overlays


def columns_by_pile(table: pd.DataFrame, cond: pd.DataFrame, profiles: list) -> tuple[pd.DataFrame, list]:
    """Several photographs of one pile (the conditions table's ``pile`` column, a label within each condition):
    where any view stands as a column the pile is a column as a whole, so its other views are flagged too
    (their stub's flanks are no repose angle) and leave the statistics and the profiles. Adds the ``pile``
    column (:func:`pile_labels`)."""
    table = table.assign(pile=pile_labels(table["image"], dict(zip(cond["image"].astype(str), cond["pile"]))))
    key = table["condition_id"].astype(str) + "\x00" + table["pile"]  # pile 1 of A is not pile 1 of B
    col = table["status"] == "column"
    # grouped by the masked key, not .assign(key=key): assigning a Series to an empty frame takes its index, so
    # where no view stood every pile read as standing
    standing = table.loc[col, "image"].groupby(key[col]).first()
    hit = key.isin(standing.index) & (table["status"] != "column")
    table.loc[hit, "message"] = [f"another view of this pile ({standing[k]}) stands as a column: the pile is a "
                                 "column as a whole" for k in key[hit]]
    table.loc[hit, "status"] = "column"
    gone = set(table.loc[hit, "image"])
    return table, [p for p in profiles if not (len(p) and p["image"].iloc[0] in gone)]


def pile_labels(images: pd.Series, pile: dict) -> list[str]:
    """Each photograph's pile as text: its ``pile`` cell (a whole number without its ".0"), or the photograph
    itself where the cell is blank or the table does not list it (a pile of one view)."""
    out = []
    for name in images.astype(str):
        v = pile.get(name)
        if v is None or (isinstance(v, float) and not np.isfinite(v)) or str(v).strip() in ("", "nan", "<NA>"):
            out.append(name)
        else:
            out.append(str(int(v)) if isinstance(v, float) and v.is_integer() else str(v).strip())
    return out


def _left_out(angles: pd.DataFrame, keep_flagged: bool) -> dict[str, int]:
    """How many images each status leaves out of the condition statistics."""
    counts = angles[~used(angles, keep_flagged)]["status"].value_counts().sort_index()
    return {str(k): int(v) for k, v in counts.items()}


def _counts(left: dict[str, int]) -> str:
    return ", ".join(f"{n} {status}" for status, n in left.items())


@dataclass
class MeasureResult(Result):
    """RUN/measure/: ``angles`` (one row per image) and ``conditions`` (n, mean, sd, ... per condition)."""

    angles: Optional[pd.DataFrame] = None
    conditions: Optional[pd.DataFrame] = None
    keep_flagged: bool = False

    def __post_init__(self):
        if self.angles is None and (self.dir / "angles.parquet").is_file():
            self.angles = art.read_table(self.dir / "angles.parquet")
            self.conditions = art.read_table(self.dir / "conditions.parquet")

    def left_out(self) -> dict[str, int]:
        """Images left out of the condition statistics, by status (e.g. {"column": 1, "unreadable": 2})."""
        return _left_out(self.angles, self.keep_flagged)

    def summary(self) -> pd.DataFrame:
        """Per condition (cf. paper Table 1); with a ``left_out`` column (how many and why) where images were."""
        out = self.conditions[["condition_id", *STAT_COLUMNS]]
        if self.left_out():
            by = {cid: _counts(_left_out(g, self.keep_flagged)) for cid, g in self.angles.groupby("condition_id")}
            out = out.assign(left_out=[by.get(c, "") for c in out["condition_id"]])
        return out

    def notes(self, markup: bool = False) -> list[str]:
        """Images with a status or a message, and how many were left out of the statistics and why
        (``markup``: with the command line's rich markup)."""
        t, out = self.angles, []
        for _, r in t[t["status"] != "ok"].iterrows():
            out.append(f"[yellow]{r['image']}[/]: {r['status']} - {r['message']}")
        for _, r in t[(t["status"] == "ok") & (t["message"] != "") & (t["message"] != "given")].iterrows():
            out.append(f"[yellow]{r['image']}[/]: {r['message']}")
        flagged = t["status"].isin(FLAGS) & np.isfinite(t["repose_angle"].astype(float))
        left, kept = self.left_out(), int((flagged & used(t, self.keep_flagged)).sum())
        if left:
            hint = int((flagged & ~used(t, self.keep_flagged)).sum())
            out.append(f"[yellow]{sum(left.values())} of {len(t)} image(s) left out of the condition statistics[/]: "
                       f"{_counts(left)}" + (f" (--keep-flagged counts the {hint} flagged one(s) whose flanks were "
                                             "fitted)" if hint else ""))
        if kept:
            out.append(f"[yellow]{kept} image(s) flagged but counted[/] (--keep-flagged)")
        return shown(out, markup)


@writes_run
def measure_angle(run: Path, images: Optional[Path] = None, conditions: Optional[Path] = None,
                  angles: Optional[Path] = None, band: tuple[float, float] = (0.15, 0.85), force: bool = False,
                  say: Optional[Say] = None, progress: Optional[Callable[[int, int], None]] = None,
                  keep_flagged: bool = False, max_flank_diff: float = ShapeLimits.max_flank_diff_deg,
                  max_residual: float = ShapeLimits.max_residual) -> MeasureResult:
    """Repose angle per photograph in ``images`` (``conditions``: a CSV image, condition_id [, condition
    variables]) or per row of an ``angles`` CSV (the conditions join on its image column), and per condition.
    A photograph whose silhouette is no heap's cone (cut by the frame, a standing column, crooked or
    asymmetric flanks beyond ``max_residual`` heap heights or ``max_flank_diff`` deg) gets that status and
    is left out of the statistics unless ``keep_flagged``. Writes RUN/measure/angles.parquet,
    conditions.parquet, profiles.parquet and overlays/; raises if no image could be measured."""
    say = say or plain
    images, conditions, angles = (Path(p) if p is not None else None for p in (images, conditions, angles))
    run = check_run_dir(run)
    if (images is None) == (angles is None):
        raise CalibError("give either --images FOLDER or --angles FILE")
    if not 0 <= band[0] < band[1] <= 1:
        raise CalibError(f"--band must satisfy 0 <= low < high <= 1, got {band}")
    if not (max_flank_diff > 0 and max_residual > 0):
        raise CalibError(f"--max-flank-diff and --max-residual must be positive, got {max_flank_diff}, {max_residual}")
    limits = ShapeLimits(max_flank_diff_deg=float(max_flank_diff), max_residual=float(max_residual))
    for folder in {p.parent for p in (conditions, angles) if p is not None} | ({images} if images is not None else set()):
        art.check_not_pending(folder, "the folder")  # a synth-lab cut short leaves two labs' photographs side by side
    cond = _read_conditions(conditions) if conditions is not None else None
    cmap = dict(zip(cond["image"], cond["condition_id"])) if cond is not None else {}
    files, table = {}, None
    if angles is not None:
        table = _angles_table(angles, cmap, cond, say)
        inputs = {"angles": angles}
    else:
        files = _photos(images)
        inputs = {f"image:{n}": p for n, p in files.items()}
    if conditions is not None:
        inputs["conditions"] = conditions
        _check_matched(set(files) if table is None else set(table["image"]), cond)  # before any image is read
    settings = _settings(band, limits, keep_flagged)
    if cond is not None and "pile" in cond.columns:  # the piles' counting moved (PILES); tables without piles keep their locks
        settings["piles"] = PILES
    st = stage(run, "measure", "angles", inputs=inputs, settings=settings)
    if st.up_to_date() and not force:
        return MeasureResult(st, True, keep_flagged=keep_flagged)
    profiles, overlays = [], {}
    if table is None:
        table, profiles, overlays = _measure_images(files, cmap, cond is None, band, limits, keep_flagged, progress)
    if cond is not None and "pile" in cond.columns:
        table, profiles = columns_by_pile(table, cond, profiles)
    _check_usable(table, keep_flagged, say)
    per_condition = _aggregate(table, cond, keep_flagged)
    prof = pd.concat(profiles, ignore_index=True) if profiles else pd.DataFrame(
        {"image": [], "condition_id": [], "s_px": [], "h_px": []})
    with st.commit() as out:
        out.table("angles.parquet", table)
        out.table("conditions.parquet", per_condition)
        out.table("profiles.parquet", prof)
        for name, img in overlays.items():
            out.bytes(f"overlays/{Path(name).stem}.png", art.png_bytes(img))
    return MeasureResult(st, False, table, per_condition, keep_flagged)


#: how a table's ``pile`` column is read, raised when that moves a measurement: 2, a pile's views count once
#: (:func:`by_pile`) and a label is one condition's (:func:`columns_by_pile`)
PILES = 2


def _settings(band, limits: ShapeLimits, keep_flagged: bool) -> dict:
    """The stage's settings (its lock's fingerprint). The shape checks' defaults are left out, so that their
    settings do not move every lock; the checks themselves moved the stage's code version (stages.common)."""
    out, default = {"band": list(band)}, ShapeLimits()
    if limits.max_flank_diff_deg != default.max_flank_diff_deg:
        out["max_flank_diff"] = limits.max_flank_diff_deg
    if limits.max_residual != default.max_residual:
        out["max_residual"] = limits.max_residual
    if keep_flagged:
        out["keep_flagged"] = True
    return out


def _check_matched(names: set, cond: pd.DataFrame) -> None:
    """Raise (nothing written) when the conditions table and the images to measure (``names``) disagree: a row
    whose image is not there (a typo, a missing file) or an image with no row would leave a condition short
    or put photographs in no condition."""
    listed = sorted(set(cond["image"]) - names)
    unlisted = sorted(names - set(cond["image"]))
    if listed or unlisted:
        parts = ([f"{len(listed)} row(s) of the conditions table name no image measured ({', '.join(listed[:5])})"]
                 if listed else []) + ([f"{len(unlisted)} image(s) have no row there ({', '.join(unlisted[:5])})"]
                                       if unlisted else [])
        raise CalibError("the conditions table and the images disagree: " + "; ".join(parts)
                         + ": give each photograph one row, its file name as in the folder")


def _check_usable(table: pd.DataFrame, keep_flagged: bool, say: Say) -> None:
    """Raise (nothing written) when no image enters the statistics, after listing why each did not."""
    if used(table, keep_flagged).any():
        return
    for _, r in table.iterrows():
        say(f"[red]{r['image']}[/]: {r['status']} - {r['message']}")
    flagged = int((table["status"].isin(FLAGS) & np.isfinite(table["repose_angle"].astype(float))).sum())
    if flagged:
        raise CalibError(f"none of the {len(table)} image(s) is a heap's cone ({_counts(_left_out(table, False))}): "
                         f"--keep-flagged measures the {flagged} flagged one(s) anyway")
    raise CalibError(f"none of the {len(table)} image(s) could be measured")


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

