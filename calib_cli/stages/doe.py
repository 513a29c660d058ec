"""The designed experiments on a run directory: Plackett-Burman screening, the steepest-ascent
path and the Box-Behnken response surface, each a design and its analysis (paper 3.1-3.4); the
designs and models themselves are calib_cli.doe's pure functions."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pandas as pd

from .. import artifacts as art
from .. import plots
from ..doe import ascent as ascent_mod
from ..doe import bbd as bbd_mod
from ..doe import pb as pb_mod
from ..errors import CalibError
from ..parameters import check
from ..settings import factor_space
from ..space import ParameterSpace
from .common import (Result, Say, check_run_dir, plain, resolve_settings, simulated_responses, space_from_design,
                     stage, writes_run)

Settings = Optional[Path]
Overrides = Optional[list[str]]


@dataclass
class DesignResult(Result):
    """RUN/<stage>/design.parquet: the ``design`` (one row per run) over its ``space``; an ascent path
    has its coded ``direction`` and ``method``."""

    design: Optional[pd.DataFrame] = None
    space: Optional[ParameterSpace] = None
    direction: Optional[dict] = None
    method: str = ""

    def __post_init__(self):
        if self.design is None and (self.dir / "design.parquet").is_file():
            self.design = art.read_table(self.dir / "design.parquet")
            self.space = space_from_design(self.dir / "design.parquet")

    def summary(self) -> pd.DataFrame:
        return self.design


@dataclass
class PBResult(Result):
    """RUN/pb/: the screening's ``analysis`` (effects, anova, fit, significant factors)."""

    analysis: Any = None

    def summary(self) -> pd.DataFrame:
        """The main effects, ranked (cf. paper Table 4)."""
        eff = self.analysis.effects if self.analysis is not None else art.read_table(self.dir / "effects.parquet")
        return eff[["factor", "effect", "sum_sq", "contribution_percent", "F", "p_value", "significant", "rank"]]


@dataclass
class AscentResult(Result):
    """RUN/ascent/: the ``analysis`` (path with its relative errors, best step, bracket)."""

    analysis: Any = None
    factors: Optional[list[str]] = None
    response: str = "repose_angle"
    target: float = float("nan")

    def summary(self) -> pd.DataFrame:
        """The path against the target (cf. paper Table 5)."""
        if self.analysis is None:
            return art.read_table(self.dir / "path.parquet")
        return self.analysis.path[["step", *self.factors, self.response, "relative_error_percent", "best"]]

    def warnings(self) -> list[str]:
        """What the analysis warns of: the best step at the end of the path."""
        if self.analysis is not None:
            at_edge = self.analysis.at_edge
        elif self.stage is not None and (self.dir / "path.parquet").is_file():  # read back: the path it wrote
            path = art.read_table(self.dir / "path.parquet")
            at_edge = bool(path["best"].to_numpy()[[0, -1]].any())
        else:
            return []
        if not at_edge:
            return []
        return ["the best step is at the end of the path; the optimum may lie outside it. Widen the screening "
                "ranges or extend the path."]


@dataclass
class BBDResult(Result):
    """RUN/bbd/: the quadratic response surface ``rsm`` and its ``coefficients``."""

    rsm: Any = None
    coefficients: Optional[pd.DataFrame] = None
    alpha: float = 0.05

    def summary(self) -> pd.DataFrame:
        """The fit's statistics (R2, adjusted and predicted R2, lack of fit, ...)."""
        return art.read_table(self.dir / "fit.parquet")

    def warnings(self) -> list[str]:
        """What the fit warns of: a significant lack of fit (at ``alpha``), adjusted and predicted R2 apart."""
        if self.rsm is not None:
            s = self.rsm.stats_
        elif self.stage is not None and (self.dir / "fit.parquet").is_file():  # read back: the statistics it wrote
            s = art.read_table(self.dir / "fit.parquet").iloc[0]
        else:
            return []
        out = []
        if s["lack_of_fit_p"] < self.alpha:
            out.append("lack of fit is significant: the quadratic model misses structure")
        if s["r2_adj"] - s["r2_pred"] > 0.2:
            out.append("adjusted and predicted R2 differ by more than 0.2")
        return out


def _fixed_values(cfg: dict, section: str, names: list[str]) -> dict[str, float]:
    """Natural values of factors held fixed: the section's `fixed` table, else the factor's centre."""
    given = cfg[section]["fixed"]
    space = factor_space(cfg, names)
    return {n: float(given.get(n, space[n].center)) for n in names}


def off_design(design: pd.DataFrame, data: pd.DataFrame, space: ParameterSpace) -> tuple[list[int], list[int], list]:
    """The rows of ``data`` (0-based) at no point of ``design``, those at a point whose runs other rows
    already took (more rows there than the design has runs), each design run taking one row within 1 %
    of every factor's range (a paper prints three digits), and the ``run_id`` of the runs left without one."""
    X = space.to_coded(design[space.names].to_numpy(dtype=float))
    free, off, more = np.ones(len(X), dtype=bool), [], []
    for i, r in enumerate(space.to_coded(data[space.names].to_numpy(dtype=float))):
        at = np.abs(X - r).max(axis=1) <= 0.02
        if (at & free).any():
            free[np.flatnonzero(at & free)[0]] = False
        else:
            (more if at.any() else off).append(i)
    ids = design["run_id"].tolist() if "run_id" in design.columns else list(range(1, len(design) + 1))
    return off, more, [ids[k] for k in np.flatnonzero(free)]


def say_off_design(responses: Optional[Path], design_path: Path, data: pd.DataFrame, say: Say) -> None:
    """Warn where a responses table's points are not its run's design: a table of its own design (a
    paper's) is analysed as it is, but a row missing or doubled from the run's design is a slip."""
    space = space_from_design(design_path)
    if responses is None or space is None or not set(space.names) <= set(data.columns):
        return
    off, more, unmet = off_design(art.read_table(design_path, what="design"), data, space)
    parts = []
    if off:
        first = ", ".join(f"{n} {data[n].iloc[off[0]]:g}" for n in space.names)
        parts.append(f"{len(off)} of its {len(data)} rows are at no run of {design_path} (row {off[0] + 1}: {first})")
    if more:
        parts.append(f"{len(more)} row(s) are at a run's point that other rows already give (row {more[0] + 1})")
    if unmet:
        ids = ", ".join(map(str, unmet[:8])) + (", ..." if len(unmet) > 8 else "")
        parts.append(f"{len(unmet)} design run(s) have no row ({ids})")
    if parts:
        say(f"[yellow]warning:[/] responses file {responses}: {'; '.join(parts)}; the analysis is of the table's "
            "own points")


def load_responses(run: Path, responses: Optional[Path], design_path: Path, factors: list[str],
                   response: str, say: Say = plain) -> tuple[pd.DataFrame, dict]:
    if responses is not None:
        return art.read_responses(responses, factors, response, warn=say), {"responses": responses}
    data = simulated_responses(run, design_path, factors, response)
    return data, {"design": design_path, "results": art.Rows(Path(run) / "simulate" / "results.parquet", data)}


# ------------------------------------------------------------------ pb
@writes_run
def pb_design(run: Path, settings: Settings = None, setting: Overrides = None, force: bool = False) -> DesignResult:
    """The 12-run Plackett-Burman design over settings pb.factors: RUN/pb/design.parquet."""
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    space = factor_space(cfg, cfg["pb"]["factors"])
    st = stage(run, "pb", "design", settings={"space": space.to_dicts(), "runs": cfg["pb"]["runs"]})
    if st.up_to_date() and not force:
        return DesignResult(st, True)
    df, _ = pb_mod.design(space, int(cfg["pb"]["runs"]))
    with st.commit() as out:
        out.table("design.parquet", df, space=space.to_dicts())
    return DesignResult(st, False, df, space)


@writes_run
def pb_analyze(run: Path, responses: Optional[Path] = None, settings: Settings = None, setting: Overrides = None,
               force: bool = False, say: Optional[Say] = None) -> PBResult:
    """Main effects and ANOVA of the screening, from the simulated heaps or ``responses``."""
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    names, response = list(cfg["pb"]["factors"]), cfg["response"]
    design_path = run / "pb" / "design.parquet"
    data, inputs = load_responses(run, responses, design_path, names, response, say or plain)
    space = space_from_design(design_path) or ParameterSpace.from_data(data, names, factor_space(cfg, names))
    st = stage(run, "pb", "analyze", inputs=inputs,
                   settings={"space": space.to_dicts(), "alpha": cfg["pb"]["alpha"], "response": response})
    # up to date: the same analysis of the same responses (a least-squares fit, milliseconds), not written again,
    # so a notebook's result has its fields on a rerun too
    res = pb_mod.analyze(data, space, response, float(cfg["pb"]["alpha"]))
    if st.up_to_date() and not force:
        return PBResult(st, True, res)
    say_off_design(responses, design_path, data, say or plain)  # once, when analysed: not on every skip
    fit = pd.DataFrame([{**{k: res.fit.stats[k] for k in ("r2", "r2_adj", "r2_pred", "adeq_precision",
                                                           "cv_percent", "std_dev", "mean", "model_F", "model_p")},
                         "intercept": float(res.fit.coef["Intercept"]), "n_runs": len(data),
                         "significant": ",".join(res.significant)}])
    with st.commit() as out:
        out.table("effects.parquet", res.effects)
        out.table("anova.parquet", res.anova)
        out.table("fit.parquet", fit)
        out.table("data.parquet", data)
        out.figure("effects.png", plots.pareto_effects(res.effects, res.alpha))
    return PBResult(st, False, res)


# ------------------------------------------------------------------ ascent
def _pb_outputs(run: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    eff = art.read_table(run / "pb" / "effects.parquet", what="screening effects (run `calib pb analyze` first)")
    fit = art.read_table(run / "pb" / "fit.parquet", what="screening fit (run `calib pb analyze` first)")
    return eff, fit


def _check_against_screening(run: Path, path: pd.DataFrame, factors: list[str], response: str, say: Say) -> None:
    """Warn where an ascent step repeats screening runs in every moved factor but its angle is not
    what the screening's model expects (ascent.screening_repeats, |z| > 3)."""
    if not all((run / "pb" / f).is_file() for f in ("data.parquet", "effects.parquet", "fit.parquet")):
        return
    eff, fit = _pb_outputs(run)
    scr = art.read_table(run / "pb" / "data.parquet", what="screening data")
    if response not in scr.columns or not set(factors) <= set(scr.columns):
        return
    design = run / "ascent" / "design.parquet"
    if design.is_file():  # the levels the path held the other screened factors at
        d = art.read_table(design, what="ascent design")
        extra = [f for f in eff["factor"] if f in d.columns and f not in path.columns]
        if "step" in d.columns and extra:
            path = path.merge(d[["step", *extra]], on="step", how="left")
    sd = float(fit["std_dev"].iloc[0])
    for r in ascent_mod.screening_repeats(path, scr, eff, sd, factors, response).itertuples():
        if abs(r.z) > 3:
            runs = ", ".join(map(str, r.runs))
            say(f"[yellow]warning:[/] step {r.step} repeats screening run(s) {runs} in {', '.join(factors)}, "
                f"but its angle {r.angle:.2f} differs from theirs ({r.screening_angle:.2f}) by "
                f"{r.angle - r.screening_angle:+.2f} deg where the screening's model expects "
                f"{r.expected:+.2f}: {r.z:+.1f} residual sd. The two stages do not agree; were they "
                "simulated (or measured) with the same setup - floor, fill, numerics?")


def _ascent_target(run: Path, cfg: dict, explicit: Optional[float] = None) -> tuple[float, dict]:
    """The ascent's target angle: --target, else settings ascent.target, else the measured angle
    (RUN/measure/conditions.parquet; the mean over conditions where there are several), else the
    settings target. Returns it with the input file it came from, if any (for the stage lock)."""
    a = cfg["ascent"]
    if explicit is not None:
        return check("repose_angle", explicit, "--target"), {}
    if a["target"] is not None:
        return float(a["target"]), {}
    cond = run / "measure" / "conditions.parquet"
    if cond.is_file():
        m = art.read_table(cond, columns=["mean"], what="measured conditions")["mean"].astype(float)
        if len(m) and np.isfinite(m).all():
            return float(m.mean()), {"conditions": cond}
    return float(cfg["target"]), {}


@writes_run
def ascent_design(run: Path, settings: Settings = None, setting: Overrides = None,
                  force: bool = False) -> DesignResult:
    """The steepest-ascent path over the screening's significant factors: RUN/ascent/design.parquet."""
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    eff, fit = _pb_outputs(run)
    sig = list(eff.loc[eff["significant"], "factor"])
    if not sig:
        raise CalibError("the screening found no significant factor: there is no ascent direction")
    a = cfg["ascent"]
    target, tin = _ascent_target(run, cfg)
    coefs = {f: float(eff.set_index("factor").loc[f, "coefficient"]) for f in sig}
    space = ParameterSpace.from_dicts(
        [{k: r[k] for k in ("low", "high", "unit")} | {"name": r["factor"]} for _, r in eff.iterrows()
         if r["factor"] in sig])
    others = [f for f in eff["factor"] if f not in sig]
    fixed = _fixed_values(cfg, "ascent", others)
    st = stage(run, "ascent", "design",
                   inputs={"effects": run / "pb" / "effects.parquet", "fit": run / "pb" / "fit.parquet", **tin},
                   settings={"method": a["method"], "steps": a["steps"], "target": target, "fixed": fixed})
    if st.up_to_date() and not force:
        return DesignResult(st, True)
    d = ascent_mod.direction(coefs, float(fit["intercept"].iloc[0]), target, a["method"])
    df = ascent_mod.design(space, d, int(a["steps"]), fixed)
    with st.commit() as out:
        out.table("design.parquet", df, space=space.to_dicts(), direction=dict(zip(sig, d.tolist())),
                  target=target)
    return DesignResult(st, False, df, space, dict(zip(sig, d.tolist())), a["method"])


@writes_run
def ascent_analyze(run: Path, responses: Optional[Path] = None, target: Optional[float] = None,
                   settings: Settings = None, setting: Overrides = None, force: bool = False,
                   say: Optional[Say] = None) -> AscentResult:
    """The relative error along the path, its best step and the bracket for the BBD."""
    say = say or plain
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    design_path = run / "ascent" / "design.parquet"
    tgt, tin = _ascent_target(run, cfg, target)
    response = cfg["response"]
    if design_path.is_file():
        factors = space_from_design(design_path).names
    elif (run / "pb" / "effects.parquet").is_file():
        eff, _ = _pb_outputs(run)
        factors = list(eff.loc[eff["significant"], "factor"])
    else:
        factors = [f for f in cfg["bbd"]["factors"] or cfg["pb"]["factors"] if f != "restitution"]
    if responses is not None:
        data = art.read_responses(responses, factors, response, optional=["step"], warn=say)
        if "step" not in data.columns:
            data.insert(0, "step", np.arange(1, len(data) + 1))
        elif data["step"].duplicated().any():  # the bracket is the best step's neighbours: one row each
            raise CalibError(f"responses file {responses}: step {data['step'][data['step'].duplicated()].iloc[0]:g} "
                             f"is given twice; give one row per step of the path")
        inputs = {"responses": responses}
    else:
        data = simulated_responses(run, design_path, factors, response, allow_failed=True)
        inputs = {"design": design_path, "results": art.Rows(run / "simulate" / "results.parquet", data)}
    inputs |= tin
    st = stage(run, "ascent", "analyze", inputs=inputs, settings={"target": tgt, "factors": factors})
    res = ascent_mod.analyze(data, factors, response, tgt)
    if st.up_to_date() and not force:  # the same path read again (as pb_analyze), not written
        return AscentResult(st, True, res, factors, response, tgt)
    for step in res.path.loc[~np.isfinite(res.path[response]), "step"]:
        say(f"[yellow]warning:[/] step {step} formed no heap (no angle): it cannot be the best step")
    with st.commit() as out:
        out.table("path.parquet", res.path, target=tgt)
        out.table("bracket.parquet", res.bracket, best_step=res.best_step, target=tgt)
        out.figure("path.png", plots.ascent_path(res.path, response, tgt))
    _check_against_screening(run, res.path, factors, response, say)
    return AscentResult(st, False, res, factors, response, tgt)


# ------------------------------------------------------------------ bbd
@writes_run
def bbd_design(run: Path, settings: Settings = None, setting: Overrides = None, force: bool = False) -> DesignResult:
    """The Box-Behnken design over the significant factors, in the ascent's bracket: RUN/bbd/design.parquet."""
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    b = cfg["bbd"]
    inputs: dict = {}
    names = list(b["factors"])
    if not names and (run / "pb" / "effects.parquet").is_file():
        eff, _ = _pb_outputs(run)
        names = list(eff.loc[eff["significant"]].sort_values("rank")["factor"])
        names = [n for n in cfg["pb"]["factors"] if n in names]  # keep the factor-table order
        inputs["effects"] = run / "pb" / "effects.parquet"
    if not names:
        raise CalibError("no factors for the BBD: set bbd.factors or run the screening (`calib pb analyze`)")
    space = factor_space(cfg, names)
    bracket_path = run / "ascent" / "bracket.parquet"
    ranges = {n: tuple(b["ranges"][n]) for n in names if n in b["ranges"]}
    if len(ranges) < len(names) and bracket_path.is_file():
        br = art.read_table(bracket_path, columns=["factor", "low", "high"], what="ascent bracket").set_index("factor")
        for n in names:
            if n not in ranges and n in br.index:
                ranges[n] = (float(br.loc[n, "low"]), float(br.loc[n, "high"]))
        inputs["bracket"] = bracket_path
    space = ParameterSpace.of(space[n].with_range(*ranges[n]) if n in ranges else space[n] for n in names)
    others = [n for n in cfg["pb"]["factors"] if n not in names]
    fixed = _fixed_values(cfg, "bbd", others)
    st = stage(run, "bbd", "design", inputs=inputs,
                   settings={"space": space.to_dicts(), "center_points": b["center_points"], "fixed": fixed})
    if st.up_to_date() and not force:
        return DesignResult(st, True)
    df = bbd_mod.design(space, int(b["center_points"]), fixed)
    with st.commit() as out:
        out.table("design.parquet", df, space=space.to_dicts())
    return DesignResult(st, False, df, space)


@writes_run
def bbd_analyze(run: Path, responses: Optional[Path] = None, settings: Settings = None, setting: Overrides = None,
                force: bool = False, say: Optional[Say] = None) -> BBDResult:
    """The quadratic response surface with ANOVA, lack of fit, R2/adj/pred and adequate precision."""
    run = check_run_dir(run)
    cfg = resolve_settings(run, settings, setting)
    response = cfg["response"]
    design_path = run / "bbd" / "design.parquet"
    space = space_from_design(design_path)
    if space is not None:
        names = space.names
    else:
        names = list(cfg["bbd"]["factors"]) or [n for n in cfg["pb"]["factors"] if n != "restitution"]
    data, inputs = load_responses(run, responses, design_path, names, response, say or plain)
    if space is None:
        space = ParameterSpace.from_data(data, names, factor_space(cfg, names))
    st = stage(run, "bbd", "analyze", inputs=inputs, settings={"space": space.to_dicts(), "response": response})
    rsm = bbd_mod.QuadraticRSM(space).fit(data[space.names], data[response])
    if st.up_to_date() and not force:  # the same surface fitted again (as pb_analyze), not written
        return BBDResult(st, True, rsm, rsm.fit_.coefficient_table(), float(cfg["bbd"]["alpha"]))
    say_off_design(responses, design_path, data, say or plain)
    s = rsm.stats_
    fit = pd.DataFrame([{k: s[k] for k in ("r2", "r2_adj", "r2_pred", "adeq_precision", "cv_percent",
                                             "lack_of_fit_F", "lack_of_fit_p", "std_dev", "mean", "press",
                                             "model_F", "model_p")} | {"n_runs": len(data)}])
    coefs = rsm.fit_.coefficient_table()
    with st.commit() as out:
        out.table("coefficients.parquet", coefs, space=space.to_dicts())
        out.table("anova.parquet", rsm.anova_)
        out.table("fit.parquet", fit)
        out.table("data.parquet", data[[*names, response]])
        for i, a in enumerate(names):
            for bname in names[i + 1:]:
                out.figure(f"surface_{a}__{bname}.png", plots.response_surface(rsm, a, bname, response))
    return BBDResult(st, False, rsm, coefs, float(cfg["bbd"]["alpha"]))
