"""adaptfilt.course.paper_common: what chapters 9-11 share (seed tables, differences, usage, the
trade-off panels and their labels), against the stored evaluations."""
from course_stand_ins import close_figures, ungm_res  # noqa: F401 (fixtures: tests/course_stand_ins.py)

import matplotlib.pyplot as plt
import pytest

import adaptfilt as af
from adaptfilt.course import paper_common
from adaptfilt.experiments import report
from adaptfilt.seed_stats import aggregate

pytestmark = pytest.mark.crosscpu  # equalities claimed on any x86-64 CPU (.ci/run reruns them)


# ---------------------------------------------------------------- seed-level tables


def test_seed_table_lists_every_seed_and_the_iqm(ungm_res):
    md = paper_common.seed_table_md(ungm_res, ["adaptive", "no-such-group"], ["rmse"])
    row = next(line for line in md.splitlines() if line.startswith("| adaptive | rmse"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    names = [f"adaptive-s{i}" for i in range(8)]
    assert [float(c) for c in cells[4:]] == pytest.approx([ungm_res[n].rmse for n in names], rel=2e-3)
    assert cells[2].startswith(f"{aggregate(ungm_res, names, 'rmse').iqm:.3g} [")
    with pytest.raises(ValueError, match="none of the groups"):
        paper_common.seed_table_md(ungm_res, ["no-such-group"])


def test_differences_md_gives_the_rules_verdict(ungm_res):
    md = paper_common.differences_md(ungm_res, [("fixed-kappa=0", "fixed-kappa=200"), ("greedy", "ml")], ["rmse"])
    assert "| fixed-kappa=0 - fixed-kappa=200 | rmse |" in md and md.splitlines()[2].endswith("| contradicted |")
    assert md.splitlines()[3].endswith("| not confirmed |")  # greedy - ml: +0.0007 [-0.012, +0.015]
    d, lo, hi = ungm_res.paired_difference("greedy", "ml", "rmse")  # one policy each: the run-level paired CI
    assert f"{d:+.3g} [{lo:+.3g}, {hi:+.3g}]" in md


def test_usage_shares_and_table(ungm_res):
    shares = paper_common.usage_shares(ungm_res, ["greedy", "adaptive"])
    assert len(shares) == 9 and all(s.sum() == pytest.approx(1.0) for s in shares.values())
    md = paper_common.usage_md(ungm_res, ["fixed-kappa=200", "fixed-kappa=5"])
    assert md.splitlines()[0] == "| policy | κ = 5 | κ = 200 |" and "| fixed-kappa=200 | . | 100 % |" in md


def _boxes(ax):
    ax.figure.canvas.draw()
    r = ax.figure.canvas.get_renderer()
    from matplotlib.text import Text

    return [Text.get_window_extent(t, r) for t in ax.texts]  # the text alone, not its leader line


def test_place_labels_keeps_labels_apart_and_inside():
    fig, ax = plt.subplots(figsize=(4, 3))
    pts = {f"policy {i}": (1.0 + 0.01 * i, 2.0) for i in range(6)}  # six points on top of each other
    ax.plot(*zip(*pts.values()), "o")
    ax.set(xlim=(0, 3), ylim=(0, 4))
    anns = paper_common.place_labels(ax, pts)
    assert set(anns) == set(pts)
    boxes = _boxes(ax)
    a = ax.get_window_extent()
    for i, b in enumerate(boxes):
        assert a.x0 - 1 <= b.x0 and b.x1 <= a.x1 + 1 and a.y0 - 1 <= b.y0 and b.y1 <= a.y1 + 1
        assert not any(b.overlaps(o) for o in boxes[i + 1:])


def test_tradeoff_panels_zoom_on_the_named_policies_and_label_without_overlap(ungm_res):
    from adaptfilt.seed_stats import collapse_seeds

    col = collapse_seeds(ungm_res)
    names = report.figure_policies(col)
    zoom = ["ml", "greedy", "adaptive", "myopic", "fixed-kappa=200"]
    fig = paper_common.plot_tradeoff_panels(col, names, zoom)
    left, right = fig.axes
    (x0, x1), (y0, y1) = right.get_xlim(), right.get_ylim()
    for n in zoom:
        assert x0 < col[n].rmse_ci[0] and col[n].rmse_ci[1] < x1 and y0 < col[n].anees_ci[0] < col[n].anees_ci[1] < y1
    assert {t.get_text() for t in right.texts} == {"ml", "greedy", "adaptive", "myopic", "κ = 200"}
    outside = {t.get_text() for t in left.texts}
    assert "κ = 0" in outside and "greedy" not in outside  # the left panel labels what the zoom does not show
    for ax in (left, right):
        b = _boxes(ax)
        assert not any(p.overlaps(q) for i, p in enumerate(b) for q in b[i + 1:])
    assert ax.get_legend() is None and len(fig.legends) == 1  # the legend sits below the panels


def test_plain_log_labels_plain_numbers():
    fig, ax = plt.subplots()
    ax.plot([1, 30], [2, 40])
    paper_common.plain_log(ax, "both")
    fig.canvas.draw()
    assert ax.get_xscale() == ax.get_yscale() == "log"
    labels = {t.get_text() for t in ax.get_yticklabels()}
    assert {"3", "10", "20"} <= labels and not any("times" in t or "^" in t for t in labels)
    with pytest.raises(ValueError, match="axis must be"):
        paper_common.plain_log(ax, "z")


def test_rmse_axes_take_a_unit(ungm_res):
    names = ["default", "greedy"]
    assert af.plots.plot_rmse_bars(ungm_res, names, unit="m").axes[0].get_xlabel() == "time-averaged RMSE (m)"
    assert af.plots.plot_tradeoff(ungm_res, names, unit="m").axes[0].get_xlabel() == "time-averaged RMSE (m)"
    assert af.plots.plot_rmse_time(ungm_res, names, unit="m").axes[0].get_ylabel() == "RMSE$_k$ (m)"
