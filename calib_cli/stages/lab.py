"""A synthetic lab: DEM heaps with known (and hidden) parameters under several conditions, rendered as
photographs with image noise, to test the calibration and the discrepancy loop against a known truth."""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from ..dem.heap import FLOOR_VARIABLES, HeapCondition
from ..errors import CalibError
from ..heaps.inputs import (COND_VARS, RUN_ENGINES, build_requests, heap_preset, make_condition, modulus_settings,
                            parse_params)
from ..heaps.inputs import Pairs, checked_condition, given_pairs as pairs
from ..heaps.keys import RUNS
from ..heaps.runner import run_campaign
from ..model import EFFECTS
from .common import checked, stage


def floor_condition(base: HeapCondition, spec: str) -> HeapCondition:
    """``steel:static_friction=0.3,rolling_friction=0.05`` -> the base condition on that floor."""
    name, sep, rest = spec.partition(":")
    if not sep or not name.strip() or not rest.strip():
        raise CalibError(f"--floor {spec!r} is not NAME:KEY=VALUE,...")
    vals = {f"floor_{k}": v for k, v in pairs(rest.split(","), f"--floor {name}:").items()}
    if set(vals) - set(FLOOR_VARIABLES):
        raise CalibError(f"--floor {spec!r}: the keys are {', '.join(k.removeprefix('floor_') for k in FLOOR_VARIABLES)}")
    if not all(ch.isalnum() or ch in "-_." for ch in name.strip()):  # it names condition ids and photographs
        raise CalibError(f"--floor {spec!r}: a floor's name is letters, digits, '-', '_' and '.' (it goes into "
                         "each condition's id and photograph's file name)")
    return make_condition(base, {"floor": name.strip(), **checked_condition(vals, f"--floor {name.strip()}")})


def _lab_conditions(floors: list[HeapCondition], sizes: str, cylinders: str, fills: Optional[str], fill_ratio: float,
                    named_floors: bool) -> list[tuple[str, HeapCondition]]:
    """Every size range x cylinder x fill height x floor, with its condition id."""
    conds = []
    try:
        heights = [float(h) for h in fills.split(",")] if fills else [None]
        for s in sizes.split(","):
            lo, hi = (float(v) for v in s.split("-"))
            for d in cylinders.split(","):
                D = float(d)
                for H in heights:
                    for fc in floors:
                        cid = f"d{s}_D{D:g}" + (f"_H{H:g}" if H is not None else "") + (f"_{fc.floor}" if named_floors else "")
                        conds.append((cid, dataclasses.replace(fc, particle_d_min_mm=lo, particle_d_max_mm=hi,
                                                               cylinder_diameter_mm=D,
                                                               fill_height_mm=D * fill_ratio if H is None else H)))
    except ValueError as e:
        raise CalibError(f"--sizes, --cylinders, --fills: expected numbers like 5-6,6-7 / 40,48 / 50,100 ({e})")
    for cid, c in conds:  # a rig's plausible ranges, as --condition checks them: millimetres, not metres
        checked_condition({v: getattr(c, v) for v in ("particle_d_min_mm", "particle_d_max_mm",
                                                       "cylinder_diameter_mm", "fill_height_mm")},
                          f"condition {cid} of --sizes, --cylinders, --fills, --fill-ratio")
    ids = [cid for cid, _ in conds]
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:  # two conditions under one id would write one photograph twice, after every heap
        raise CalibError(f"--sizes, --cylinders, --fills or --floor give condition {twice[0]} twice: give each "
                         "value once")
    return conds


@dataclass
class LabResult:
    """The lab's heaps (``rows``, one per photograph) in ``out``; ``skipped`` where its photographs were
    up to date (then ``rows`` holds each photograph's condition and angle as truth.toml records them)."""

    out: Path
    rows: pd.DataFrame
    n_conditions: int
    skipped: bool = False

    def summary(self) -> str:
        if self.skipped:
            return (f"{self.out}: its {len(self.rows)} photographs in {self.n_conditions} conditions are up to date "
                    "(--force makes them again)")
        ok = self.rows["status"].eq("ok").sum()
        return f"{len(self.rows)} heaps ({ok} formed) in {self.n_conditions} conditions -> {self.out}"


def _locks_out(fn):
    """The lab folder's own lock (:func:`~calib_cli.artifacts.run_lock`) for the whole call: a second synth-lab
    on it fails at once, and another command's sweep of the run around it leaves its staging alone."""
    @functools.wraps(fn)
    def locked(*args, **kwargs):
        out = Path(args[0] if args else kwargs["out"])
        if out.exists() and not out.is_dir():  # said before the lock would say it of a run directory
            raise CalibError(f"--out {out} is a file, not a folder: give a folder for the lab's photographs")
        with art.run_lock(out):
            return fn(*args, **kwargs)
    return locked


@checked
@_locks_out
def synth_lab(out: Path, set_: Pairs = None, hidden: str = "cohesion", sizes: str = "5-6,6-8,8-10",
              cylinders: str = "50", fill_ratio: float = 1.0, fills: Optional[str] = None, repeats: int = 3,
              preset: str = "smoke", workers: int = 1, shear_modulus: Optional[float] = None,
              floor: Optional[list[str]] = None, noise: float = 6.0, seed: int = 7,
              engine: str = "builtin", px_per_m: float = 6000.0, force: bool = False) -> LabResult:
    """Synthetic measurements with a hidden effect: DEM heaps at the true parameters ``set_`` under every
    condition (sizes x cylinders x fills x floors) on ``engine`` (builtin, gpu, or lammps: another DEM
    code's heaps, its own laws), rendered as photographs of ``px_per_m`` pixels a metre with image noise,
    a conditions.csv and truth.toml (which no stage reads) in ``out``. A stage: its lock
    (``out/synth-lab.lock.json``) records what made the photographs, so the same lab asked again is
    skipped unless ``force``, without its heaps (``out/.runs``, a cache) or the engine at hand."""
    if hidden != "none" and hidden not in EFFECTS:  # a label truth.toml keeps: a typo would mislabel the lab
        raise CalibError(f"unknown hidden effect {hidden!r}: none or one of {', '.join(EFFECTS)}")
    truth = parse_params(pairs(set_, "--set")) if set_ else {}
    pre = heap_preset(preset, shear_modulus)
    floor = [floor] if isinstance(floor, str) else floor  # one floor, not its letters
    floors = [floor_condition(pre.condition, f) for f in floor] if floor else [pre.condition]
    conds = _lab_conditions(floors, sizes, cylinders, fills, fill_ratio, bool(floor))
    _check_lab_options(engine, px_per_m, noise, Path(out))
    reqs = build_requests([(0, truth)], conds, pre.numerics, seed=seed, repeats=repeats, preset=preset, design="lab",
                          model="truth", label_by_condition=True, engine=engine)
    for _, c in conds:
        c.validate()
    out = Path(out)
    meta = {"hidden_effect": hidden, "parameters": truth, "preset": preset, "seed": seed,
            **({"engine": engine} if engine != "builtin" else {}), **({"px_per_m": px_per_m} if px_per_m != 6000 else {}),
            **modulus_settings(shear_modulus)}
    st = stage(out.parent, out.name, "synth-lab", version="synth-lab",
               settings={"requests": [q.hash for q in reqs], "noise": noise, "px_per_m": px_per_m, **meta})
    if st.up_to_date() and not force:
        return LabResult(out, _recorded_rows(out), len(conds), skipped=True)
    _engine_ready(engine)
    rows = run_campaign(reqs, out / ".runs", workers)
    with st.commit() as w:
        _write_lab(w, rows, reqs, conds, out / ".runs", meta, noise, px_per_m, seed, bool(floor))
    return LabResult(out, rows, len(conds))


def _check_lab_options(engine: str, px_per_m: float, noise: float, out: Path) -> None:
    if engine not in (*RUN_ENGINES, "lammps"):
        raise CalibError(f"unknown engine {engine!r}: {', '.join(RUN_ENGINES)} or lammps")
    if not (np.isfinite(px_per_m) and 1000.0 <= px_per_m <= 50000.0):
        raise CalibError(f"--px-per-m {px_per_m:g} is outside 1000 to 50000 pixels a metre")
    if not (np.isfinite(noise) and 0.0 <= noise <= 100.0):
        raise CalibError(f"--noise {noise:g} is outside 0 to 100 grey levels (the image noise's sd)")
    if out.exists() and not out.is_dir():
        raise CalibError(f"--out {out} is a file, not a folder: give a folder for the lab's photographs")


def _engine_ready(engine: str) -> None:
    """Fail now, with the extra named, rather than after the first heap: no GPU, or no LAMMPS."""
    if engine == "gpu":
        from ..dem.gpu import cuda_module

        cuda_module()
    if engine == "lammps":
        from ..engines.lammps import open_lammps

        open_lammps().close()


def _write_lab(w, rows: pd.DataFrame, reqs, conds, work: Path, meta: dict, noise: float, px_per_m: float,
               seed: int, floors: bool) -> None:
    """Each heap's side view rendered with image noise (one generator over the heaps in order) as a
    photograph, the conditions table and truth.toml, into the stage's writer ``w``."""
    import cv2
    import tomli_w

    from ..dem.render import render_side_view

    rng = np.random.default_rng(seed)
    # the floor's label and values only where the lab has floors: an empty cell is no condition value
    cvars = [k for k in COND_VARS if k not in FLOOR_VARIABLES or any(k in c.floor_values() for _, c in conds)]
    cvars += ["floor"] if floors else []
    lines = ["image," + "condition_id," + ",".join(cvars)]
    for (_, row), req in zip(rows.iterrows(), reqs):
        st = art.read_table(work / RUNS / row["run_hash"] / "state.parquet")
        img = render_side_view(st[["x", "y", "z"]].to_numpy(), st["radius"].to_numpy(), px_per_m=px_per_m).image
        img = np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
        name = f"{req.condition_id}_r{req.repeat + 1}.png"
        w.bytes(name, cv2.imencode(".png", img)[1].tobytes())
        c = req.condition
        lines.append(f"{name},{req.condition_id}," + ",".join(str(getattr(c, k)) for k in cvars))
    w.text("conditions.csv", "\n".join(lines) + "\n")
    w.text("truth.toml", "# the truth of this synthetic lab: no stage reads this file\n" + tomli_w.dumps(
        {**meta, "angles": {f"{r.condition_id}_r{r.repeat + 1}": float(a) for r, a in zip(reqs, rows["repose_angle"])}}))


def _recorded_rows(out: Path) -> pd.DataFrame:
    """An up-to-date lab's photographs: each one's condition and the angle truth.toml records for its heap."""
    import tomllib

    table = pd.read_csv(out / "conditions.csv")
    angles = tomllib.loads((out / "truth.toml").read_text()).get("angles", {})
    return table.assign(repose_angle=[angles.get(Path(i).stem, np.nan) for i in table["image"]])
