"""`calib report` leads with the answer: the first screen (headline, parameters, fit, error history,
ranking, photographs) comes before the paper's stages and the raw tables; every committed kind of
run renders, whatever stages it lacks; wide tables scroll inside their box; raw tables are collapsed."""

import json
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from calib_cli import artifacts as art
from calib_cli.report import SECTIONS, build_report

RUNS = Path(__file__).resolve().parents[1] / "sample_runs"
VOID = {"img", "meta", "br", "hr", "input", "link", "source", "wbr"}


class Tree(HTMLParser):
    """Records, for every table and every details element, the tags and classes enclosing it."""

    def __init__(self):
        super().__init__()
        self.stack: list[tuple[str, str, str]] = []  # (tag, class, id)
        self.tables: list[list[tuple[str, str, str]]] = []
        self.scripts = 0

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "table":
            self.tables.append(list(self.stack))
        self.scripts += tag == "script"
        if tag not in VOID:
            self.stack.append((tag, a.get("class") or "", a.get("id") or ""))

    def handle_endtag(self, tag):
        for i in range(len(self.stack) - 1, -1, -1):
            if self.stack[i][0] == tag:
                del self.stack[i:]
                return


def parse(page: str) -> Tree:
    t = Tree()
    t.feed(page)
    return t


def summary_of(page: str) -> str:
    return page[page.index("<section id=summary>"):page.index("<section id=posterior>")]


@pytest.mark.parametrize("name", ["paper", "smoke", "calibration", "hidden-effect", "hidden-wall", "control-lab",
                                  "foreign-lab"])
def test_every_committed_run_renders_its_sections_in_order(name):
    page = build_report(RUNS / name)
    ids = ["summary"] + [a for a, _ in SECTIONS]
    pos = [page.find(f"<section id={i}>") for i in ids]
    assert -1 not in pos and pos == sorted(pos), dict(zip(ids, pos))
    assert pos[0] < page.find("<details")  # nothing collapsed before the answer
    tree = parse(page)
    assert tree.scripts == 0  # readable without JavaScript
    # every table sits in a horizontally scrolling box, and every raw table is collapsed
    assert tree.tables and all(any("scroll" in c.split() for _, c, _ in anc) for anc in tree.tables)
    raw = [anc for anc in tree.tables if any(i == "raw" for _, _, i in anc)]
    assert raw and all(any(t == "details" for t, _, _ in anc) for anc in raw)
    # images are linked by their path inside the run directory, and each exists
    for src in re.findall(r'<img src="([^"]+)"', page):
        assert (RUNS / name / src).is_file(), src


@pytest.mark.parametrize("report", sorted(RUNS.glob("*/report.html")), ids=lambda p: p.parent.name)
def test_every_committed_report_is_what_the_code_renders_now(report, monkeypatch):
    """A change to the report's code, or to what a run holds, regenerates the committed page (`calib report
    --run RUN`): a stale page said "Calibrated" and "Not pinned" of the paper's GA point long after the code
    stopped saying so. A run directory holding heaps' folders (uncommitted caches) renders their side views:
    it is left out."""
    run = report.parent
    if any(p.name != "example" for p in (run / "simulate" / "runs").glob("*")):
        pytest.skip("this checkout holds the run's heap folders: its page shows their side views")
    monkeypatch.chdir(RUNS.parent)  # the page names its run as `make` gave it: sample_runs/NAME
    rel = run.relative_to(RUNS.parent)
    assert build_report(rel).encode() == report.read_bytes(), f"regenerate it: calib report --run {rel}"


def test_a_condition_where_the_compared_model_formed_no_heap_is_no_pass(tmp_path):
    """compare found no heap at one condition (every fill stood): that condition has no z, which once counted
    as a pass and left the RMSE blank; the headline calls it a misfit and the chart says "no heap"."""
    run = tmp_path / "hidden-effect"
    shutil.copytree(RUNS / "hidden-effect", run, ignore=shutil.ignore_patterns("runs"))
    res = art.read_table(run / "compare" / "residuals.parquet")
    gone = res["condition_id"].iloc[2]
    res.loc[2, ["simulated", "simulated_sd", "residual", "z"]] = np.nan
    res.loc[2, "fails"] = False
    art.write_table(run / "compare" / "residuals.parquet", res)
    for lock in (run / "compare").glob("*.lock.json"):  # the edit stands in for what compare would write
        lock.unlink()
    top = summary_of(build_report(run))
    assert "badge fail nw'>misfit" in top and f"forms no heap at 1 of 6 conditions ({gone})" in top
    chart = top[top.index("<svg"):top.index("</svg>")]
    assert chart.count(">no heap<") == 1


def test_first_screen_of_a_run_with_diagnose():
    """hidden-effect: the loop calibrated in rounds; cohesion added after diagnose ranked it; the first
    screen leads with the posterior (no GA point, nothing called pinned); no side view is committed.
    compare's four heaps a condition at revision 1's point miss one condition: the headline says so."""
    top = summary_of(build_report(RUNS / "hidden-effect"))
    assert "60 photographed heaps under 6 conditions" in top
    # one |z| of 2.10 among six conditions is what a right model gives one time in four: no misfit, but no
    # confirmation either; and no parameter's interval is narrow: the posterior of them, not "calibrated"
    assert "badge info nw'>consistent" in top and "reproduces the 6 conditions as well as chance allows" in top
    assert "not a confirmation" in top and "<b>The posterior of static friction" in top
    assert "1 of 6 conditions lies beyond two combined standard uncertainties" in top and "p 0.38" in top
    assert "ranked capillary and cohesion significant; revision 1 adds cohesion" in top
    assert top.index("Calibrated parameters: the posterior") < top.index("Fit per condition")
    assert "Cohesion: the data call for it (Bayes factor of off &lt; 0.066)" in top
    assert "surface_energy</td><td>0.453</td><td>0.316 &ndash; 0.67</td><td>J/m2</td>" in top
    assert ">pinned<" not in top and "best fit (GA)" not in top
    assert ("8 rounds, 240 heaps simulated, the posterior on 372 (132 of them simulated before this calibration and "
            "reused: an earlier revision's, compare's, diagnose's or other heaps of the model in the run); "
            "stopped by its budget") in top
    # the one set a user simulates with: compare's point, not the medians
    assert "static_friction 0.456, rolling_friction 0.123, restitution 0.22, surface_energy 0.438 J/m2." in top
    # fit per condition: one chart row per condition, pass or fail as compare's residuals say
    sol = art.read_table(RUNS / "hidden-effect" / "compare" / "residuals.parquet")
    chart = top[top.index("<svg"):top.index("</svg>")]
    assert all(c in chart for c in sol["condition_id"])
    assert chart.count(">pass<") == (~sol["fails"]).sum() and chart.count(">fail<") == sol["fails"].sum() == 1
    # error history and ranking with verdicts
    assert "+ cohesion (surface_energy)" in top and top.count("1 of 6 |z| &gt; 2") == 2  # revisions 0 and 1
    assert "sliding_friction (static_friction), rolling_friction, restitution" in top  # the posterior's names
    assert ">significant<" in top and "not significant" in top
    # one photograph per condition, and an honest word about the missing simulated side views (a clone
    # keeps none; a checkout that ran the pipeline keeps its heaps' folders, and shows them)
    assert top.count('src="measure/overlays/') == len(sol)
    kept = any((RUNS / "hidden-effect" / "simulate" / "runs").glob("*/side.png"))
    assert ("No simulated side view is kept in this run directory for any condition" in top) != kept


def test_the_posterior_section_shows_the_rounds_the_corner_plot_and_the_surrogates_errors():
    """What the posterior card summarises, drawn below it; the card's links lead there. The trends diagnose
    fitted are labelled with the revision it judged, not the one compare now holds."""
    page = build_report(RUNS / "hidden-effect")
    sec = page[page.index("<section id=posterior>"):page.index("<section id=screening>")]
    assert 'src="calibrate/rounds.png"' in sec and 'src="posterior/corner.png"' in sec
    assert "Model revision 1's posterior draws" in sec and ">gp<" in sec and ">fullness<" in sec
    assert summary_of(page).count("href='#posterior'") == 2
    assert "Model revision 0's residual against each condition variable" in page
    paper = build_report(RUNS / "paper")
    assert "Not run in this run directory (<code>calib calibrate</code>)" in paper
    # the answer is the rounds' last posterior sampled longer; averaged over the effect on and off where the
    # data decided it, which is why the control's answer is narrower than its last round
    assert "averaged over" not in sec and "drawn hollow is an upper bound" in sec
    control = build_report(RUNS / "control-lab")
    sec = control[control.index("<section id=posterior>"):control.index("<section id=screening>")]
    assert "then averaged over cohesion on and off (probability off 0.99)" in sec


def test_first_screen_flags_an_interval_its_box_cut(tmp_path):
    """A posterior crowding the top of its prior (the LAMMPS lab's restitution of 2026-11-27: 0.438-0.498 of
    0.1-0.5, truth 0.3): a red 'at upper edge', not 'identified', and the headline says to widen the range.
    The box cuts the whole posterior: the other parameters are known inside it only and cohesion gets no
    verdict, its Bayes factor shown."""
    run = tmp_path / "run"
    shutil.copytree(RUNS / "foreign-lab", run, ignore=shutil.ignore_patterns("runs", ".runs"))
    path = run / "posterior" / "summary.parquet"
    table, meta = art.read_table(path), art.read_provenance(path)
    at = table["parameter"] == "restitution"
    table.loc[at, ["median", "q05", "q95", "rel_width", "edge"]] = [0.482, 0.438, 0.498, 0.15, "high"]
    table[["surrogate_ratio", "decided"]] = [0.79, True]  # that run's surrogates were sure enough
    table.loc[~at, "edge"] = ""
    table["box_cut"] = "restitution high"
    art.write_table(path, table, meta)
    lock = run / "posterior" / "sample.lock.json"  # the edit is this test's, not a corrupt artefact
    record = json.loads(lock.read_text())
    record["outputs"]["summary.parquet"] = art.file_hash(path)
    lock.write_text(json.dumps(record))
    top = summary_of(build_report(run))
    assert "restitution</td><td>0.482</td>" in top and ">at upper edge<" in top
    assert "Pressed against an edge of its range, so cut by it: restitution" in top
    assert ">identified<" not in top.split("restitution</td>")[1].split("</tr>")[0]
    assert top.count(">inside the box only<") == 3 and ">no verdict: the box cuts the posterior<" in top
    assert "No verdict: the box cuts the posterior at restitution&#x27;s upper edge" in top
    assert "Cohesion: no verdict while the box cuts the posterior (Bayes factor of off 2.9)" in top
    assert "Known inside the box only, which cuts the posterior:" in top


def test_first_screen_degrades_on_the_paper_and_smoke_runs():
    paper = summary_of(build_report(RUNS / "paper"))
    assert "Not checked by simulation" in paper and "surrogate prediction at the solution" in paper
    assert "Not run yet: <code>calib compare</code>" in paper and "Not run yet: <code>calib diagnose</code>" in paper
    assert "No photographs in this run directory" in paper
    smoke = summary_of(build_report(RUNS / "smoke"))
    assert "reproduces the measured condition" in smoke and "Not run yet: <code>calib diagnose</code>" in smoke
    # smoke keeps one compare heap's folder: its side view stands beside the photograph
    assert 'src="simulate/runs/example/side.png"' in smoke and "No simulated side view" not in smoke


def test_side_view_of_a_kept_compare_heap_and_validation_fallback(tmp_path):
    """A compare heap whose folder is kept shows beside its condition's photograph; without compare,
    the fit is the validation heaps of the chosen refinement round."""
    src, run = RUNS / "hidden-wall", tmp_path / "run"  # a run of the paper's chain: invert's validation heaps
    for stage in ("measure", "invert", "simulate"):
        shutil.copytree(src / stage, run / stage)
    rows = art.read_table(run / "simulate" / "results.parquet")
    last = rows[(rows["design"] == "compare") & (rows["condition_id"] == "d4-5_D40_H50")].iloc[-1]
    side = run / "simulate" / "runs" / last["run_hash"] / "side.png"
    side.parent.mkdir(parents=True)
    shutil.copy(RUNS / "smoke" / "simulate" / "runs" / "example" / "side.png", side)
    top = summary_of(build_report(run))
    assert f'src="simulate/runs/{last["run_hash"]}/side.png"' in top
    assert "for 5 of 6 conditions" in top
    assert "validation heaps at the solution (refinement round 0)" in top
    assert re.search(r"The validation heaps at the solution (reproduce|miss) ", top)
    assert "Not run yet: <code>calib compare</code>" in top


def test_a_heap_folder_calib_did_not_write_is_passed_over(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(RUNS / "hidden-effect", run, ignore=shutil.ignore_patterns("runs"))
    (run / "simulate" / "runs" / "abc").mkdir(parents=True)
    (run / "simulate" / "runs" / "abc" / "result.json").write_text("[1]")  # was exit 70
    assert "Photographs" in summary_of(build_report(run))


@pytest.mark.parametrize("best", ["[]", '{"best": "rsm", "inputs": ["static_friction"], "lows": null}'])
def test_a_best_json_of_another_shape_leaves_the_ga_cards_edges_unsaid(tmp_path, best):
    run = tmp_path / "run"
    shutil.copytree(RUNS / "hidden-capillary", run, ignore=shutil.ignore_patterns("runs"))
    for lock in (run / "surrogate").glob("*.lock.json"):  # the edit stands in for another version's file
        lock.unlink()
    (run / "surrogate" / "best.json").write_text(best)
    top = summary_of(build_report(run))
    assert "The surrogate&#x27;s best fit (GA)" in top or "best fit (GA)" in top
    assert "at upper edge" not in top


def test_a_run_with_only_a_measurement(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(RUNS / "hidden-effect" / "measure", run / "measure")
    page = build_report(run)
    assert "No calibration in this run directory yet" in summary_of(page)
    assert "Not run yet: <code>calib calibrate</code>" in page
    assert page.count("Not run in this run directory") >= 4  # pb, ascent, bbd, surrogate, invert


def test_a_misfit_is_judged_on_the_conditions_together():
    """Six conditions: one |z| beyond 2 is chance (a right model gives one 24 % of the time), one beyond
    Sidak's 2.63, or a chi-square of all six beyond p 0.05, is a misfit; one condition alone keeps |z| > 2."""
    import pandas as pd

    from calib_cli.report.summary import Fit, verdict

    class Files:
        def __init__(self, z, chi2_dof):
            self.tabs = {"compare/residuals.parquet": pd.DataFrame({"z": z}),
                         "compare/history.parquet": pd.DataFrame({"revision": [1], "rmse": [2.0],
                                                                  "chi2_dof": [chi2_dof]})}

        def table(self, rel):
            return self.tabs.get(rel)

    def judge(z, chi2_dof):
        rows = pd.DataFrame({"condition_id": [f"c{i}" for i in range(len(z))], "fails": np.abs(z) > 2})
        return verdict(Files(np.asarray(z, float), chi2_dof), Fit(rows, "compare", ""))[0]

    z = [0.1, 1.0, -1.2, 0.6, -2.3, 0.0]
    assert judge(z, 1.65) == "chance"  # sum z^2 7.95 on 4.8 dof: p 0.15
    assert judge([0.1, 1.0, -1.2, 0.6, -1.3, 0.0], 0.8) == "pass"
    assert judge([0.1, 1.0, -1.2, 0.6, -2.9, 0.0], 2.3) == "fail"  # beyond 2.63
    assert judge([2.1, 1.9, 1.9, 1.8, 1.9, 0.0], 3.3) == "fail"  # each within, together p < 0.05
    assert judge([2.3], 5.3) == "fail"  # one condition: |z| > 2 is the bar


def test_the_surrogates_best_fit_says_how_far_its_surrogate_can_be_trusted():
    """A near-optimal tolerance of 0.25 deg means little from a surrogate that misses held-out heaps by 12 deg
    (the sample calibration's bp); and three parameters reaching one angle within 0.00 deg says nothing."""
    cal = summary_of(build_report(RUNS / "calibration"))
    assert "The surrogate inverted (bp) predicts a heap it was not fitted to within RMSE 12.40&deg;" in cal
    paper = summary_of(build_report(RUNS / "paper"))
    assert "with 3 parameters for 1 angle the search can always reach it" in paper
    # heaps simulated at such a point that reach the angle check the solution, not the model: no "fits"
    assert "badge info nw'>reached" in cal and "a fit is expected to reach it: that checks the solution" in cal
    assert ">fits<" not in cal


def test_the_ga_point_on_its_search_box_edge_is_said_to_be():
    """hidden-capillary's GA point has rolling friction at 0.3 and restitution at 0.1, the edges of the box its
    surrogate was fitted on (0.1-0.3, 0.1-0.5): once badged "narrow"; invert's warnings reach the card."""
    top = summary_of(build_report(RUNS / "hidden-capillary"))
    assert "fail nw'>at upper edge" in top and "fail nw'>at lower edge" in top and ">narrow<" not in top
    assert "invert: rolling_friction = 0.3 is at the high end of the range the surrogate was fitted on" in top


def test_an_effect_added_without_the_diagnosis_is_said_to_be():
    """hidden-floor's diagnosis found nothing, yet revision 1 adds wall rolling: the headline says both."""
    top = summary_of(build_report(RUNS / "hidden-floor"))
    assert ("found no significant missing effect; revision 1 adds wall rolling, which it did not rank "
            "significant (RMSE 1.46&deg; &rarr; 0.62&deg;") in top


def test_the_inversions_predictions_are_named_by_condition():
    page = build_report(RUNS / "hidden-wall")
    part = page[page.index("Surrogate prediction at the solution"):]
    assert "<th>condition_id</th><th class=n>target [deg]</th>" in part[:600] and "d4-5_D40_H50" in part[:2000]
    assert "<figcaption>The GA&#x27;s best and mean fitness" in page or "The GA's best and mean fitness" in page
    # the paper's path is judged against its Table 5 target, not its measurement: the page says so
    assert "judged against a target of 32.84&deg;" in build_report(RUNS / "paper") and "judged against" not in page


def test_an_undecided_posterior_is_not_called_calibrated_nor_its_point_final():
    """foreign-lab's surrogate is unsure where the posterior lies (ratio 1.3): the headline says calibrating,
    undecided so far, compare's verdict is at a point that may move, and the point's static friction, at the
    box's edge outside its own 90 % interval, is marked."""
    top = summary_of(build_report(RUNS / "foreign-lab"))
    assert "Calibrating static friction" in top and "undecided so far" in top and "<b>Calibrated" not in top
    assert "At the most probable draw of a posterior still undecided" in top
    assert "static_friction 0.7*" in top and "The posterior is undecided, so this point may still move" in top


def test_the_ga_point_is_pinned_only_where_the_posterior_identifies_it_around_that_value():
    """The GA card's badge reads the posterior as its own rows do: undecided, off, cut, wide, then pinned only
    where the point lies in the 90 % interval (the paper's rolling friction 0.198 against an identified
    0.144-0.162 once read "pinned")."""
    import pandas as pd

    from calib_cli.report.cards import _ga_state

    post = pd.DataFrame({"parameter": ["rolling_friction", "surface_energy"], "identified": [True, True],
                         "q05": [0.144, 0.0], "q95": [0.162, 0.0], "decided": True, "box_cut": "",
                         "p_off": [np.nan, 0.985]}).set_index("parameter")
    assert "pinned" in _ga_state("rolling_friction", 0.05, post, 0.15)
    assert "outside the posterior&#x27;s 90 %" in _ga_state("rolling_friction", 0.05, post, 0.198)
    assert "posterior: off" in _ga_state("surface_energy", 0.05, post, 0.3)
    assert "posterior undecided" in _ga_state("rolling_friction", 0.05, post.assign(decided=False), 0.15)
    assert "the box cuts" in _ga_state("rolling_friction", 0.05, post.assign(box_cut="static_friction high"), 0.15)
    assert "posterior wide" in _ga_state("rolling_friction", 0.05, post.assign(identified=False), 0.15)
    assert "range&#x27;s edge" in _ga_state("rolling_friction", 0.05, post.assign(edge=["high", ""]), 0.15)
