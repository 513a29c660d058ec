"""Matplotlib figures for the stages (PNG, headless Agg backend)."""

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
    space = rsm.space_
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
