"""The stages' figures: what they draw, not how it looks."""

import numpy as np
import pandas as pd

from calib_cli.plots import _distinct_variables, history_figure, residuals_figure


def _table():
    return pd.DataFrame({"condition_id": ["a", "b", "c", "d"], "particle_d_min_mm": [4.0, 4.0, 5.0, 5.0],
                         "particle_d_max_mm": [5.0, 5.0, 6.0, 6.0], "fill_height_mm": [50.0, 100.0, 50.0, 100.0],
                         "cylinder_diameter_mm": [40.0] * 4, "residual": [1.0, -0.5, 3.0, -4.0],
                         "uncertainty": [1.0, 1.0, 1.2, 1.5], "fails": [False, False, True, True]})


def test_a_variable_that_repeats_another_s_pattern_is_folded_into_its_label():
    kept = _distinct_variables(_table(), ["particle_d_min_mm", "particle_d_max_mm", "cylinder_diameter_mm",
                                          "fill_height_mm", "lift_speed_mm_s"])
    assert kept == {"particle_d_min_mm": ["particle_d_max_mm"], "fill_height_mm": []}


def test_residuals_figure_one_panel_per_distinct_variable_conditions_side_by_side():
    fig = residuals_figure(_table(), 1, ["particle_d_min_mm", "particle_d_max_mm", "fill_height_mm"])
    axes = [a for a in fig.axes if a.get_xlabel()]
    assert [a.get_xlabel() for a in axes] == ["particle_d_min_mm\n(particle_d_max_mm with it)", "fill_height_mm"]
    # the two conditions at d 4 mm are drawn apart, not on top of each other
    xs = sorted({float(line.get_xdata()[0]) for line in axes[0].lines if len(line.get_xdata()) == 1})
    assert len(xs) == 4 and xs[0] < xs[1] < 4.5 < xs[2] < xs[3]
    labels = axes[-1].get_legend_handles_labels()[1]
    assert labels == ["a", "b", "c (beyond 2 u)", "d (beyond 2 u)"]


def test_residuals_figure_without_a_varying_condition_draws_one_panel_by_condition():
    t = _table().drop(columns=["particle_d_min_mm", "particle_d_max_mm", "fill_height_mm"])
    fig = residuals_figure(t, 0, ["particle_d_min_mm", "cylinder_diameter_mm"])
    assert [a.get_xlabel() for a in fig.axes] == ["condition"]


def test_history_figure_labels_each_revision_by_what_it_added_and_draws_chi2():
    hist = pd.DataFrame({"revision": [0, 1, 2], "effects": ["sliding_friction,restitution",
                                                            "sliding_friction,restitution,cohesion",
                                                            "sliding_friction,restitution,cohesion,wall_friction"],
                         "rmse": [2.5, 2.7, 1.0], "chi2_dof": [3.3, 1.6, np.nan]})
    fig = history_figure(hist)
    rmse, chi2 = fig.axes
    assert [t.get_text() for t in rmse.get_xticklabels()] == ["0", "1\n+ cohesion", "2\n+ wall_friction"]
    assert chi2.get_ylabel() == "chi2 / dof" and chi2.get_ylim()[1] >= 3.3
