"""adaptfilt.course.reporting: the helpers of chapter 5 ("How results are reported")."""
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from adaptfilt import metrics, seed_stats  # noqa: E402
from adaptfilt.course import reporting as rep  # noqa: E402
from adaptfilt.experiments import artefacts  # noqa: E402


class _Results:
    """The little of a Results that the helpers read: ``config`` and ``results[name]``."""

    def __init__(self, config, **policies):
        self.config, self.policies = config, policies

    def __getitem__(self, name):
        return self.policies[name]


@pytest.fixture(scope="module")
def ungm():
    return artefacts.load_results("ungm-ukf")


def test_run_counts_recompute_the_stored_replicates(ungm):
    counts = rep.run_counts(ungm)
    assert counts.shape == (ungm.config["n_boot"], ungm.config["n_runs"])
    assert (counts.sum(axis=1) == ungm.config["n_runs"]).all()
    for name in ("greedy", "adaptive-s3"):
        p = ungm[name]
        assert np.allclose(counts @ p.run_cost / ungm.config["n_runs"], p.boot_cost)
        assert np.allclose(counts @ p.run_anees / ungm.config["n_runs"], p.boot_anees)


def test_run_counts_refuse_given_trajectories():
    with pytest.raises(ValueError, match="given trajectories"):
        rep.run_counts(_Results({"trajectories": "given", "seed": 0, "n_runs": 10, "n_boot": 5}))


def test_unpaired_permutes_the_second_policy_replicates():
    a = np.arange(200.0)
    u = rep.unpaired(a, a, seed=1)
    assert np.array_equal(np.sort(a - u), a)  # b's replicates, reordered
    assert np.ptp(u) > 0                       # the pairing (a - a = 0) is broken
    assert np.array_equal(u, rep.unpaired(a, a, seed=1))
    with pytest.raises(ValueError, match="shapes"):
        rep.unpaired(a, a[:10])


def test_pooled_runs_is_narrower_than_the_two_level_interval_when_seeds_differ(ungm):
    names = seed_stats.seed_groups(ungm.names)["adaptive"]
    pooled = rep.pooled_runs(ungm, names, "rmse")
    assert np.allclose(pooled, np.mean([ungm[n].boot_rmse for n in names], axis=0))
    lo, hi = metrics.percentile_ci(pooled)
    agg = seed_stats.aggregate(ungm, names, "rmse")
    assert hi - lo < agg.mean_ci[1] - agg.mean_ci[0]


def test_divergence_uses_the_library_definition():
    nx = 2
    run = np.array([1.0, 3.0, 2e4, 2.5e4, np.nan])  # 2e4 <= 1e4 * nx: not diverged; NaN is
    res = _Results({"nx": nx}, f=SimpleNamespace(run_anees=run))
    v = rep.divergence(res, "f")
    assert v["bad"].tolist() == [False, False, False, True, True]
    assert (v["n"], v["runs"], v["rate"]) == (2, 5, 0.4)
    assert v["ci"][0] < 0.4 < v["ci"][1]
    assert v["anees_kept"] == pytest.approx(np.mean([1.0, 3.0, 2e4]))
    with pytest.raises(ValueError, match="per-run"):
        rep.divergence(_Results({"nx": 1}, g=SimpleNamespace(run_anees=np.empty(0))), "g")


def test_divergence_matches_the_stored_share():
    ctm = artefacts.load_results("ctm-sif-logmaxnis")
    for name in ("default", "greedy", "fixed-n_iter=1"):
        assert rep.divergence(ctm, name)["rate"] == pytest.approx(ctm[name].divergent_frac)


def test_figures_draw(ungm):
    g = ungm["greedy"]
    figs = [rep.plot_bootstrap(g.run_cost, g.boot_cost), rep.plot_paired(ungm, "adaptive-s0", "greedy", "rmse"),
            rep.plot_levels(ungm, seed_stats.seed_groups(ungm.names)["adaptive"], "anees"),
            rep.plot_divergence(ungm, ["default", "fixed-kappa=0"])]
    assert [len(f.axes) for f in figs] == [2, 2, 1, 1]
    assert len(figs[2].axes[0].get_yticklabels()) == 8 + 3  # the seeds and three aggregates
    for f in figs:
        plt.close(f)
