"""adaptfilt.style: the one plotting style of the course."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402

from adaptfilt import style  # noqa: E402


@pytest.fixture(autouse=True)
def _clean_rc():
    with matplotlib.rc_context():
        yield
    plt.close("all")


def test_param_label_writes_greek_letters():
    assert style.param_label("kappa", 200) == "κ = 200"
    assert style.param_label("kappa", 0.5) == "κ = 0.5"
    assert style.param_label("kappa", 1e4) == "κ = 10000"
    assert style.param_label("gamma") == "γ"
    assert style.param_label("n_iter", 10) == "N_it = 10"
    assert style.param_label("speed", 3) == "speed = 3"  # no Greek letter: unchanged


def test_policy_label_rewrites_parameters_inside_names():
    assert style.policy_label("fixed-kappa=200") == "fixed κ = 200"
    assert style.policy_label("UKF kappa=100, update only") == "UKF κ = 100, update only"
    assert style.policy_label("fixed-n_iter=10") == "fixed N_it = 10"
    assert style.policy_label("fixed-kappa=-0.5") == "fixed κ = -0.5"
    for name in ("default", "greedy", "ml", "exact (point mass)", "ac-gamma0.5-s3"):
        assert style.policy_label(name) == name


@pytest.mark.parametrize("n", [0, 1, 5, 8, 9, 13, 20])
def test_colors_are_pairwise_different(n):
    cs = [to_rgba(c) for c in style.colors(n)]
    assert len(cs) == n
    assert len(set(cs)) == n
    if n <= 8:
        assert style.colors(n) == list(style.OKABE_ITO[:n])


def test_colors_rejects_negative():
    with pytest.raises(ValueError, match="n >= 0"):
        style.colors(-1)


def test_use_sets_readable_fonts_and_the_colour_cycle():
    matplotlib.rcdefaults()
    style.use()
    rc = matplotlib.rcParams
    assert rc["legend.fontsize"] >= 8 and rc["font.size"] >= 10
    assert [to_rgba(c) for c in rc["axes.prop_cycle"].by_key()["color"]] == [to_rgba(c) for c in style.OKABE_ITO]
    fig, ax = plt.subplots()
    line, = ax.plot([0, 1])
    assert to_rgba(line.get_color()) == to_rgba(style.OKABE_ITO[0])


def test_figure_shapes_and_title():
    fig, ax = style.figure(title="T")
    assert isinstance(ax, plt.Axes) and fig._suptitle.get_text() == "T"
    fig, axes = style.figure(2, 3)
    assert axes.shape == (6,)
    with pytest.raises(ValueError, match="at least one row"):
        style.figure(0, 1)


def test_small_multiples_draws_one_panel_per_value():
    seen = []

    def draw(v, ax, scale=1.0):
        seen.append(v)
        ax.plot([0, 1], [0, v * scale])

    fig = style.small_multiples(draw, [0, 2, 10], "kappa", scale=2.0)
    assert seen == [0, 2, 10]
    assert [ax.get_title() for ax in fig.axes] == ["κ = 0", "κ = 2", "κ = 10"]
    assert fig.axes[2].lines[0].get_ydata()[1] == 20.0
    fig = style.small_multiples(lambda v, ax: ax.set_ylabel("y"), [1, 2])
    assert [ax.get_ylabel() for ax in fig.axes] == ["y", ""]  # one label for a shared axis
    with pytest.raises(ValueError, match="at least one value"):
        style.small_multiples(draw, [])


def test_plots_module_labels_parameters_in_greek():
    """af.plots writes the prose's Greek letters and tells 13 grid values apart."""
    from adaptfilt import plots
    from adaptfilt.evaluation import evaluate
    from adaptfilt.experiment_registry import UNGM_KAPPA_GRID
    from adaptfilt.mdp import Cost, FilterEnv
    from adaptfilt.models import ungm
    from adaptfilt.gaf import UKF
    from adaptfilt.policies import FixedPolicy, GreedyPolicy

    grid = UNGM_KAPPA_GRID
    env = FilterEnv(UKF(ungm(n_steps=15), on_indefinite="clip"), grid, cost=Cost("nis"))
    res = evaluate(env, [FixedPolicy(200, "kappa", grid=grid), GreedyPolicy(grid=grid)], n_runs=30, seed=0,
                   progress=False)
    fig = plots.plot_rmse_bars(res)
    assert [t.get_text() for t in fig.axes[0].get_yticklabels()] == ["κ = 200", "greedy"]
    fig = plots.plot_choices(res, "greedy")
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels and all(lab.startswith("κ = ") for lab in labels)
    faces = [to_rgba(c) for c in (p.get_facecolor() for p in fig.axes[0].collections)]
    assert len(set(faces)) == len(faces)
    fig = plots.plot_rmse_time(res)
    assert "fixed κ = 200" in [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
