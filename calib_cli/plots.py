"""Matplotlib figures for the stages (PNG). The one place that sets the headless Agg backend: a module that
draws imports ``plt`` from here."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _label(f) -> str:
    unit = f" [{f.unit}]" if f.unit and f.unit != "-" else ""
    return f"{f.label or f.name}{unit}"


def response_surface(rsm, a: str, b: str, response: str = "repose_angle", n: int = 41):
    """Surface and contour of the RSM over factors a, b with the others at their middle (Fig. 6)."""
    space = rsm.space
    fa, fb = space[a], space[b]
    ga, gb = np.meshgrid(np.linspace(fa.low, fa.high, n), np.linspace(fb.low, fb.high, n))
    pts = np.tile([f.center for f in space.factors], (ga.size, 1))
    pts[:, space.names.index(a)] = ga.ravel()
    pts[:, space.names.index(b)] = gb.ravel()
    z = rsm.predict(pts).reshape(ga.shape)
    fig = plt.figure(figsize=(11, 4.6))
    ax1 = fig.add_subplot(1, 2, 1)
    cs = ax1.contourf(ga, gb, z, levels=14, cmap="viridis")
    ax1.contour(ga, gb, z, levels=14, colors="k", linewidths=0.4)
    fig.colorbar(cs, ax=ax1, label=f"{response} [deg]")
    ax1.set_xlabel(_label(fa))
    ax1.set_ylabel(_label(fb))
    ax1.set_title("contour")
    ax2 = fig.add_subplot(1, 2, 2, projection="3d")
    ax2.plot_surface(ga, gb, z, cmap="viridis", linewidth=0, antialiased=True)
    ax2.set_xlabel(fa.name)
    ax2.set_ylabel(fb.name)
    ax2.set_zlabel(f"{response} [deg]")
    ax2.set_title("response surface")
    others = [f.name for f in space.factors if f.name not in (a, b)]
    fig.suptitle(f"{fa.name} x {fb.name}" + (f" ({', '.join(others)} at middle level)" if others else ""))
    return fig


def ascent_path(path, response: str, target: float):
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(path["step"], path[response], "o-", label="response")
    ax.axhline(target, color="r", ls="--", label=f"target {target:g}")
    best = path[path["best"]]
    ax.plot(best["step"], best[response], "s", ms=12, mfc="none", mec="r", label="best step")
    ax.set_xlabel("step")
    ax.set_ylabel(f"{response} [deg]")
    ax.legend()
    ax.set_title("steepest-ascent path")
    return fig


def pareto_effects(effects, alpha: float):
    e = effects.sort_values("sum_sq")
    fig, ax = plt.subplots(figsize=(6, 0.6 * len(e) + 1.5))
    colors = ["tab:red" if s else "tab:gray" for s in e["significant"]]
    ax.barh(e["factor"], np.abs(e["effect"]), color=colors)
    for y, (v, p) in enumerate(zip(e["effect"], e["p_value"])):
        ax.text(abs(v), y, f"  {v:+.3g} (p={p:.3g})", va="center", fontsize=8)
    ax.set_xlabel("|main effect| [deg]")
    ax.set_title(f"Plackett-Burman main effects (red: p < {alpha:g})")
    return fig


def corner(samples, table):
    """Every pair of parameters' posterior draws (2-D histograms), each one's own on the diagonal with its
    90 % interval, each axis over the parameter's whole prior range."""
    names = list(table["parameter"])
    d = len(names)
    fig, axes = plt.subplots(d, d, figsize=(2.3 * d + 0.5, 2.3 * d + 0.5), squeeze=False)
    lim = {r.parameter: (r.low, r.high) for r in table.itertuples()}
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples[a], bins=40, range=lim[a], color="0.4")
                for q in ("q05", "q95"):
                    ax.axvline(table.loc[i, q], color="tab:red", ls="--", lw=1)
                ax.set_yticks([])
            else:
                ax.hist2d(samples[b], samples[a], bins=40, range=[lim[b], lim[a]], cmap="Greys")
                ax.set_ylim(lim[a])
            ax.set_xlim(lim[b])
            ax.set_xlabel(b if i == d - 1 else "")
            ax.set_ylabel(a if j == 0 and i > 0 else "")
    fig.suptitle("posterior draws over the prior ranges (dashed: 90 % interval)")
    fig.tight_layout()
    return fig


def rounds_figure(rounds, answer=None):
    """calibrate's rounds: each parameter's 90 % interval and median against the heaps its posterior
    learnt from, over its prior range; and the surrogates' variance at the posterior's draws over the
    measured means' (below 1 a verdict can be given) with each effect's Bayes factor of "off". ``answer``
    (the final posterior's summary, sampled longer) is drawn in black after the last round."""
    params = list(dict.fromkeys(rounds["parameter"]))
    averaged = answer is not None and "p_off" in answer.columns and answer["p_off"].notna().any()
    said = "the answer (sampled longer, averaged on and off)" if averaged else "the answer (sampled longer)"
    n = len(params) + 1
    cols = min(n, 3)
    rows_ = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows_, cols, figsize=(4.2 * cols, 3.2 * rows_), squeeze=False)
    for ax, p in zip(axes.flat, params):
        r = rounds[rounds["parameter"] == p]
        ax.fill_between(r["heaps"], r["q05"], r["q95"], color="tab:blue", alpha=0.25, step=None, label="90 %")
        ax.plot(r["heaps"], r["median"], "o-", color="tab:blue", ms=3, label="median")
        if answer is not None and p in set(answer["parameter"]):
            a = answer.set_index("parameter").loc[p]
            ax.errorbar([r["heaps"].iloc[-1]], [a["median"]], yerr=[[a["median"] - a["q05"]], [a["q95"] - a["median"]]],
                        fmt="D", color="k", ms=4, capsize=3, label=said)
        ax.set_ylim(r["low"].iloc[0], r["high"].iloc[0])
        ax.set_title(p)
        ax.set_xlabel("heaps the posterior learnt from")
    ax = axes.flat[len(params)]
    first = rounds.groupby("round", sort=True).first()
    ax.semilogy(first["heaps"], first["surrogate_ratio"], "s-", color="0.3", ms=3, label="surrogate / measured variance")
    for p in params:
        r = rounds[(rounds["parameter"] == p) & rounds["bf_off"].notna()]
        if len(r):
            line, = ax.semilogy(r["heaps"], r["bf_off"].clip(lower=1e-4), "o-", ms=3, label=f"Bayes factor off ({p})")
            bound = r[r["bf_upper"].astype(bool)] if "bf_upper" in r.columns else r.iloc[:0]
            if len(bound):  # no draw near the neutral value: an upper bound, drawn hollow
                ax.semilogy(bound["heaps"], bound["bf_off"].clip(lower=1e-4), "o", ms=6, mfc="white",
                            color=line.get_color(), label="  (hollow: an upper bound)")
            fin = answer[answer["parameter"] == p] if answer is not None and "bf_off" in answer.columns else r.iloc[:0]
            if len(fin) and np.isfinite(fin["bf_off"].iloc[0]):
                upper = bool(fin["bf_upper"].iloc[0]) if "bf_upper" in fin.columns else False
                ax.semilogy([r["heaps"].iloc[-1]], [max(float(fin["bf_off"].iloc[0]), 1e-4)], "D", ms=6, color="k",
                            mfc="white" if upper else "k", label="  its Bayes factor in the answer")
    ax.axhline(1.0, color="k", lw=0.6)
    ax.axhline(0.1, color="tab:red", lw=0.6, ls="--")
    ax.axhline(3.0, color="tab:green", lw=0.6, ls="--")
    ax.set_xlabel("heaps the posterior learnt from")
    ax.set_ylabel("ratio; Bayes factor of off")
    ax.set_title("ratio above 1: no verdict; Bayes factor below 0.1 (red): on, above 3 (green): off", fontsize=8)
    spare = list(axes.flat)[n:]
    handles, labels = ax.get_legend_handles_labels()
    diamond = [(h, lab) for h, lab in zip(*axes.flat[0].get_legend_handles_labels()) if lab == said]
    handles, labels = [h for h, _ in diamond] + handles, [lab for _, lab in diamond] + labels
    if spare:  # the curves fill their panel: the legend goes in the empty one beside it
        spare[0].legend(handles, labels, loc="center left", fontsize=8, frameon=False)
    else:
        ax.legend(handles, labels, fontsize=7)
    for extra in spare:
        extra.axis("off")
    fig.suptitle(f"calibrate, model revision {int(rounds['revision'].iloc[0])}: the posterior round by round")
    fig.tight_layout()
    return fig


def _distinct_variables(table, names):
    """The condition variables that vary, those that only repeat another's pattern (particle_d_max_mm
    when every grain class is 1 mm wide) folded into the first one's label."""
    kept: dict[str, list[str]] = {}
    for v in names:
        if v not in table.columns or table[v].nunique() < 2:
            continue
        x = table[v].astype(float)
        twin = next((k for k in kept if table[k].nunique() == x.nunique()
                     and abs(np.corrcoef(table[k].astype(float), x)[0, 1]) > 1 - 1e-9), None)
        kept.setdefault(twin or v, []).extend([v] if twin else [])
    return kept


def residuals_figure(table, revision: int, variables):
    """compare's residual (measured - simulated, +-2 combined u) per condition against each condition
    variable that varies, one colour per condition, conditions that share a value side by side; a
    condition beyond 2 u drawn as a cross."""
    groups = _distinct_variables(table, variables) or {"condition": []}
    n = len(groups)
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n + 2.2, 3.4), squeeze=False, sharey=True)
    colours = plt.get_cmap("tab10" if len(table) <= 10 else "tab20")
    fails = table["fails"].astype(bool).to_numpy() if "fails" in table.columns else np.zeros(len(table), bool)
    for ax, (v, twins) in zip(axes[0], groups.items()):
        x = table[v].to_numpy(float) if v in table.columns else np.arange(len(table), dtype=float)
        span = (np.ptp(x) or 1.0) * 0.035
        for i in range(len(table)):  # the conditions at one value side by side, in the table's order
            same = np.flatnonzero(x == x[i])
            dx = (np.searchsorted(same, i) - (len(same) - 1) / 2) * span
            ax.errorbar(x[i] + dx, table["residual"].iloc[i], yerr=2 * table["uncertainty"].iloc[i],
                        fmt="X" if fails[i] else "o", ms=7 if fails[i] else 5, capsize=2, color=colours(i % 20),
                        label=str(table["condition_id"].iloc[i]) + (" (beyond 2 u)" if fails[i] else ""))
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(np.unique(x))
        ax.set_xlabel(v + (f"\n({', '.join(twins)} with it)" if twins else ""))
    axes[0, 0].set_ylabel("measured - simulated [deg]\n(bars: 2 combined u)")
    axes[0, -1].legend(loc="center left", bbox_to_anchor=(1.02, 0.5), fontsize=8, frameon=False)
    fig.suptitle(f"residuals, model revision {revision}")
    fig.tight_layout()
    return fig


def history_figure(hist):
    """compare's error per model revision: the RMSE over conditions and chi2/dof (1: the residuals as
    large as the measured and simulated scatter explains), each revision labelled by what it added."""
    seen: set[str] = set()
    labels = []
    for rev, eff in zip(hist["revision"], hist["effects"]):
        effects = [e for e in str(eff).split(",") if e]
        new = [e for e in effects if e not in seen] if seen else []
        labels.append(f"{rev}" + (f"\n+ {', '.join(new)}" if new else ""))
        seen.update(effects)
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.2))
    for ax, col, ylabel in zip(axes, ("rmse", "chi2_dof"), ("RMSE over conditions [deg]", "chi2 / dof")):
        ax.plot(labels, hist[col], "o-")
        ax.set_ylabel(ylabel)
        y = hist[col].to_numpy(float)
        ax.set_ylim(0, max(1.15 * float(np.max(y[np.isfinite(y)], initial=0.0)), 1.3))
        ax.set_xlabel("model revision")
    axes[1].axhline(1.0, color="k", lw=0.6, ls="--")
    fig.suptitle("error per model revision (chi2/dof near 1: within the uncertainties)")
    fig.tight_layout()
    return fig
