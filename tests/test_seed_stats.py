"""Seed-level aggregation (adaptfilt.seed_stats) against rliable and the run-level bootstrap."""
from types import SimpleNamespace

import numpy as np
import pytest

from adaptfilt import metrics
from adaptfilt.seed_stats import aggregate, difference, iqm, seed_groups
from adaptfilt.verdicts import verdict


def fake_results(values: dict, run_sd: float = 0.0, B: int = 1000, seed: int = 0):
    """name -> value; run-level replicates value + a shared run effect * run_sd."""
    rng = np.random.default_rng(seed)
    shared = rng.standard_normal(B)
    out = {}
    for n, v in values.items():
        boot = v + run_sd * (shared + 0.3 * rng.standard_normal(B))
        out[n] = SimpleNamespace(rmse=v, boot_rmse=boot, anees=v, boot_anees=boot, cost=v, boot_cost=boot)
    return out


def test_iqm_is_rliables():
    rl_metrics = pytest.importorskip("rliable.metrics")
    x = np.random.default_rng(1).lognormal(size=(8, 1))
    assert iqm(x.ravel()) == pytest.approx(rl_metrics.aggregate_iqm(x), rel=1e-14)
    assert iqm(np.arange(8.0)) == pytest.approx(np.mean([2, 3, 4, 5]))


def test_without_run_noise_the_interval_is_rliables_stratified_bootstrap():
    rly = pytest.importorskip("rliable.library")
    rl_metrics = pytest.importorskip("rliable.metrics")
    v = np.random.default_rng(2).normal(3.0, 0.5, size=8)
    res = fake_results({f"a-s{i}": x for i, x in enumerate(v)}, run_sd=0.0, B=4000)
    agg = aggregate(res, [f"a-s{i}" for i in range(8)], "rmse")
    _, ci = rly.get_interval_estimates({"a": v[:, None]}, lambda s: np.array([rl_metrics.aggregate_iqm(s),
                                                                             rl_metrics.aggregate_mean(s)]),
                                       reps=20000, random_state=np.random.RandomState(0))
    spread = v.max() - v.min()
    assert agg.iqm == pytest.approx(rl_metrics.aggregate_iqm(v[:, None]))
    np.testing.assert_allclose(agg.iqm_ci, ci["a"][:, 0], atol=0.04 * spread)
    np.testing.assert_allclose(agg.mean_ci, ci["a"][:, 1], atol=0.04 * spread)


def test_one_seed_is_the_run_level_interval():
    res = fake_results({"a-s0": 2.0}, run_sd=0.1)
    agg = aggregate(res, ["a-s0"], "anees")
    assert agg.iqm_ci == metrics.percentile_ci(res["a-s0"].boot_anees)


def test_difference_finds_a_shift_and_not_a_null():
    rng = np.random.default_rng(3)
    a = {f"a-s{i}": x for i, x in enumerate(rng.normal(1.0, 0.2, 8))}
    b = {f"b-s{i}": x for i, x in enumerate(rng.normal(2.0, 0.2, 8))}
    c = {f"c-s{i}": x for i, x in enumerate(rng.normal(1.0, 0.2, 8))}
    res = fake_results({**a, **b, **c}, run_sd=0.05)
    d = difference(res, list(a), list(b), "cost")
    assert d["iqm"][2] < 0 and d["mean"][2] < 0 and verdict("lower", d["iqm"]) == "confirmed"
    null = difference(res, list(a), list(c), "cost")
    assert null["mean"][1] < 0 < null["mean"][2] and verdict("lower", null["mean"]) == "not confirmed"
    assert verdict("not worse", null["mean"], 0.1) == "confirmed"  # 10 % of b = 1


def test_paired_runs_cancel_shared_run_noise():
    """Two seed groups with equal values and a large shared run effect: the difference's interval is
    narrow (paired runs), much narrower than either group's own interval."""
    res = fake_results({**{f"a-s{i}": 1.0 for i in range(4)}, **{f"b-s{i}": 1.0 for i in range(4)}}, run_sd=1.0)
    d = difference(res, [f"a-s{i}" for i in range(4)], [f"b-s{i}" for i in range(4)], "rmse")
    own = aggregate(res, [f"a-s{i}" for i in range(4)], "rmse")
    assert (d["mean"][2] - d["mean"][1]) < 0.5 * (own.mean_ci[1] - own.mean_ci[0])


def test_seed_groups_and_errors():
    g = seed_groups(["adaptive-s10", "adaptive-s2", "greedy", "myopic-faithful-s0", "adaptive"])
    assert g == {"adaptive": ["adaptive-s2", "adaptive-s10"], "myopic-faithful": ["myopic-faithful-s0"]}
    res = fake_results({"a-s0": 1.0})
    with pytest.raises(ValueError, match="metric"):
        aggregate(res, ["a-s0"], "nees")
    with pytest.raises(ValueError, match="no policies"):
        aggregate(res, [], "rmse")


def test_paired_seeds_judge_two_snapshots_of_the_same_trainings():
    """Two snapshots of the same eight trainings, the later one better by 0.05 on every seed while the seeds
    spread by 1: paired seeds (the same seeds drawn on both sides) confirm the improvement, independent
    resampling of the seeds drowns it in their spread; the same networks on both sides give exactly 0."""
    v = np.random.default_rng(4).normal(3.0, 1.0, 8)
    res = fake_results({**{f"late-s{i}": x - 0.05 for i, x in enumerate(v)}, **{f"early-s{i}": x for i, x in enumerate(v)}},
                       run_sd=0.0)
    late, early = [f"late-s{i}" for i in range(8)], [f"early-s{i}" for i in range(8)]
    paired = difference(res, late, early, "rmse", paired=True)["iqm"]
    assert paired[1] == pytest.approx(-0.05) and paired[2] == pytest.approx(-0.05)
    assert verdict("lower", paired) == "confirmed"
    assert verdict("lower", difference(res, late, early, "rmse")["iqm"]) == "not confirmed"
    same = difference(res, early, early, "rmse", paired=True)["iqm"]
    assert same == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="one policy per seed on both sides"):
        difference(res, late, early[:7], "rmse", paired=True)
