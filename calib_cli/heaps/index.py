"""The results index ``RUN/simulate/results.parquet`` (:data:`RESULTS`): one row per finished heap and
label, rewritten atomically after every finished run and merged with what is on disk under the run lock
(:func:`append_index`); its readers keep the rows of the physics their heaps run now
(:func:`current_results`)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pandas as pd

from .. import __version__
from .. import artifacts as art
from ..dem.heap import CONDITION_VARIABLES, FLOOR_VARIABLES, LAWS, PARAMETERS, HeapCondition, Numerics
from ..errors import CalibError
from .keys import RUNS, cache_source, heap_source, physics

RESULTS = Path("simulate") / "results.parquet"
#: the results rows' columns that hold numbers
NUMERIC = ("run_id", "repeat", "seed", "repose_angle", "angle_coords", "angle_image", "angle_image_left",
           "angle_image_right", "fullness", "heap_height_mm", "base_radius_mm", *PARAMETERS)


def load_results(run_dir: Path) -> pd.DataFrame:
    path = Path(run_dir) / RESULTS
    if not path.is_file():
        return pd.DataFrame()
    try:
        return _checked(art.read_table(path, what="simulation results"), path)
    except CalibError as e:  # the index is rebuilt from the heaps' folders: say how to get there
        raise CalibError(f"{e}; delete it and rerun: the index is rebuilt from the heaps kept in "
                         f"{Path(run_dir) / RUNS} (a heap whose folder is gone is simulated again)") from None


def _checked(rows: pd.DataFrame, path: Path) -> pd.DataFrame:
    """The index as its writer left it: a table edited by hand to hold text where numbers belong is refused
    here, not met as a TypeError in whichever stage reads it."""
    from pandas.api.types import is_numeric_dtype

    if len(rows) and "repose_angle" not in rows.columns:
        raise CalibError(f"simulation results {path}: no column repose_angle")
    text = [c for c in NUMERIC if c in rows.columns and len(rows) and not is_numeric_dtype(rows[c])]
    if text:
        raise CalibError(f"simulation results {path}: column(s) {', '.join(text)} hold text where numbers belong")
    # a heap's condition and its angle as a simulation gives them: a NaN condition variable broke the
    # surrogate's linear algebra (an internal error), and an angle of 400 deg was fitted as a heap
    present = [c for c in CONDITION_VARIABLES if c in rows.columns]
    values = {c: pd.to_numeric(rows[c], errors="coerce").to_numpy(float) for c in present}
    text = [c for c in present if (rows[c].notna().to_numpy() & np.isnan(values[c])).any()]
    if text:
        raise CalibError(f"simulation results {path}: column(s) {', '.join(text)} hold text where numbers belong")
    # a floor variable left empty is the default floor's; every heap has a grain size, cylinder, fill and lift
    blank = [c for c in present if np.isinf(values[c]).any()
             or (c not in FLOOR_VARIABLES and np.isnan(values[c]).any())]
    if blank:
        raise CalibError(f"simulation results {path}: column(s) {', '.join(blank)} have an empty or infinite "
                         "value in some row (every heap has a grain size, cylinder, fill and lift speed)")
    if "repose_angle" in rows.columns:
        a = rows["repose_angle"].to_numpy(float)
        bad = np.isinf(a) | (a < 0) | (a > 90)
        if bad.any():
            raise CalibError(f"simulation results {path}: repose_angle {a[bad][0]:g} deg (row {int(np.argmax(bad))}) is "
                             "outside 0 to 90 deg")
    return rows


def current_sources(rows: pd.DataFrame) -> pd.Series:
    """The physics version each results row's heap would run now (its parameters' and floor's laws);
    "" where they are no longer valid parameters."""
    cols = tuple(c for c in (*PARAMETERS, *FLOOR_VARIABLES) if c in rows.columns)
    laws = cache_source(physics())  # the laws' versions now: the memo holds per state of the registry
    out = [_source_now(laws, cols, tuple(None if pd.isna(v) else v for v in vals))
           for vals in rows[list(cols)].itertuples(index=False, name=None)]
    return pd.Series(out, index=rows.index, dtype=object)


@functools.lru_cache(maxsize=65536)
def _source_now(laws: str, cols: tuple[str, ...], vals: tuple) -> str:
    """The physics version a parameter set runs today: worked out once per process (an index holds few
    distinct sets among many rows, and every stage that reads results asks for them again)."""
    given = {k: float(v) for k, v in zip(cols, vals) if v is not None}
    floor = {k: v for k, v in given.items() if k in FLOOR_VARIABLES}
    try:
        return heap_source({k: v for k, v in given.items() if k not in floor}, HeapCondition(**floor))
    except (CalibError, TypeError, ValueError):
        return ""


def current_results(run_dir: Path) -> pd.DataFrame:
    """The index rows an analysis may use: those of the physics their heaps run now (:func:`heap_source`),
    each run once.

    The index keeps rows of older kernel or law versions (their artefacts stay in the cache), but they
    are other simulations: averaging them with the current ones as if they were repeats shifted
    a whole calibration (found on a fresh clone whose committed index held older rows). Rows come in
    a canonical order (design, run, condition, repeat), not the order the heaps finished in.
    """
    df = load_results(run_dir)
    if df.empty:
        return df
    if "source" in df.columns:
        df = df[df["source"] == current_sources(df)]
    if "run_hash" not in df.columns:  # not an index written by calib: nothing to de-duplicate by
        return df.reset_index(drop=True)
    keys = [k for k in ("run_hash", "design", "run_id", "repeat", "condition_id") if k in df.columns]
    df = df.drop_duplicates(subset=keys, keep="last")
    # the index holds rows in the order the workers finished them; a surrogate's fit (and so the next
    # round's heaps) depends on row order, so the same run on another machine must see the same order
    order = [k for k in ("design", "run_id", "condition_id", "repeat", "run_hash") if k in df.columns]
    return df.sort_values(order, kind="mergesort", na_position="last").reset_index(drop=True)


def row_moduli(rows: pd.DataFrame) -> pd.Series:
    """Each simulation row's shear modulus (rows at the presets' modulus do not carry the column)."""
    if "shear_modulus" in rows.columns:
        return rows["shear_modulus"].fillna(Numerics.shear_modulus)
    return pd.Series(Numerics.shear_modulus, index=rows.index)


def row_laws(rows: pd.DataFrame) -> list[dict[str, float]]:
    """Each simulation row's contact-law switches that are on (:data:`..dem.heap.LAWS`; off, 0,
    is every law's default, and rows that did not set one lack its column or hold NaN)."""
    on = [k for k in LAWS if k in rows.columns]
    return [{k: float(r[k]) for k in on if pd.notna(r[k]) and r[k] != 0} for _, r in rows[on].iterrows()] \
        if on else [{} for _ in range(len(rows))]


def heap_setups(rows: pd.DataFrame) -> list[str]:
    """The distinct (preset, shear modulus, contact laws switched on) of simulation rows, as
    'preset default at 5 MPa' or 'preset default at 5 MPa, rolling_spring 1'."""
    if rows.empty or "preset" not in rows.columns:
        return []
    return sorted({f"preset {p} at {m / 1e6:g} MPa" + "".join(f", {k} {v:g}" for k, v in sorted(law.items()))
                   for p, m, law in zip(rows["preset"], row_moduli(rows), row_laws(rows))})


def _save_index(run_dir: Path, rows: list[dict]) -> None:
    """One row per (run, design, run id, repeat, condition), the latest content in the place of
    the first: a rerun of finished runs leaves the index as it was, byte for byte, so the stages
    that read it stay up to date (moving rerun rows to the end changed its hash and re-ran them)."""
    keys = ("run_hash", "design", "run_id", "repeat", "condition_id")
    latest: dict[tuple, dict] = {}
    for r in rows:
        latest[tuple(str(r.get(k)) for k in keys)] = r  # an existing key keeps its place
    columns = list(dict.fromkeys(k for r in rows for k in r))  # as pd.DataFrame(rows) orders them
    art.write_table(Path(run_dir) / RESULTS, pd.DataFrame(list(latest.values()), columns=columns),
                    {"stage": "simulate", "version": __version__})


def append_index(run_dir: Path, rows: list[dict]) -> None:
    """Add finished runs' rows to RUN/simulate/results.parquet: merged with the index as it is on disk
    now, under the run lock. Each command used to rewrite it from the copy it read at its start, so
    two writers (or any row added meanwhile) lost rows."""
    if not rows:
        return
    with art.run_lock(run_dir, wait=True):
        previous = load_results(run_dir)
        _save_index(run_dir, (previous.to_dict("records") if len(previous) else []) + list(rows))
