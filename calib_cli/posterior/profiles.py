"""The heap profile as a second response beside the angle: each heap's fullness
(:func:`calib_cli.profile.fullness`), of the measured photographs and of the simulated heaps, both
taken from a silhouette by the same image code."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..errors import CalibError
from ..heaps.keys import RUNS
from ..measurements import photo_piles
from ..profile import fullness

FULLNESS = "fullness"


def asked_for(e: CalibError) -> CalibError:
    """Why the profile cannot be evidence (``e``), told to one who asked for it with --profile: the way out
    is to leave it out. The reasons themselves carry no such advice, since a stage that weighs the profile
    by default (or as its posterior did) leaves it out, or has no --profile to drop."""
    return CalibError(f"{e} (or drop --profile to weigh the angle alone)")


def profile_inputs(run: Path) -> dict[str, Path]:
    """The measured files the profile's evidence reads, for a stage's lock; a one-line error where the
    photographs' profiles are missing."""
    prof, angles = run / "measure" / "profiles.parquet", run / "measure" / "angles.parquet"
    if not (prof.is_file() and angles.is_file()):
        raise CalibError(f"no heap profiles in {prof.parent} (profiles.parquet and angles.parquet): measure the "
                         "photographs (`calib measure-angle --images`) first")
    return {"profiles": prof, "angles": angles}


def _side_view_fullness(folder: Path) -> float:
    """The fullness of a simulated heap's side view, measured as the campaign measures it; NaN where
    the folder has none (a heap that blew up) or its silhouette is no heap."""
    from ..imaging.measure import measure_image, read_image

    side = folder / "side.png"
    if not side.is_file():
        return float("nan")
    res = measure_image(read_image(side), limits=None)
    return fullness(res.profile_s, res.profile_h) if res.status == "ok" else float("nan")


def _own(rows: pd.DataFrame) -> pd.Series:
    """Each row's recorded fullness (NaN where the campaign did not record one)."""
    return rows[FULLNESS].astype(float).copy() if FULLNESS in rows.columns else pd.Series(np.nan, index=rows.index)


def simulated_fullness(run: Path, rows: pd.DataFrame) -> pd.Series:
    """Each results row's fullness: the row's own where it has one (heaps simulated since the campaign
    records it), else measured on its side view (RUN/simulate/runs/<hash>/side.png); NaN where the
    heap's folder is gone (a committed sample run keeps its rows, not its folders)."""
    out = _own(rows)
    if "run_hash" not in rows.columns:  # a results table not written by a campaign: no heap folders to read
        return out
    for i in out.index[out.isna()]:
        out[i] = _side_view_fullness(run / RUNS / str(rows.at[i, "run_hash"]))
    return out


def profiles_at_hand(run: Path, rows: pd.DataFrame) -> int:
    """How many rows have a fullness or a side view to measure it on: a stage's lock keeps it, so that
    heaps whose folders arrive later (simulated again, copied in) rerun it."""
    own = _own(rows).notna()
    if "run_hash" not in rows.columns:
        return int(own.sum())
    return int(sum(o or (run / RUNS / str(h) / "side.png").is_file() for o, h in zip(own, rows["run_hash"])))


def _pooled_correlation(a: np.ndarray, b: np.ndarray, groups: np.ndarray) -> float:
    """The correlation of a and b within the groups: each group's deviations from its own means,
    pooled (0 with fewer than 3 degrees of freedom or no spread)."""
    da = a - pd.Series(a).groupby(groups).transform("mean").to_numpy()
    db = b - pd.Series(b).groupby(groups).transform("mean").to_numpy()
    den = np.sqrt(np.sum(da ** 2) * np.sum(db ** 2))
    dof = len(a) - len(np.unique(groups))
    return float(np.clip(np.sum(da * db) / den, -0.95, 0.95)) if dof >= 3 and den > 0 else 0.0


def measured_fullness(run: Path, conds: pd.DataFrame) -> tuple[pd.DataFrame, float]:
    """Per measured condition, in ``conds``' order: the fullness's ``mean``, ``sd`` and ``n`` over its
    photographs' profiles (RUN/measure/profiles.parquet, the photographs that enter the statistics),
    and the pooled within-condition correlation of a photograph's fullness with its angle."""
    path = run / "measure" / "profiles.parquet"
    prof = art.read_table(path, columns=["image", "condition_id", "s_px", "h_px"],
                          what="measured heap profiles (run `calib measure-angle --images` first)")
    if prof.empty:
        raise CalibError(f"{path} holds no profile: the angles were given as a table, not measured on "
                         "photographs, so there is no heap profile to use")
    per_image = pd.DataFrame([{"image": im, "condition_id": str(g["condition_id"].iloc[0]),
                               FULLNESS: fullness(g["s_px"].to_numpy(), g["h_px"].to_numpy())}
                              for im, g in prof.groupby("image", sort=True)])
    angles = art.read_table(run / "measure" / "angles.parquet", columns=["image", "repose_angle"])
    angles = angles.assign(pile=photo_piles(angles))[["image", "repose_angle", "pile"]]
    per_image = per_image.merge(angles, on="image", how="left")
    per_image = per_image[np.isfinite(per_image[FULLNESS]) & np.isfinite(per_image["repose_angle"])]
    stats = per_image.groupby("condition_id")[FULLNESS].agg(["mean", "std"])
    # a pile is one draw however many views it has (as measure-angle counts the angle's): its views' mean,
    # and the piles counted; the sd stays one photograph's
    piles = per_image.groupby(["condition_id", "pile"])[FULLNESS].mean()
    stats = stats.assign(mean=piles.groupby(level=0).mean(), count=piles.groupby(level=0).size())
    ids = conds["condition_id"].astype(str)
    missing = sorted(set(ids) - set(stats.index))
    if missing:
        raise CalibError(f"condition(s) {', '.join(missing)} have no photograph whose profile gives a fullness: "
                         "measure them on photographs")
    stats = stats.loc[ids]
    table = pd.DataFrame({"condition_id": ids.to_numpy(), "mean": stats["mean"].to_numpy(),
                          "sd": stats["std"].fillna(0.0).to_numpy(), "n": stats["count"].to_numpy()})
    mine = per_image[per_image["condition_id"].isin(set(ids))]  # not an unassigned photograph's
    rho = _pooled_correlation(mine["repose_angle"].to_numpy(float), mine[FULLNESS].to_numpy(float),
                              mine["condition_id"].to_numpy())
    return table, rho
