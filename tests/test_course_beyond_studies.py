"""adaptfilt.course.beyond_studies: the helpers of chapters 14-15, against the library's definitions."""
import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest

from adaptfilt.course import beyond_studies, seed_results
from adaptfilt.experiment_registry import get_experiment
from adaptfilt import seed_stats as sd
from course_stand_ins import ungm_seed_groups  # tests/course_stand_ins.py


@pytest.fixture(scope="module")
def ungm_results():
    return ungm_seed_groups()


def test_chapter_11_helpers(ungm_results):
    res = ungm_results
    text = beyond_studies.verdict_counts(res, "a", "greedy", ("cost", "rmse"))
    lines = text.splitlines()
    assert len(lines) == 2 and lines[0].startswith("a - greedy  cost")
    d = sd.difference(res, sd.seed_groups(res.names)["a"], ["greedy"], "rmse")["iqm"]
    assert f"{d[0]:+.4g} [{d[1]:+.4g}, {d[2]:+.4g}]" in lines[1]
    counts = seed_results.seed_verdicts(res, "a", "greedy", "rmse")["counts"]
    assert sum(counts.values()) == 4 and all(f"{n} {v}" in lines[1] for v, n in counts.items())
    fig = beyond_studies.plot_cost_divergence(res, ["a", "b"], title="x")
    ax = fig.axes[0]
    fixed = [n for n in res.names if n.startswith("fixed-")]
    line = next(ln for ln in ax.lines if ln.get_label() == "fixed $n_{it}$")
    rel = 100 * (res[fixed[0]].cost_charged / res["default"].cost_charged - 1)
    assert len(line.get_xdata()) == len(fixed) and ax.get_yscale() == "symlog"
    assert line.get_xdata()[0] == pytest.approx(np.clip(rel, *ax.get_xlim()))
    texts = {t.get_text() for t in ax.get_legend().get_texts()}
    assert texts >= {"greedy", "a (4 seeds)", "b (3 seeds)"} and any(t.startswith("default") for t in texts)
    # the legend sits off the axes, and every panel of several has the same x range
    assert ax.get_legend().get_bbox_to_anchor().x0 > ax.get_window_extent().x1 - 1
    fig = beyond_studies.plot_cost_divergence(res, ["a"], xlim=(-5.0, 5.0), legend=None)
    assert fig.axes[0].get_xlim() == (-5.0, 5.0) and fig.axes[0].get_legend() is None
    # crowded n_it labels are all drawn (none dropped) and no two of them overlap
    fig = beyond_studies.plot_cost_divergence(res, ["a"], xlim=(-1e4, 1e4), legend=None)
    ax = fig.axes[0]
    fig.canvas.draw()
    labels = [t for t in ax.texts if t.get_text() in {n.split("=")[1] for n in fixed}]
    shown = [n for n in fixed if -1e4 <= 100 * (res[n].cost_charged / res["default"].cost_charged - 1) <= 1e4]
    assert len(labels) == len(shown)
    boxes = [t.get_window_extent() for t in labels]
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
    table = {"q1-r1": {"greedy": {"gain": 0.2}, "learned": {"gain": -0.1}}, "q4-r0.25": {"greedy": {"gain": 0.4}}}
    fig = beyond_studies.plot_ood_gains(table, "objective", columns=("greedy", "learned"))
    im = fig.axes[0].images[0]
    assert im.norm.vmax == pytest.approx(0.4) and fig.axes[1].images[0].norm.vmin == pytest.approx(-0.4)
    G = np.asarray(im.get_array())
    assert G[1, 1] == pytest.approx(0.2) and G[2, 0] == pytest.approx(0.4) and np.isnan(G[0, 0])


def test_divergence_onsets_use_the_librarys_one_definition():
    from adaptfilt.metrics import DIVERGED_NEES, divergence_step, divergent

    env = get_experiment("ctm-sif-logmaxnis").make_env(seed=0, n_steps=40)
    out = beyond_studies.divergence_onsets(env, 1.0, n_runs=400, seed=3)
    N, onset, div = out["nees"], out["onset"], out["divergent"]
    assert N.shape == (40, 400) and onset.shape == div.shape == (400,)
    np.testing.assert_array_equal(div, divergent(N.T, env.model.nx))
    np.testing.assert_array_equal(onset, divergence_step(N.T, env.model.nx))
    # the onset is the first step at which the running time average crosses DIVERGED_NEES * nx
    running = np.cumsum(np.where(np.isfinite(N), N, np.inf), axis=0) / np.arange(1, 41)[:, None]
    for m in np.flatnonzero(onset >= 0)[:20]:
        assert not running[onset[m], m] <= DIVERGED_NEES * env.model.nx
        assert (running[: onset[m], m] <= DIVERGED_NEES * env.model.nx).all()
    assert (onset[div] >= 0).all()
    # the same runs with ten iterations: no more divergent runs (the SIF with one iteration is the fragile one)
    ten = beyond_studies.divergence_onsets(env, 10.0, n_runs=400, seed=3)
    assert ten["divergent"].sum() <= div.sum()
    with pytest.raises(ValueError, match="not on the grid"):
        beyond_studies.divergence_onsets(env, 4.0, n_runs=2)


def test_seed_differences_show_every_seed_and_cut_at_the_edge(ungm_results):
    res = ungm_results
    fig = beyond_studies.plot_seed_differences(res, ["a", "b"], "greedy", ("rmse", "cost"), xlim={"cost": (-0.1, 0.1)})
    ax_rmse, ax_cost = fig.axes
    labels = [t.get_text() for t in ax_rmse.get_yticklabels()]
    assert labels[:4] == ["a-s0", "a-s1", "a-s2", "a-s3"] and "a: IQM of 4" in labels and "b: mean of 3" in labels
    # without xlim the range holds every interval and 0; with one, what lies beyond is written at the edge
    lo, hi = ax_rmse.get_xlim()
    d = res.paired_difference("a-s3", "greedy", "rmse")
    assert lo <= min(d[1], 0.0) and hi >= max(d[2], 0.0)
    assert ax_cost.get_xlim() == (-0.1, 0.1)
    big = res.paired_difference("a-s3", "greedy", "cost")[0]
    assert abs(big) > 0.1 and any(f"{big:+.3g}" in t.get_text() for t in ax_cost.texts)
